#!/usr/bin/env python3
"""Refinement figures for BENCHMARKS.md: runs `relief refine --json` over a fixed set of views of
each terrain file and prints Markdown tables.

    tools/bench_refine.py [--relief target/release/relief] [--views 12] [--repeat 15] FILE.relief...

Views: N low-altitude oblique views from a circle of radius 0.35 × extent around the centre, at
2 % of the extent above the highest point, each looking across the centre at the lowest height
(the same definition for every terrain). Tables, per file:
  - mesh quality at τ = 1, 2, 4 px (culling off and on): median and worst ratio to the minimal
    mesh, strip vertices per non-degenerate triangle;
  - single-thread throughput (median over views of M triangles/s, each the median of --repeat
    refinements) and the 2-thread speed-up (ratio of median times), at τ = 1 px with culling.
Files of the same terrain in several layouts give one throughput row per layout.
"""

import argparse
import json
import math
import statistics
import subprocess
import sys


def run(relief, args):
    out = subprocess.run([relief] + args + ["--json"], check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def views(info, count):
    ex, ey = info["extent_m"]
    size = max(ex, ey)
    cx, cy = ex / 2, ey / 2
    zmax, zmin = info["z_max"], info["z_min"]
    for k in range(count):
        a = 2 * math.pi * k / count
        eye = (cx + 0.35 * ex * math.cos(a), cy + 0.35 * ey * math.sin(a), zmax + 0.02 * size)
        look = (cx - 0.2 * ex * math.cos(a), cy - 0.2 * ey * math.sin(a), zmin)
        yield ",".join(f"{v:.3f}" for v in eye), ",".join(f"{v:.3f}" for v in look)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("files", nargs="+")
    p.add_argument("--relief", default="target/release/relief")
    p.add_argument("--views", type=int, default=12)
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--skip-quality", action="store_true")
    a = p.parse_args()

    if not a.skip_quality:
        print("| terrain | culling | τ px | median ratio to minimal | worst | median strip vertices / triangle | median triangles |")
        print("|---|---|---|---|---|---|---|")
        seen = set()
        for f in a.files:
            info = run(a.relief, ["info", f])
            key = f.split("/")[-1].split(".")[0]
            if key in seen:
                continue  # one layout per terrain is enough: every layout gives the same strip
            seen.add(key)
            vs = list(views(info, a.views))
            for cull in (False, True):
                for tau in (1, 2, 4):
                    ratios, spt, tris = [], [], []
                    for eye, look in vs:
                        args = ["refine", f, "--eye", eye, "--look", look, "--tolerance", str(tau), "--compare-minimal"]
                        if not cull:
                            args.append("--no-cull")
                        r = run(a.relief, args)
                        ratios.append(r["ratio_to_minimal"])
                        spt.append(r["strip_vertices_per_triangle"])
                        tris.append(r["triangles"])
                    print(f"| {key} | {'on' if cull else 'off'} | {tau} | {statistics.median(ratios):.3f} | "
                          f"{max(ratios):.3f} | {statistics.median(spt):.3f} | {int(statistics.median(tris))} |")
                    sys.stdout.flush()
        print()

    print("| terrain | layout | median triangles | M triangles/s, 1 thread (median) | min–max over views | 2-thread speed-up (median) |")
    print("|---|---|---|---|---|---|")
    for f in a.files:
        info = run(a.relief, ["info", f])
        rates, speedups, tris = [], [], []
        for eye, look in views(info, a.views):
            base = ["refine", f, "--eye", eye, "--look", look, "--tolerance", "1", "--repeat", str(a.repeat)]
            r1 = run(a.relief, base + ["--threads", "1"])
            r2 = run(a.relief, base + ["--threads", "2"])
            rates.append(r1["mtris_per_s"])
            speedups.append(r1["refine_ms"] / r2["refine_ms"])
            tris.append(r1["triangles"])
        name = f.split("/")[-1].split(".")[0]
        print(f"| {name} | {info['layout']} | {int(statistics.median(tris))} | {statistics.median(rates):.1f} | "
              f"{min(rates):.1f}–{max(rates):.1f} | {statistics.median(speedups):.2f} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
