#!/usr/bin/env python3
"""Meta-node tree builds, before and after, in one run (BENCHMARKS.md, "Meta-node trees", Table 1).

    python3 tools/bench_metanode.py --after target/release/relief [--before OLD_RELIEF]
        [--mesh NAME=PATH ...] [--budgets 1/8,4G] [--limit-s 600] [--json OUT.json]

Runs `relief mesh build MESH OUT.rmn --vdt OUT.vdt --memory B --json --quiet` for every mesh,
budget and binary, one after the other, under `/usr/bin/time` (the process's peak RSS), and
prints one Markdown row each: ingest (reading and checking the mesh), VDT build (the edge
collapses), meta-node blocking (the .rmn), total wall seconds, triangles per second end to end
and peak RSS. The outputs of every run of a mesh are compared byte for byte (`same`). A run that
passes `--limit-s` is killed and reported as such (`> LIMIT`), not waited for.

Without --mesh: the real meshes of ../shared/data/mesh. `--before` is a binary built from an
earlier commit (git worktree add ..., cargo build --release); `--before-batched` instead runs the
after binary with `--batched` (the B-tree path at every budget).
"""

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SHARED = os.path.normpath(os.path.join(HERE, "..", "..", "shared", "data", "mesh"))


def run(binary, mesh, budget, out_dir, tag, extra, limit_s):
    rmn = os.path.join(out_dir, f"{tag}.rmn")
    vdt = os.path.join(out_dir, f"{tag}.vdt")
    for p in (rmn, vdt):
        if os.path.exists(p):
            os.remove(p)
    args = ["/usr/bin/time", "-f", "MAXRSS %M", binary, "mesh", "build", mesh, rmn, "--vdt", vdt,
            "--memory", budget, "--json", "--quiet"] + extra
    t0 = time.monotonic()
    try:
        p = subprocess.run(args, capture_output=True, text=True, timeout=limit_s)
    except subprocess.TimeoutExpired:
        return {"timeout": True, "wall_s": limit_s}
    wall = time.monotonic() - t0
    if p.returncode != 0:
        sys.exit(f"{' '.join(args)} failed: {p.stderr.strip()}")
    rss_kb = 0
    for line in p.stderr.splitlines():
        if line.startswith("MAXRSS "):
            rss_kb = int(line.split()[1])
    r = json.loads(p.stdout)
    v, m = r.get("vdt", r), r["metanode"]  # the VDT report is flattened into the top level
    digest = hashlib.sha256()
    for p_out in (rmn, vdt):
        with open(p_out, "rb") as f:
            digest.update(f.read())
    return {
        "timeout": False,
        "wall_s": wall,
        "ingest_s": v["ingest_ms"] / 1e3,
        "vdt_s": v["build_ms"] / 1e3,
        "metanode_s": m["build_ms"] / 1e3,
        "batches": v["batches"],
        "triangles": v["triangles"],
        "budget_bytes": v["memory_budget_bytes"],
        "peak_accounted_bytes": v["peak_accounted_bytes"],
        "peak_rss_bytes": rss_kb * 1024,
        "digest": digest.hexdigest(),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--after", required=True)
    ap.add_argument("--before")
    ap.add_argument("--before-batched", action="store_true")
    ap.add_argument("--mesh", action="append", default=[], help="NAME=PATH")
    ap.add_argument("--budgets", default="1/8,4G")
    ap.add_argument("--limit-s", type=float, default=600)
    ap.add_argument("--json")
    a = ap.parse_args()
    meshes = [m.split("=", 1) for m in a.mesh] or [
        ["Bunny", os.path.join(SHARED, "bunny.off")],
        ["Armadillo", os.path.join(SHARED, "armadillo.off")],
        ["Dragon", os.path.join(SHARED, "dragon_202k.ply.gz")],
    ]
    binaries = []
    if a.before:
        binaries.append(("before", a.before, []))
    elif a.before_batched:
        binaries.append(("before (--batched)", a.after, ["--batched"]))
    binaries.append(("after", a.after, []))
    rows = []
    print("| mesh | tris | budget | binary | batches | ingest s | VDT build s | meta-node s | total s | tris/s | peak RSS MB | same |")
    print("|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---|")
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as out_dir:
        for name, path in meshes:
            digests = set()
            for budget in a.budgets.split(","):
                for label, binary, extra in binaries:
                    r = run(binary, path, budget, out_dir, "out", extra, a.limit_s)
                    r.update(mesh=name, budget=budget, binary=label)
                    rows.append(r)
                    if r["timeout"]:
                        print(f"| {name} | | {budget} | {label} | | | | | > {a.limit_s:.0f} (killed) | | | |", flush=True)
                        continue
                    digests.add(r["digest"])
                    tris = r["triangles"]
                    print(
                        f"| {name} | {tris:,} | {budget} | {label} | {r['batches']} | {r['ingest_s']:.2f} | "
                        f"{r['vdt_s']:.2f} | {r['metanode_s']:.2f} | {r['wall_s']:.2f} | "
                        f"{tris / r['wall_s']:,.0f} | {r['peak_rss_bytes'] / 1e6:.1f} | "
                        f"{'yes' if len(digests) == 1 else 'NO'} |",
                        flush=True,
                    )
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
