#!/usr/bin/env python3
"""Refinement before/after for BENCHMARKS.md: the median `relief refine` time per terrain file,
two builds of relief run in turn on each view (so that both see the same machine), 1 and 2 threads.

    tools/bench_refine_ab.py OLD_RELIEF NEW_RELIEF FILE.relief... > table.md

Views: the 12 low oblique views of tools/bench_refine.py, tau = 1 px, culling on, --repeat 15.
Per view and binary: the median of the repeats; per file: the median over the views, and the
2-thread speed-up as the median over views of (1-thread time / 2-thread time). The two builds may
decide a few vertices differently (the new one tests in f32 with a relative slack): the table gives
the largest difference in triangles over the views, and every new strip is checked crack-free
(`--check`), in one and two threads; the script stops if one is not, or if the two thread counts
of one build differ.
"""
import statistics
import sys
import time

# The same views and the same `relief … --json` runner as the one-build tables.
from bench_refine import run, views

old, new = sys.argv[1], sys.argv[2]
repeat = 15
print(f"Run {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, load {open('/proc/loadavg').read().split()[:3]}")
print("| terrain | layout | median triangles | largest triangle difference | old 1-thread ms | new 1-thread ms | old/new | old 2-thread speed-up | new 2-thread speed-up |")
print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
for f in sys.argv[3:]:
    info = run(new, ["info", f])
    o1, n1, o2, n2, tris, diff = [], [], [], [], [], []
    for eye, look in views(info, 12):
        base = ["refine", f, "--eye", eye, "--look", look, "--tolerance", "1", "--repeat", str(repeat)]
        ro1 = run(old, base + ["--threads", "1"]); rn1 = run(new, base + ["--threads", "1"])
        ro2 = run(old, base + ["--threads", "2"]); rn2 = run(new, base + ["--threads", "2"])
        assert ro1["triangles"] == ro2["triangles"] and rn1["triangles"] == rn2["triangles"], (f, eye)
        for threads in ["1", "2"]:
            c = run(new, base[:-2] + ["--repeat", "1", "--threads", threads, "--check"])
            assert c["check"]["crack_free"] and c["triangles"] == rn1["triangles"], (f, eye, threads, c["check"])
        diff.append((abs(rn1["triangles"] - ro1["triangles"]) / ro1["triangles"], rn1["triangles"] - ro1["triangles"]))
        o1.append(ro1["refine_ms"]); n1.append(rn1["refine_ms"]); o2.append(ro2["refine_ms"]); n2.append(rn2["refine_ms"])
        tris.append(rn1["triangles"])
    name = f.split("/")[-1].split(".")[0]
    mo, mn = statistics.median(o1), statistics.median(n1)
    so = statistics.median([a / b for a, b in zip(o1, o2)])
    sn = statistics.median([a / b for a, b in zip(n1, n2)])
    worst = max(diff)
    print(f"| {name} | {info['layout']} | {int(statistics.median(tris))} | {worst[1]:+d} ({100 * worst[0]:.3f}%) | {mo:.3f} | {mn:.3f} | {mo/mn:.2f} | {so:.2f} | {sn:.2f} |")
    sys.stdout.flush()
