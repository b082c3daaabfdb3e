#!/usr/bin/env bash
# Builds the web viewer (src/web) into target/viewer: relief-core and the renderer compiled to
# wasm32-unknown-unknown, the JavaScript glue made by wasm-bindgen-cli of the version
# src/web/Cargo.toml pins, and the page. Installs the target and the CLI where missing (from
# crates.io: no binaries are downloaded). Then serve it: relief serve FILE.relief --viewer.
set -euo pipefail
cd "$(dirname "$0")/.."
version=$(sed -n 's/^wasm-bindgen = "=\([0-9.]*\)"/\1/p' src/web/Cargo.toml)
[ -n "$version" ] || { echo "tools/web.sh: no pinned wasm-bindgen in src/web/Cargo.toml" >&2; exit 1; }
if ! rustup target list --installed | grep -qx wasm32-unknown-unknown; then
    rustup target add wasm32-unknown-unknown
fi
if [ "$(wasm-bindgen --version 2>/dev/null | awk '{print $2}')" != "$version" ]; then
    # --locked where the CLI's own lock file resolves; a registry mirror without one of its
    # pinned versions needs the plain install (same CLI version, its dependencies resolved anew).
    cargo install --locked wasm-bindgen-cli --version "$version" || cargo install wasm-bindgen-cli --version "$version"
fi
cargo build --locked -p relief-web --target wasm32-unknown-unknown --profile web
out=target/viewer
mkdir -p "$out"
wasm-bindgen --target web --no-typescript --remove-name-section --remove-producers-section --out-dir "$out" target/wasm32-unknown-unknown/web/relief_web.wasm
cp src/web/index.html "$out/index.html"
wasm=$out/relief_web_bg.wasm
echo "tools/web.sh: $out ($(du -k "$wasm" | cut -f1) KiB wasm, $(gzip -9c "$wasm" | wc -c | awk '{printf "%d", $1/1024}') KiB gzipped)"
