#!/usr/bin/env bash
# Conversion benchmark: for each SYNTHETIC DEM given, convert it into every layout and print a
# Markdown table row per run: vertices/s, wall time, peak anonymous RSS (relief's own sampler) and
# peak total RSS (/usr/bin/time -v, which also counts mapped file pages).
#
#   bash tools/bench_convert.sh /work/bench/synthetic_4097.tif [more.tif ...]
#
# Set OUT_DIR for the outputs (default: a temporary directory, removed afterwards).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet --bin relief
bin=target/release/relief
out_dir=${OUT_DIR:-$(mktemp -d)}
layouts=${LAYOUTS:-"row-major tiled interleaved embedded hz"}
echo "| input | layout | grid | records | file | wall s | M vertices/s | read s | fill s | bounds s | layout s | write s | peak anon RSS | peak RSS (time -v) |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
for dem in "$@"; do
  for layout in $layouts; do
    out="$out_dir/bench.$layout.relief"
    json=$(/usr/bin/time -v -o "$out_dir/time.txt" "$bin" convert --quiet --json --layout "$layout" "$dem" "$out")
    maxrss_kb=$(awk -F: '/Maximum resident set size/ {gsub(/ /,"",$2); print $2}' "$out_dir/time.txt")
    python3 - "$dem" "$layout" "$maxrss_kb" <<PY
import json, sys, os
r = json.loads('''$json''')
dem, layout, maxrss = sys.argv[1], sys.argv[2], int(sys.argv[3])
s = r["steps"]
mib = lambda b: f"{b / 2**20:.0f} MiB"
print(f"| {os.path.basename(dem)} | {layout} | {r['grid_size']}² | {r['records']} | {mib(r['file_bytes'])} | {r['seconds']:.2f} | {r['vertices_per_s'] / 1e6:.1f} | {s['read']:.2f} | {s['fill']:.2f} | {s['bounds']:.2f} | {s['layout']:.2f} | {s['write']:.2f} | {mib(r['peak_rss_anon_bytes'])} | {mib(maxrss * 1024)} |")
PY
    rm -f "$out"
  done
done
[ -n "${OUT_DIR:-}" ] || rm -rf "$out_dir"
