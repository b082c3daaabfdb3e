#!/usr/bin/env python3
"""Disk-page hierarchy benchmark (BENCHMARKS.md, "Disk-page hierarchy"): raster vs hilbert vs
2factor page files of the same triangles, flown along one path per input.

    python3 tools/bench_pages.py [--dir DIR] [--rounds 3] [--frames 200] [INPUT ...]
    python3 tools/bench_pages.py --cap synth       # the SYNTHETIC terrain under a cgroup cap
    python3 tools/bench_pages.py --render dragon zurich   # with rendering (lavapipe), warm

INPUT is one of bunny, armadillo, dragon (real scans in ../shared/data/mesh), zurich (the real
Zürich DEM in data/, converted and exported as triangles, every post) and synth (a SYNTHETIC 2049²
terrain, `relief-synth --size 2049 --seed 7`); default: all five. Per input: one page file per
layout (`relief pages build --json`), one fly-over path (`relief path flyover` on the raster file),
one warming flight per layout, then ROUNDS rounds with the layouts interleaved, each a warm flight
(`relief pages fly --no-render --json`) and a cold one (`--cold-frames`: the file is evicted from
the page cache before every frame). Prints a Markdown table of the medians over the rounds of each
flight's means; raw JSON goes to DIR (default /work/bench/pages).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
RELIEF = ROOT / "target" / "release" / "relief"
SYNTH = ROOT / "target" / "release" / "relief-synth"
LAYOUTS = ["raster", "hilbert", "2factor"]
NAMES = {"bunny": "bunny", "armadillo": "armadillo", "dragon": "dragon", "zurich": "Zürich 513²",
         "synth": "SYNTHETIC 2049²"}


def run(args, **kw):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    if p.returncode != 0:
        sys.exit(f"bench_pages: {' '.join(map(str, args))}: exit {p.returncode}: {p.stderr.strip()}")
    return p.stdout


def relief_json(*args):
    return json.loads(run([RELIEF, *args, "--json"]))


def source(name, work):
    """The file `pages build` reads for input `name` (building terrain inputs on first use)."""
    meshes = {"bunny": "bunny.off", "armadillo": "armadillo.off", "dragon": "dragon_202k.ply.gz"}
    if name in meshes:
        return SHARED / "mesh" / meshes[name]
    if name == "zurich":
        out = work / "zurich.relief"
        if not out.exists():
            run([RELIEF, "convert", ROOT / "data" / "zurich_25m_i16.tif", out, "--quiet"])
        return out
    if name == "synth":
        out = work / "synthetic_2049.relief"
        if not out.exists():
            tif = work / "synthetic_2049.tif"
            run([SYNTH, tif, "--size", "2049", "--seed", "7"])
            run([RELIEF, "convert", tif, out, "--quiet"])
        return out
    sys.exit(f"bench_pages: unknown input {name} (one of {', '.join(NAMES)})")


def prepare(name, work, rebuild=True):
    """Page files in every layout and the path; returns ({layout: build report}, path). Without
    `rebuild`, page files already in `work` (from a table run) are kept and get no report."""
    src = source(name, work)
    builds = {}
    for layout in LAYOUTS:
        out = work / f"{name}_{layout}.rpg"
        if rebuild or not out.exists():
            builds[layout] = relief_json("pages", "build", src, out, "--layout", layout, "--quiet")
    path = work / f"{name}_fly.json"
    if not path.exists():
        run([RELIEF, "path", "flyover", work / f"{name}_raster.rpg", "--frames", args.frames, "--out", path])
    return builds, path


def fly(name, layout, path, work, *extra):
    return relief_json("pages", "fly", work / f"{name}_{layout}.rpg", "--path", path, *extra)["summary"]


def peak_rss_fly(name, layout, path, work, *extra):
    """A flight's peak RSS in bytes (/usr/bin/time -v) and its summary."""
    t = work / "time.txt"
    out = run(["/usr/bin/time", "-v", "-o", t, RELIEF, "pages", "fly", work / f"{name}_{layout}.rpg",
               "--path", path, *extra, "--json"])
    kb = next(int(l.split(":")[1]) for l in t.read_text().splitlines() if "Maximum resident set size" in l)
    return kb * 1024, json.loads(out)["summary"]


def med(xs):
    return statistics.median(xs)


