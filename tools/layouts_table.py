#!/usr/bin/env python3
# Markdown tables of `relief layouts --json` outputs (BENCHMARKS.md): python3 tools/layouts_table.py A.json B.json …
import json, sys
# Per input: faults at each τ per backend and layout, ×first row of the backend, ×bound, os major.
for f in sys.argv[1:]:
    r = json.load(open(f))
    mesh = r.get('mesh')
    extra = f", mesh of {mesh['triangles']:,} triangles (every {mesh['step']} post)" if mesh else ""
    print(f"\n**{f.replace('.json','')}** — {r['frames']} frames, memory {r['cache_pages']} pages of {r['page_bytes']} B ({r['memory_bytes']/2**20:.2f} MiB){extra}\n")
    taus = sorted({x['tolerance'] for x in r['runs']})
    hdr = ("| backend | layout | access | " + " | ".join(f"faults τ={t:g}" for t in taus)
           + " | ×first (τ=1) | ×lower bound (τ=1) | faults/frame mean, max (τ=1) | triangles/frame (τ=1) | OS major, read MiB (τ=1) |")
    print(hdr); print("|" + "---|" * (hdr.count("|") - 1))
    rows = []
    for x in r['runs']:
        key = (x['backend'], x['layout'])
        if key not in rows:
            rows.append(key)
    for backend, lay in rows:
        runs = {x['tolerance']: x for x in r['runs'] if (x['backend'], x['layout']) == (backend, lay)}
        t1 = runs[taus[0]]
        os = t1.get('os')
        osv = f"{os['major']}, {os['read_bytes'] / 2**20:.1f}" if os else "-"
        ratio = t1['ratio_to_first']
        print(f"| {backend} | {lay} | {t1['access']['mode']} | " + " | ".join(f"{runs[t]['faults']:,}" for t in taus)
              + f" | {ratio:.3f} | {t1['ratio_to_lower_bound']:.1f} | {t1['faults_per_frame_mean']:.1f}, {t1['faults_per_frame_max']}"
              + f" | {t1['triangles_per_frame_mean']:,.0f} | {osv} |")
