#!/usr/bin/env bash
# Makes the README's screenshots of `relief fly` under Xvfb (needs xvfb, xdotool, x11-apps for
# xwd, imagemagick): a real DEM in flight, and the frozen mesh seen from outside.
# Usage: bash tools/screenshots.sh [OUT_DIR]   (default data/screenshots)
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-data/screenshots}"
mkdir -p "$out"
work="$(mktemp -d)"
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
export XDG_RUNTIME_DIR="$work" DISPLAY=:97
cargo build --release --quiet
relief=target/release/relief
# Fuji's Terrain-RGB tile has no georeferencing: 30 m posts give it its real proportions roughly.
$relief convert ../shared/data/dem/fuji_terrain_rgb.png "$work/fuji.relief" --spacing 30 --quiet >/dev/null
Xvfb :97 -screen 0 1280x800x24 >/dev/null 2>&1 &
sleep 1
shot() { xwd -root -display :97 | /usr/bin/convert xwd:- -resize 1024x640 -colors 256 "PNG8:$1"; }
window() { xdotool search --name relief | head -1; }

# 1. In flight, τ = 1 px.
$relief fly "$work/fuji.relief" --width 1280 --height 800 --eye 7680,-4000,2600 --look 7680,7680,2200 --quiet &
sleep 8
shot "$out/fly_fuji.png"
kill %2; sleep 1

# 2. Refinement frozen at a low view (τ = 3 px, wireframe), then flown back, up, and looking down.
$relief fly "$work/fuji.relief" --width 1280 --height 800 --eye 7680,-2000,2600 --look 7680,7680,1800 \
  --tolerance 3 --wireframe --quiet &
sleep 6
w=$(window)
xdotool windowfocus "$w"
xdotool key --window "$w" f
sleep 0.5
xdotool keydown --window "$w" s keydown --window "$w" e
sleep 12
xdotool keyup --window "$w" s keyup --window "$w" e
xdotool mousemove --window "$w" 700 300 mousedown 1
for _ in $(seq 7); do xdotool mousemove_relative 0 20; sleep 0.1; done
xdotool mouseup 1
sleep 2
shot "$out/frozen_mesh_fuji.png"
echo "wrote $out/fly_fuji.png $out/frozen_mesh_fuji.png"

# 3. Render-time looks (headless `relief render`, no window): ETOPO20 as it is, exaggerated 40
#    times, and exaggerated with the viridis ramp under a low western sun.
$relief convert ../shared/data/dem/etopo20_world.tif "$work/etopo20.relief" --quiet >/dev/null
view=(--eye 12000000,-2000000,100000 --look 12000000,9000000,-75000 --width 960 --height 600)
# The same view unexaggerated: the camera 40 times as high, as the exaggerated scene puts it.
$relief render "$work/etopo20.relief" --eye 12000000,-2000000,4000000 --look 12000000,9000000,-3000000 \
  --width 960 --height 600 --out "$out/looks_etopo_x1.png" >/dev/null
$relief render "$work/etopo20.relief" "${view[@]}" --z-exaggeration 40 --out "$out/looks_etopo_x40.png" >/dev/null
$relief render "$work/etopo20.relief" "${view[@]}" --z-exaggeration 40 --ramp viridis --sun-azimuth 270 \
  --sun-altitude 25 --out "$out/looks_etopo_x40_viridis.png" >/dev/null
# Real imagery of the same place (data/imagery: NASA's world image, with its world file).
$relief render "$work/etopo20.relief" "${view[@]}" --z-exaggeration 40 --imagery data/imagery/earth_2048.jpg \
  --out "$out/looks_etopo_x40_draped.png" >/dev/null
echo "wrote $out/looks_etopo_x1.png $out/looks_etopo_x40.png $out/looks_etopo_x40_viridis.png $out/looks_etopo_x40_draped.png"
