#!/usr/bin/env python3
"""Non-square DEMs before and after padding stopped being stored: file size (against the DEM's own
posts x 12 bytes) and conversion time, per layout, two `relief` builds in one run.

    python3 tools/bench_non_square.py OLD_RELIEF NEW_RELIEF DEM [DEM ...]

Each (build, DEM, layout) is converted REPEAT times (default 5, env REPEAT), alternating builds so
that machine noise falls on both; the table gives medians. Outputs go to a temporary directory
(env OUT_DIR to keep them); the page cache is warm (the DEM is read once before timing).
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile

LAYOUTS = os.environ.get("LAYOUTS", "row-major tiled interleaved embedded hz").split()
REPEAT = int(os.environ.get("REPEAT", "5"))


def convert(binary, dem, layout, out):
    r = subprocess.run([binary, "convert", "--quiet", "--json", "--layout", layout, dem, out],
                       check=True, capture_output=True, text=True)
    j = json.loads(r.stdout)
    size = os.path.getsize(out)
    os.remove(out)
    return j, size


def main():
    old, new, dems = sys.argv[1], sys.argv[2], sys.argv[3:]
    out_dir = os.environ.get("OUT_DIR") or tempfile.mkdtemp()
    print("| DEM | posts | grid | layout | file before | file after | before / posts×12 B | after / posts×12 B "
          "| convert s before | convert s after | after / before |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for dem in dems:
        with open(dem, "rb") as f:
            while f.read(1 << 24):
                pass
        for layout in LAYOUTS:
            runs = {old: [], new: []}
            sizes = {}
            for _ in range(REPEAT):
                for b in (old, new):
                    j, size = convert(b, dem, layout, os.path.join(out_dir, "bench.relief"))
                    runs[b].append(j["seconds"])
                    sizes[b] = (size, j)
            j = sizes[new][1]
            own = j["source_width"] * j["source_height"] * 12
            t_old, t_new = statistics.median(runs[old]), statistics.median(runs[new])
            mib = lambda b: f"{b / 2**20:.1f} MiB"
            print(f"| {os.path.basename(dem)} | {j['source_width']} × {j['source_height']} | {j['grid_size']}² "
                  f"| {layout} | {mib(sizes[old][0])} | {mib(sizes[new][0])} | {sizes[old][0] / own:.2f} "
                  f"| {sizes[new][0] / own:.2f} | {t_old:.3f} | {t_new:.3f} | {t_new / t_old:.2f} |", flush=True)


if __name__ == "__main__":
    main()
