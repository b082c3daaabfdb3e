#!/usr/bin/env bash
# Paged imagery's figures in BENCHMARKS.md ("Imagery larger than memory, paged (issue 22)"): a
# SYNTHETIC 16385² hz terrain with a SYNTHETIC 16384² RGB image of it, tiled once with
# `relief imagery`, flown headless along two 300-frame flyovers with the image paged; the low one
# again under a 1 GiB memory cap (../shared/tools/memlimit.sh, needs root) with the heights paged
# too. Prints the tiling's time and peak memory, then one row per flight.
#   bash tools/bench_imagery.sh DIR [RELIEF]      (DIR gets about 7 GB of files)
set -eu
DIR=${1:?usage: bench_imagery.sh DIR [RELIEF]}; R=${2:-target/release/relief}
S=$(dirname "$R")/relief-synth; CAP=$(dirname "$0")/../../shared/tools/memlimit.sh
mkdir -p "$DIR"; F=$DIR/synthetic_16385_h07.hz.relief; PNG=$DIR/synthetic_16384_imagery.png
T=$DIR/synthetic_16384_imagery.rimg
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
[ -f "$DIR/synthetic_16385_h07.tif" ] || "$S" "$DIR/synthetic_16385_h07.tif" --size 16385 --seed 1 --hurst 0.7
[ -f "$PNG" ] || "$S" "$PNG" --size 16384 --seed 1 --hurst 0.7 --format rgb-png
[ -f "$F" ] || "$R" convert "$DIR/synthetic_16385_h07.tif" "$F" --layout hz -q
sync; echo 3 > /proc/sys/vm/drop_caches || true
/usr/bin/time -f "%e s, peak RSS %M KiB" -o "$DIR/tiling.time" "$R" imagery "$PNG" "$T" --json -q > "$DIR/tiling.json"
echo "tiling: $(cat "$DIR/tiling.time"): $(cat "$DIR/tiling.json" | tr -d '\n ')"
# The whole image instead (decoded and held with its mip levels): what happens.
"$R" render "$F" --eye 80000,20000,4000 --look 80000,80000,1000 --imagery "$PNG" --out "$DIR/whole.png" -q \
  2> "$DIR/whole.err" && echo "whole image: rendered" || echo "whole image: $(tail -1 "$DIR/whole.err")"
"$R" path flyover "$F" --frames 300 --out "$DIR/fly300.json"
"$R" path flyover "$F" --frames 300 --clearance 300 --out "$DIR/low300.json"
# fly NAME PATH [CAP [ARGS]]: one flight, its peak RSS (KiB) in NAME.rss.
fly() {
  local name=$1 path=$2 cap=(); shift 2
  if [ $# -ge 1 ]; then cap=(bash "$CAP" "$1"); shift; fi
  /usr/bin/time -f "%M" -o "$DIR/$name.rss" "${cap[@]}" "$R" fly "$F" --path "$DIR/$path.json" \
    --imagery "$T" --stats "$DIR/${name}_stats.json" -q "$@"
}
fly fly300 fly300
fly low300 low300
sync; echo 3 > /proc/sys/vm/drop_caches || true
fly low300_cap1g low300 1G --gpu-memory 256M --imagery-gpu-memory 128M
python3 - "$DIR" <<'PY'
import json, sys
d = sys.argv[1]
print("| flight | frame ms median / max | triangles mean | imagery GPU max / pool | imagery upload median / max | tiles resident median | tiles uploaded | evicted | frames with fallbacks (total) | imagery step µs median / max | heights | peak RSS MiB |")
for name in ["fly300", "low300", "low300_cap1g"]:
    r = json.load(open(f"{d}/{name}_stats.json")); s = r["summary"]; fr = r["frames"]; g = [f["gpu_imagery"] for f in fr]
    h = "cached" if fr[0]["gpu_heights"]["cached"] else "resident"
    rss = int(open(f"{d}/{name}.rss").read().split()[-1]) / 1024
    print(f"| {name} | {s['frame_ms']['median']:.1f} / {s['frame_ms']['max']:.1f} | {s['triangles']['mean']:,.0f} | "
          f"{max(x['in_use_bytes'] for x in g):,} / {g[0]['budget_bytes']:,} | "
          f"{s['imagery_upload_bytes']['median']:,.0f} / {max(x['upload_bytes'] for x in g):,} | {s['imagery_tiles_resident']['median']:,.0f} | "
          f"{sum(x['tiles_uploaded'] for x in g):,} | {sum(x['evicted'] for x in g):,} | "
          f"{sum(1 for x in g if x['fallbacks'])} ({sum(x['fallbacks'] for x in g)}) | "
          f"{s['imagery_step_us']['median']:,.0f} / {s['imagery_step_us']['max']:,.0f} | {h} | {rss:,.0f} |")
PY
