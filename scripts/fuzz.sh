#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz) with clang, AddressSanitizer and UndefinedBehaviorSanitizer
# in build-fuzz, replays every checked-in regression input, then fuzzes each target for FUZZ_SECONDS
# seconds (default 10) from its seed corpus. A crash, sanitizer report or timeout fails the run and
# leaves the input in build-fuzz/findings/<target>/ (copy it to tests/fuzz/regressions/<target>/
# once fixed). FUZZ_SECONDS=600 bash scripts/fuzz.sh fuzzes for longer.
#
# The build is -O1 with line tables (CMake's build type Sanitize), as OSS-Fuzz builds. The same
# folder serves scripts/test.sh's asan pass, which runs the GoogleTest suite under these sanitizers:
# FUZZ_WITH_TESTS=1 builds the suite there too (but the binaries labelled slow, which that pass
# leaves out), and FUZZ_BUILD_ONLY=1 stops after the build. One clang build serves both passes:
# they had a build each, GCC's ASan build taking over 35 minutes, and CI no longer finished
# within its 90.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD="${FLAMERIG_FUZZ_BUILD_DIR:-build-fuzz}"
SECONDS_PER_TARGET="${FUZZ_SECONDS:-10}"
CXX_BIN="$(command -v clang++-14 || command -v clang++)"
CC_BIN="$(command -v clang-14 || command -v clang)"
TESTS=OFF
if [ -n "${FUZZ_WITH_TESTS:-}" ]; then TESTS=ON; fi
mkdir -p "$BUILD"
cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Sanitize -DCMAKE_CXX_COMPILER="$CXX_BIN" \
  -DCMAKE_C_COMPILER="$CC_BIN" -DFLAMERIG_FUZZ=ON -DFLAMERIG_BUILD_TESTS="$TESTS" -DFLAMERIG_MPI=OFF \
  > "$BUILD/configure.log" 2>&1 || { cat "$BUILD/configure.log"; exit 1; }
if [ "$TESTS" = ON ]; then
  # The suite but its slow binaries (the asan pass leaves them out), and the fuzz targets.
  cmake --build "$BUILD" -j "$(nproc)" --target tests_not_slow fuzz_all
else
  cmake --build "$BUILD" --target fuzz_all -j "$(nproc)"
fi
if [ -n "${FUZZ_BUILD_ONLY:-}" ]; then exit 0; fi
# Full stacks on allocations, so that a report says whose allocation it was.
export ASAN_OPTIONS="detect_leaks=0:allocator_may_return_null=1:fast_unwind_on_malloc=0"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
status=0
for bin in "$BUILD"/tests/fuzz/fuzz_*; do
  target="$(basename "$bin")"; target="${target#fuzz_}"
  corpus="$BUILD/corpus/$target"; findings="$BUILD/findings/$target"
  rm -rf "$corpus" "$findings"; mkdir -p "$corpus" "$findings"
  cp -r tests/fuzz/corpus/"$target"/. "$corpus"/ 2>/dev/null || true
  # OpenVDB's reader trusts the sizes a file states (a name length, a compressed block size): a
  # damaged .vdb makes it ask for gigabytes to terabytes before the read fails. Without sanitizers
  # that is std::bad_alloc, which ReadVdb turns into an error naming the file (a test checks it);
  # under ASan it is a report. Such reports (an out-of-memory whose allocation comes from
  # libopenvdb) are counted and fuzzing goes on; every other finding fails the run. A single
  # allocation over 1 GB is reported with its stack (-malloc_limit_mb): OpenVDB's allocation of a
  # 2.9 GB metadata name, freed and held in ASan's quarantine, then passed the 3 GB RSS limit in
  # a report that names no allocation (fuzz_vdb budgets ReadVdb's own fields at 256 MB).
  # (grep without -q at the pipe's end: -q exits at its first match, the grep before it dies of
  # SIGPIPE, and under pipefail the match read as none.)
  dependency_oom() {
    [ "$target" = vdb ] && grep -q "out-of-memory\|out of memory" "$1" &&
      grep -A40 -E "out-of-memory|out of memory" "$1" | grep "libopenvdb" > /dev/null
  }
  # The regressions, one at a time.
  for input in tests/fuzz/regressions/"$target"/*; do
    [ -f "$input" ] || continue
    "$bin" -rss_limit_mb=3072 -malloc_limit_mb=1024 -timeout=20 "$input" > "$findings/replay.log" 2>&1 ||
      dependency_oom "$findings/replay.log" ||
      { echo "fuzz $target: regression input $input fails again"; tail -30 "$findings/replay.log"; status=1; }
  done
  deadline=$(( $(date +%s) + SECONDS_PER_TARGET )); runs_total=0; dependency_ooms=0; verdict=""
  while [ -z "$verdict" ]; do
    left=$(( deadline - $(date +%s) )); [ "$left" -ge 1 ] || { verdict=ok; break; }
    rm -f "$findings"/crash-* "$findings"/oom-* "$findings"/timeout-*
    if "$bin" -max_total_time="$left" -rss_limit_mb=3072 -malloc_limit_mb=1024 -timeout=20 \
         -max_len=65536 -print_final_stats=1 -artifact_prefix="$findings/" "$corpus" \
         > "$findings/fuzz.log" 2>&1; then
      verdict=ok
    elif dependency_oom "$findings/fuzz.log"; then
      dependency_ooms=$((dependency_ooms + 1))
    else
      verdict=finding
    fi
    runs=$( (grep -o 'stat::number_of_executed_units: *[0-9]*' "$findings/fuzz.log" || true) |
      awk '{print $2}')
    [ -n "$runs" ] || runs=$( (grep -oE '^#[0-9]+' "$findings/fuzz.log" || true) | tail -1 | tr -d '#')
    runs_total=$(( runs_total + ${runs:-0} ))
  done
  if [ "$verdict" = ok ]; then
    cov=$( (grep -oE 'cov: [0-9]+' "$findings/fuzz.log" || true) | tail -1 | awk '{print $2}')
    note=""; [ "$dependency_ooms" -eq 0 ] || note=" ($dependency_ooms OpenVDB allocations of damaged sizes)"
    echo "fuzz $target: $runs_total executions in ${SECONDS_PER_TARGET} s, coverage ${cov:-?} edges, no finding$note"
  else
    echo "fuzz $target: FINDING (input in $findings)"; tail -40 "$findings/fuzz.log"; status=1
  fi
done
exit $status
