#!/usr/bin/env bash
# The GPU height cache's figures in BENCHMARKS.md ("GPU height cache (issue 18)"): a SYNTHETIC
# 32769² hz terrain flown along two 300-frame flyovers with 256 MiB of GPU heights, once under a
# 1 GiB memory cap (../shared/tools/memlimit.sh, needs root), then one summary row per flight.
#   bash tools/bench_height_cache.sh DIR [RELIEF]      (DIR gets the terrain, about 17 GB at peak)
set -eu
DIR=${1:?usage: bench_height_cache.sh DIR [RELIEF]}; R=${2:-target/release/relief}
S=$(dirname "$R")/relief-synth; CAP=$(dirname "$0")/../../shared/tools/memlimit.sh
mkdir -p "$DIR"; F=$DIR/synthetic_32769_h07.hz.relief
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
if [ ! -f "$F" ]; then
  "$S" "$DIR/synthetic_32769_h07.tif" --size 32769 --seed 1 --hurst 0.7
  "$R" convert "$DIR/synthetic_32769_h07.tif" "$F" --layout hz -q
fi
"$R" path flyover "$F" --frames 300 --out "$DIR/fly300.json"
"$R" path flyover "$F" --frames 300 --clearance 300 --out "$DIR/low300.json"
# fly NAME PATH [CAP]: one flight, its peak RSS (KiB) in NAME.rss.
fly() {
  local cap=(); [ $# -ge 3 ] && cap=(bash "$CAP" "$3")
  /usr/bin/time -f "%M" -o "$DIR/$1.rss" "${cap[@]}" "$R" fly "$F" --path "$DIR/$2.json" \
    --gpu-memory 256M --gpu-upload 16M --stats "$DIR/$1_stats.json" -q
}
fly fly300 fly300
sync; echo 3 > /proc/sys/vm/drop_caches || true
fly cap1g fly300 1G
fly low300 low300
python3 - "$DIR" <<'PY'
import json, sys
d = sys.argv[1]
print("| path | frame ms median / max | render ms median | triangles mean | GPU heights max / budget | height upload median / max | tiles resident median | tiles uploaded | evicted | frames with fallbacks (total) | cache step µs median / max | peak RSS MiB |")
for name in ["fly300", "cap1g", "low300"]:
    r = json.load(open(f"{d}/{name}_stats.json")); s = r["summary"]; fr = r["frames"]; g = [f["gpu_heights"] for f in fr]
    rss = int(open(f"{d}/{name}.rss").read().split()[-1]) / 1024
    print(f"| {name} | {s['frame_ms']['median']:.1f} / {s['frame_ms']['max']:.1f} | {s['render_ms']['median']:.1f} | "
          f"{s['triangles']['mean']:,.0f} | {max(x['in_use_bytes'] for x in g):,} / {g[0]['budget_bytes']:,} | "
          f"{s['height_upload_bytes']['median']:,.0f} / {max(x['upload_bytes'] for x in g):,} | {s['tiles_resident']['median']:,.0f} | "
          f"{sum(x['tiles_uploaded'] for x in g):,} | {sum(x['evicted'] for x in g):,} | "
          f"{sum(1 for x in g if x['fallbacks'])} ({sum(x['fallbacks'] for x in g)}) | "
          f"{s['height_step_us']['median']:,.0f} / {s['height_step_us']['max']:,.0f} | {rss:,.0f} |")
PY
