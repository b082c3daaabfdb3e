#!/usr/bin/env bash
# The project's test command (README, .ci/run): installs what the tests need, then runs them.
# Tests read real DEMs from ../shared/data (beside this checkout).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -d ../shared/data/dem ]; then
  echo "tools/test.sh: ../shared/data/dem not found beside this checkout (the tests use its real DEMs)" >&2
  exit 1
fi
cargo test --locked --all-targets