def table(inputs, work):
    print("| input | layout | triangles | pages (MiB) | build s | pages/frame | seek pages/frame "
          "| triangles/frame | warm fetch ms | cold fetch ms | cold reads ms | cold fetch fps | cold vs raster |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name in inputs:
        builds, path = prepare(name, work)
        for layout in LAYOUTS:  # warm the page cache and the binary
            fly(name, layout, path, work, "--no-render")
        warm = {l: [] for l in LAYOUTS}
        cold = {l: [] for l in LAYOUTS}
        for _ in range(args.rounds):
            for layout in LAYOUTS:
                warm[layout].append(fly(name, layout, path, work, "--no-render"))
                cold[layout].append(fly(name, layout, path, work, "--no-render", "--cold-frames"))
        (work / f"{name}_results.json").write_text(json.dumps({"builds": builds, "warm": warm, "cold": cold}))
        cold_ms = {l: med([s["update_ms"]["mean"] for s in cold[l]]) for l in LAYOUTS}
        for layout in LAYOUTS:
            b, w, c = builds[layout], warm[layout], cold[layout]
            pf = lambda runs, k: med([s[k]['mean'] for s in runs])
            build_s = (b["layout_ms"] + b["write_ms"]) / 1000
            print(f"| {NAMES[name]} | {layout} | {b['triangles']:,} | {b['pages']:,} ({b['file_bytes'] / 2**20:.1f}) "
                  f"| {build_s:.1f} | {pf(c, 'pages_requested'):,.0f} | {pf(c, 'seek_pages'):,.0f} "
                  f"| {med([s['triangles']['mean'] for s in c]):,.0f} | {pf(w, 'update_ms'):.2f} "
                  f"| {cold_ms[layout]:.2f} | {pf(c, 'read_ms'):.2f} | {1000 / cold_ms[layout]:,.0f} "
                  f"| {cold_ms['raster'] / cold_ms[layout]:.1f}× |", flush=True)


def cap(inputs, work):
    """Each flight's own uncapped peak RSS plus a quarter of its page file, cold start."""
    print("| input | layout | cap | fetch ms (each run) | reads ms | vs raster |")
    print("|---|---|---:|---:|---:|---:|")
    for name in inputs:
        _, path = prepare(name, work, rebuild=False)
        caps, fetch, reads = {}, {}, {}
        for layout in LAYOUTS:
            rss, _ = peak_rss_fly(name, layout, path, work, "--no-render", "--cold")
            caps[layout] = rss + (work / f"{name}_{layout}.rpg").stat().st_size // 4
        for _ in range(args.rounds):
            for layout in LAYOUTS:
                s = fly(name, layout, path, work, "--no-render", "--cold", "--cap", str(caps[layout]))
                fetch.setdefault(layout, []).append(s["update_ms"]["mean"])
                reads.setdefault(layout, []).append(s["read_ms"]["mean"])
        for layout in LAYOUTS:
            print(f"| {NAMES[name]} | {layout} | {caps[layout] / 2**20:.0f} MiB "
                  f"| {', '.join(f'{x:.1f}' for x in fetch[layout])} | {', '.join(f'{x:.1f}' for x in reads[layout])} "
                  f"| {med(fetch['raster']) / med(fetch[layout]):.1f}× |", flush=True)


def render(inputs, work):
    print("| input | layout | fetch ms | render ms (median) | frame ms (median) | fps |")
    print("|---|---|---:|---:|---:|---:|")
    for name in inputs:
        _, path = prepare(name, work, rebuild=False)
        for layout in LAYOUTS:
            s = fly(name, layout, path, work, "--width", "640", "--height", "360")
            print(f"| {NAMES[name]} | {layout} | {s['update_ms']['mean']:.2f} | {s['render_ms']['median']:.1f} "
                  f"| {s['frame_ms']['median']:.1f} | {s['fps']:.1f} |", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="*", default=list(NAMES))
    ap.add_argument("--dir", type=Path, default=Path("/work/bench/pages"), help="working directory")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=200)
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--cap", action="store_true", help="cold flights under a cgroup memory cap")
    mode.add_argument("--render", action="store_true", help="warm flights with rendering, 640 × 360")
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    run(["cargo", "build", "--release", "--quiet", "--bin", "relief", "--bin", "relief-synth"], cwd=ROOT)
    (cap if args.cap else render if args.render else table)(args.inputs, args.dir)
