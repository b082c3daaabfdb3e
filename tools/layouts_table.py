#!/usr/bin/env python3
# Markdown tables of `relief layouts --json` outputs (BENCHMARKS.md): python3 tools/layouts_table.py A.json B.json …
import json, sys
# Markdown table per input: faults at each τ per layout, ×row-major, ×bound, os major.
for f in sys.argv[1:]:
    r = json.load(open(f))
    print(f"\n**{f.replace('.json','')}** — {r['frames']} frames, cache {r['cache_pages']} pages of {r['page_bytes']} B ({r['memory_bytes']/2**20:.2f} MiB)\n")
    taus = sorted({x['tolerance'] for x in r['layouts']})
    hdr = "| layout | " + " | ".join(f"faults τ={t:g}" for t in taus) + " | ×row-major (τ=1) | ×lower bound (τ=1) | faults/frame mean, max (τ=1) | OS major (τ=1) |"
    print(hdr); print("|" + "---|" * (hdr.count("|") - 1))
    for lay in ["row-major", "tiled", "interleaved", "embedded", "hz"]:
        runs = {x['tolerance']: x for x in r['layouts'] if x['layout'] == lay}
        if not runs: continue
        t1 = runs[taus[0]]
        os = t1.get('os') or {}
        print(f"| {lay} | " + " | ".join(f"{runs[t]['faults']:,}" for t in taus)
              + f" | {t1['ratio_to_row_major']:.3f} | {t1['ratio_to_lower_bound']:.1f} | {t1['faults_per_frame_mean']:.1f}, {t1['faults_per_frame_max']} | {os.get('major','-')} |")
