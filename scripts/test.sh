#!/usr/bin/env bash
# The test command: installs what is missing, builds, and runs the whole test suite with CTest.
# Labels: unit (fast, no subprocesses), integration (runs the flamerig binary or mrcal's Python tools),
# slow (longer end-to-end runs). Pass CTest arguments through, e.g. scripts/test.sh -L unit.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
cd "${FLAMERIG_BUILD_DIR:-build}"
# A per-test limit, so that a hung test fails instead of holding CI to its own limit.
ctest --output-on-failure --timeout 300 -j "$(nproc)" "$@"
