#!/usr/bin/env bash
# Fuzzes every reader of outside bytes (issue 8): DEMs (through detection and forced), terrain
# files (+ verify, an orbit and a refinement), flight paths, meshes, VDT files, meta-node files
# (every block), navigation over them, and page files (every page, then the per-frame fetch).
# Not part of CI or tools/test.sh. Usage, from anywhere:
#   bash tools/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]      (default: 30 s each, all targets)
# Installs cargo-fuzz when missing. cargo-fuzz needs nightly compiler flags; the stable toolchain
# accepts them with RUSTC_BOOTSTRAP=1. Built optimised with debug assertions (overflow checks),
# without a sanitizer (-s none: the library's readers are safe Rust over bounds-checked slices,
# and an ASan build of wgpu & co. takes too long on 2 cores). One target at a time, each in one
# process with one job and one worker (libFuzzer's default; an explicit -jobs=1 forks a worker that
# logs to ./fuzz-0.log instead); each run is bounded by -max_total_time, 2 GB of RSS, 1 GB per
# allocation and 10 s per input.
# A crash leaves its input in fuzz/artifacts/TARGET/; replay it with
#   RUSTC_BOOTSTRAP=1 cargo fuzz run -O -a -s none TARGET fuzz/artifacts/TARGET/crash-…
# Prints one line per target (executions, seconds, exec/s, result); logs in fuzz/logs/.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(dem dem_forced terrain path mesh vdt metanode navigate pages)
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
export RUSTC_BOOTSTRAP=1
cargo fuzz build -O -a -s none
failed=()
for t in "${targets[@]}"; do
  # Work on a copy of the committed seeds, so the repository's corpus stays small.
  work="fuzz/corpus-run/$t"
  mkdir -p "$work" fuzz/logs
  cp -n fuzz/corpus/"$t"/seed-* "$work"/ 2>/dev/null || true
  set +e
  cargo fuzz run -O -a -s none "$t" "$work" -- \
    -max_total_time="$seconds" -rss_limit_mb=2048 -malloc_limit_mb=1024 \
    -max_len=65536 -timeout=10 -print_final_stats=1 >"fuzz/logs/$t.log" 2>&1
  rc=$?
  set -e
  stat() { grep -E "^stat::$1:" "fuzz/logs/$t.log" | tail -1 | awk '{print $2}'; }
  result=clean
  if [ $rc -ne 0 ]; then
    result="CRASH: $(grep -hoE '(crash|oom|timeout|leak|slow-unit)-[0-9a-f]+' "fuzz/logs/$t.log" | head -1)"
    failed+=("$t")
  fi
  printf '%-11s %12s executions %5s s %8s exec/s  peak %5s MB  %s\n' "$t" "$(stat number_of_executed_units)" \
    "$seconds" "$(stat average_exec_per_sec)" "$(stat peak_rss_mb)" "$result"
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "tools/fuzz.sh: crashes in: ${failed[*]} (inputs in fuzz/artifacts/, logs in fuzz/logs/)" >&2
  exit 1
fi
echo "tools/fuzz.sh: no crash in ${targets[*]} ($seconds s each)" >&2
