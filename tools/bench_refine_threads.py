#!/usr/bin/env python3
"""Two threads against one by mesh size (BENCHMARKS.md, issue 43).

    python3 tools/bench_refine_threads.py [--relief target/release/relief] [--views 12]
        [--taus 0.25,1,4,16] [--repeat 51] [--threads 2] [--json OUT] FILE.relief...

For every file, view (tools/bench_refine.py's low oblique views), τ and culling mode (on and
off), it runs `relief refine --threads 1` and `--threads N` in turn (so both see the same machine)
with --repeat R, and takes each one's median refinement time. The meshes are binned by their
non-degenerate triangles into decades (10³ = 1,000–9,999, …); per decade it prints the number of
meshes, the median of (1-thread time / N-thread time) and its range, and both median times.
The two thread counts must refine the same triangles; the script stops if they do not.
"""

import argparse
import json
import math
import statistics
import sys

from bench_refine import run, views


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+")
    ap.add_argument("--relief", default="target/release/relief")
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--taus", default="0.25,1,4,16")
    ap.add_argument("--repeat", type=int, default=51)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json")
    a = ap.parse_args()
    taus = [float(t) for t in a.taus.split(",")]
    meshes = []
    for f in a.files:
        info = run(a.relief, ["info", f])
        for eye, look in views(info, a.views):
            for tau in taus:
                for cull in (True, False):
                    base = ["refine", f, "--eye", eye, "--look", look, "--tolerance", str(tau),
                            "--repeat", str(a.repeat)] + ([] if cull else ["--no-cull"])
                    one = run(a.relief, base + ["--threads", "1"])
                    many = run(a.relief, base + ["--threads", str(a.threads)])
                    if one["triangles"] != many["triangles"]:
                        sys.exit(f"{f} τ {tau}: {one['triangles']} triangles on 1 thread, {many['triangles']} on {a.threads}")
                    meshes.append({"file": f, "eye": eye, "tau": tau, "cull": cull, "triangles": one["triangles"],
                                   "one_ms": one["refine_ms"], "many_ms": many["refine_ms"]})
    if a.json:
        with open(a.json, "w") as out:
            json.dump(meshes, out, indent=1)
    decades = {}
    for m in meshes:
        if m["triangles"] > 0:
            decades.setdefault(int(math.log10(m["triangles"])), []).append(m)
    n = a.threads
    print(f"| triangles | meshes | 1-thread ms, median | {n}-thread ms, median | speed-up, median | lowest | highest |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for d in sorted(decades):
        ms = decades[d]
        ups = [m["one_ms"] / m["many_ms"] for m in ms]
        print(f"| 10^{d} ({10 ** d:,}–{10 ** (d + 1) - 1:,}) | {len(ms)} | {statistics.median(m['one_ms'] for m in ms):.3f} | "
              f"{statistics.median(m['many_ms'] for m in ms):.3f} | {statistics.median(ups):.2f} | {min(ups):.2f} | {max(ups):.2f} |")


if __name__ == "__main__":
    main()
