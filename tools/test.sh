#!/usr/bin/env bash
# The project's test command (README, .ci/run): installs what the tests need, then runs them.
# Tests read real DEMs from ../shared/data (beside this checkout).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -d ../shared/data/dem ]; then
  echo "tools/test.sh: ../shared/data/dem not found beside this checkout (the tests use its real DEMs)" >&2
  exit 1
fi
# Rendering tests need Vulkan: without a GPU, Mesa's software driver (lavapipe); the window test
# needs Xvfb and xdotool. Install them on Debian/Ubuntu when missing (as root, or with sudo).
need=()
{ ldconfig -p 2>/dev/null | grep -q 'libvulkan\.so\.1' && ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1; } ||
  need+=(mesa-vulkan-drivers libvulkan1)
command -v xvfb-run >/dev/null || need+=(xvfb xauth)
command -v xdotool >/dev/null || need+=(xdotool)
# The coordinate-system tests compare with GDAL's own reading (gdalinfo, gdal_translate).
command -v gdalinfo >/dev/null || need+=(gdal-bin)
# The `gdal` feature (LERC, VRT, JPEG and the other formats only libgdal reads; ZSTD, LZW and
# Deflate GeoTIFFs are read natively) links the system's GDAL.
pkg-config --exists gdal 2>/dev/null || need+=(libgdal-dev pkg-config)
# The web viewer's test opens its page in Debian's headless Chromium (WebGL2 on SwiftShader).
{ [ -x /usr/lib/chromium/chromium-headless-shell ] || [ -x /usr/lib/chromium/chromium ]; } ||
  need+=(chromium-headless-shell)
# The sharded-conversion test runs tools/dask_convert.py on Dask (a venv where python3 lacks it).
python3 -c 'import dask.distributed' 2>/dev/null || python3 -c 'import venv, ensurepip' 2>/dev/null ||
  need+=(python3-venv)
if [ ${#need[@]} -gt 0 ] && command -v apt-get >/dev/null; then
  sudo=""; [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "tools/test.sh: installing ${need[*]}" >&2
  $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${need[@]}" >/dev/null
fi
if ! python3 -c 'import dask.distributed' 2>/dev/null; then
  if ! target/dask-venv/bin/python -c 'import dask.distributed' 2>/dev/null; then
    echo "tools/test.sh: installing dask[distributed] into target/dask-venv" >&2
    python3 -m venv target/dask-venv && target/dask-venv/bin/pip install --quiet 'dask[distributed]'
  fi
  export RELIEF_PYTHON="$PWD/target/dask-venv/bin/python"
fi
# Mesa warns when the runtime directory is missing.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ]; then
  export XDG_RUNTIME_DIR="$(mktemp -d)"
  chmod 700 "$XDG_RUNTIME_DIR"
fi
# The policy (ARCHITECTURE.md, "Policy"): formatting and lints, with the workspace's lint levels.
for c in rustfmt clippy; do
  { [ "$c" = rustfmt ] && cargo fmt --version >/dev/null 2>&1; } ||
    { [ "$c" = clippy ] && cargo clippy --version >/dev/null 2>&1; } ||
    rustup component add "$c"
done
cargo fmt --all --check
cargo clippy --locked --workspace --all-targets --features gdal -- -D warnings
# The web viewer: its wasm build linted too (the page's code compiles only there), then built
# into target/viewer for the browser test (tests/web).
rustup target list --installed | grep -qx wasm32-unknown-unknown || rustup target add wasm32-unknown-unknown
cargo clippy --locked -p relief-web --target wasm32-unknown-unknown -- -D warnings
bash tools/web.sh
cargo test --locked --workspace --all-targets --features gdal
