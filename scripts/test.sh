#!/usr/bin/env bash
# The test command: installs what is missing, builds, and runs the whole test suite with CTest.
# Labels: unit (fast, no subprocesses), integration (runs the flamerig binary or mrcal's Python tools),
# browser (headless Chromium), slow (over a minute under the sanitizers; tests/CMakeLists.txt). Pass
# CTest arguments through, e.g. scripts/test.sh -L unit.
#
# Then the hardening passes (issue 9), chosen by FLAMERIG_HARDENING:
#   tsan   the threaded capture tests (acquisition) under ThreadSanitizer        (build-tsan, ~1 min)
#   asan   the suite again under AddressSanitizer + UndefinedBehaviorSanitizer, built by clang at
#          -O1 in build-fuzz with the fuzz targets (scripts/fuzz.sh), but the test binaries labelled
#          slow (tests/CMakeLists.txt: the fit's, tomography's and end-to-end runs, 10 to 40 times
#          slower there; they took over 30 minutes); pipeline_calibrate_job_test reuses the ring
#          the plain build rendered (FLAMERIG_TEST_DATA_DIR)
#   fuzz   every fuzz target for FUZZ_SECONDS (default 10) after replaying its
#          checked-in regressions (scripts/fuzz.sh)                               (build-fuzz)
# The two share build-fuzz's libraries: whichever runs first builds them. GCC's -O3 ASan build of
# its own took over 35 minutes on two cores (400 s for fitting/renderer.cc alone; clang, 37 s).
# FLAMERIG_HARDENING="tsan asan fuzz" is the default in CI (CI=true), "" elsewhere; "all" = all three;
# "none" = none.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
(cd "${FLAMERIG_BUILD_DIR:-build}" &&
  # A per-test limit, so that a hung test fails instead of holding CI to its own limit.
  ctest --output-on-failure --timeout 300 -j "$(nproc)" "$@")

PASSES="${FLAMERIG_HARDENING-}"
if [ -z "${FLAMERIG_HARDENING+set}" ] && [ "${CI:-}" = "true" ]; then PASSES="tsan asan fuzz"; fi
if [ "$PASSES" = all ]; then PASSES="tsan asan fuzz"; fi
if [ "$PASSES" = none ]; then PASSES=""; fi

for pass in $PASSES; do
  case "$pass" in
    tsan)
      echo "== ThreadSanitizer: the capture daemon, recorder and simulated cameras =="
      FLAMERIG_BUILD_DIR=build-tsan \
        FLAMERIG_BUILD_TARGETS="acquisition_sim_test acquisition_capture_test acquisition_recording_test" \
        bash scripts/build.sh -DFLAMERIG_TSAN=ON -DFLAMERIG_MPI=OFF
      (cd build-tsan &&
        TSAN_OPTIONS="halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/../tests/tsan.supp" \
        ctest --output-on-failure --timeout 900 -j "$(nproc)" \
          -R "^(acquisition_sim_test|acquisition_capture_test|acquisition_recording_test)\.")
      ;;
    fuzz)
      echo "== libFuzzer: every parser of outside input =="
      bash scripts/fuzz.sh
      ;;
    asan)
      echo "== AddressSanitizer + UndefinedBehaviorSanitizer: the suite but its slow binaries =="
      FUZZ_WITH_TESTS=1 FUZZ_BUILD_ONLY=1 bash scripts/fuzz.sh
      (cd "${FLAMERIG_FUZZ_BUILD_DIR:-build-fuzz}" &&
        FLAMERIG_TEST_DATA_DIR="$PWD/../${FLAMERIG_BUILD_DIR:-build}/testdata" \
        ASAN_OPTIONS="detect_leaks=0:abort_on_error=1" \
        UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1" \
        ctest --output-on-failure --timeout 900 -j "$(nproc)" -LE slow -E '_NOT_BUILT$')
      ;;
    *) echo "FLAMERIG_HARDENING: unknown pass '$pass' (tsan, fuzz, asan, all, none)"; exit 2 ;;
  esac
done
