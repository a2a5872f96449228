#!/usr/bin/env bash
# Configures and builds flamerig in ./build (Release, Ninja). Warnings are errors when CI=true.
# Extra CMake arguments pass through, e.g. scripts/build.sh -DFLAMERIG_SANITIZE=ON.
# FLAMERIG_BUILD_DIR picks another folder; FLAMERIG_BUILD_TARGETS="a b" builds only those targets.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR="${FLAMERIG_BUILD_DIR:-build}"
WERROR=OFF
if [ "${CI:-}" = "true" ]; then WERROR=ON; fi
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DFLAMERIG_WERROR="$WERROR" "$@"
if [ -n "${FLAMERIG_BUILD_TARGETS:-}" ]; then
  # shellcheck disable=SC2086
  cmake --build "$BUILD_DIR" -j "$(nproc)" --target $FLAMERIG_BUILD_TARGETS
else
  cmake --build "$BUILD_DIR" -j "$(nproc)"
fi
