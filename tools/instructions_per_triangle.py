#!/usr/bin/env python3
"""Instructions per non-degenerate triangle of one refinement (BENCHMARKS.md, issue 43), counted
with cachegrind, so that the figure does not depend on the machine's noise.

    python3 tools/instructions_per_triangle.py [--relief target/release/relief] [--views 12]
        [--tolerance 1] [--cull on|off|both] [--threads 1] [--json OUT] FILE.relief...

Per view (tools/bench_refine.py's low oblique views) it runs `relief refine` under
`valgrind --tool=cachegrind --cache-sim=no` twice, with `--repeat 1` and `--repeat 1+K`, and
takes the difference of the two instruction counts over K refinements: what one refinement costs
without the process's start, the file's opening and the report. Divided by the view's
non-degenerate triangles (`triangles` of `--json`), that is the figure. Prints one Markdown row
per file and culling mode: median, lowest and highest over the views, and the median triangles.
"""

import argparse
import json
import re
import statistics
import subprocess
import sys

from bench_refine import run, views

EXTRA = 10  # refinements counted per view (the difference of the two runs)


def instructions(relief, args):
    p = subprocess.run(
        ["valgrind", "--tool=cachegrind", "--cache-sim=no", "--cachegrind-out-file=/dev/null", relief] + args,
        capture_output=True,
        text=True,
    )
    if p.returncode != 0:
        sys.exit(f"relief {' '.join(args)} under cachegrind failed: {p.stderr.strip()[-400:]}")
    m = re.search(r"I\s+refs:\s+([\d,]+)", p.stderr)
    if not m:
        sys.exit(f"no instruction count in cachegrind's output: {p.stderr.strip()[-400:]}")
    return int(m.group(1).replace(",", "")), json.loads(p.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+")
    ap.add_argument("--relief", default="target/release/relief")
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--tolerance", type=float, default=1.0)
    ap.add_argument("--cull", choices=["on", "off", "both"], default="both")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json")
    a = ap.parse_args()
    culls = {"on": [True], "off": [False], "both": [True, False]}[a.cull]
    rows = []
    print("| terrain | culling | τ px | views | median triangles | instructions / triangle, median | lowest | highest |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for f in a.files:
        info = run(a.relief, ["info", f])
        for cull in culls:
            per, tris = [], []
            for eye, look in views(info, a.views):
                base = ["refine", f, "--eye", eye, "--look", look, "--tolerance", str(a.tolerance),
                        "--threads", str(a.threads), "--json"] + ([] if cull else ["--no-cull"])
                one, r1 = instructions(a.relief, base + ["--repeat", "1"])
                many, rk = instructions(a.relief, base + ["--repeat", str(1 + EXTRA)])
                if r1["triangles"] != rk["triangles"]:
                    sys.exit(f"{f}: the repeats refined different meshes ({r1['triangles']} and {rk['triangles']})")
                t = max(r1["triangles"], 1)
                per.append((many - one) / EXTRA / t)
                tris.append(r1["triangles"])
            row = {"file": f, "cull": cull, "tolerance_px": a.tolerance, "views": len(per),
                   "median_triangles": statistics.median(tris), "per_triangle": per,
                   "median": statistics.median(per)}
            rows.append(row)
            print(f"| {f} | {'on' if cull else 'off'} | {a.tolerance:g} | {len(per)} | {row['median_triangles']:,.0f} | "
                  f"{row['median']:.1f} | {min(per):.1f} | {max(per):.1f} |", flush=True)
    if a.json:
        with open(a.json, "w") as out:
            json.dump(rows, out, indent=1)


if __name__ == "__main__":
    main()
