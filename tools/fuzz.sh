#!/usr/bin/env bash
# Fuzzes every reader of outside bytes (issue 8): DEMs, terrain files, flight paths, meshes, VDT
# and meta-node files. Not part of CI. Usage, from anywhere:
#   bash tools/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]      (default: 30 s each, all targets)
# Installs cargo-fuzz when missing. cargo-fuzz needs nightly compiler flags; the stable toolchain
# accepts them with RUSTC_BOOTSTRAP=1. Built optimised with debug assertions (overflow checks),
# without a sanitizer (-s none: the build of wgpu & co. under ASan takes too long on 2 cores).
# A crash leaves its input in fuzz/artifacts/TARGET/; replay it with
#   RUSTC_BOOTSTRAP=1 cargo fuzz run -O -a -s none TARGET fuzz/artifacts/TARGET/crash-…
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(dem terrain path mesh vdt metanode)
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
export RUSTC_BOOTSTRAP=1
cargo fuzz build -O -a -s none
failed=()
for t in "${targets[@]}"; do
  # Work on a copy of the committed seeds, so the repository's corpus stays small.
  work="fuzz/corpus-run/$t"
  mkdir -p "$work" fuzz/logs
  cp -n fuzz/corpus/"$t"/seed-* "$work"/ 2>/dev/null || true
  echo "== $t: $seconds s" >&2
  set +e
  cargo fuzz run -O -a -s none "$t" "$work" -- \
    -max_total_time="$seconds" -rss_limit_mb=2048 -malloc_limit_mb=1024 -max_len=65536 -timeout=10 \
    -print_final_stats=1 >"fuzz/logs/$t.log" 2>&1
  rc=$?
  set -e
  grep -E '^stat::(number_of_executed_units|average_exec_per_sec|peak_rss_mb)|panicked|SUMMARY|crash-|oom-|timeout-' "fuzz/logs/$t.log" >&2 || true
  [ $rc -eq 0 ] || failed+=("$t")
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "tools/fuzz.sh: crashes in: ${failed[*]} (inputs in fuzz/artifacts/, logs in fuzz/logs/)" >&2
  exit 1
fi
echo "tools/fuzz.sh: no crash in ${targets[*]} ($seconds s each)" >&2
