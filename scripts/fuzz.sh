#!/usr/bin/env bash
# Builds the libFuzzer targets (tests/fuzz) with clang, AddressSanitizer and UndefinedBehaviorSanitizer
# in build-fuzz, replays every checked-in regression input, then fuzzes each target for FUZZ_SECONDS
# seconds (default 10) from its seed corpus. A crash, sanitizer report or timeout fails the run and
# leaves the input in build-fuzz/findings/<target>/ (copy it to tests/fuzz/regressions/<target>/
# once fixed). FUZZ_SECONDS=600 bash scripts/fuzz.sh fuzzes for longer.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD="${FLAMERIG_FUZZ_BUILD_DIR:-build-fuzz}"
SECONDS_PER_TARGET="${FUZZ_SECONDS:-10}"
CXX_BIN="$(command -v clang++-14 || command -v clang++)"
CC_BIN="$(command -v clang-14 || command -v clang)"
cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_COMPILER="$CXX_BIN" \
  -DCMAKE_C_COMPILER="$CC_BIN" -DFLAMERIG_FUZZ=ON -DFLAMERIG_BUILD_TESTS=OFF -DFLAMERIG_MPI=OFF \
  > "$BUILD.configure.log" 2>&1 || { cat "$BUILD.configure.log"; exit 1; }
cmake --build "$BUILD" --target fuzz_all -j "$(nproc)"
export ASAN_OPTIONS="detect_leaks=0:allocator_may_return_null=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
status=0
for bin in "$BUILD"/tests/fuzz/fuzz_*; do
  target="$(basename "$bin")"; target="${target#fuzz_}"
  corpus="$BUILD/corpus/$target"; findings="$BUILD/findings/$target"
  rm -rf "$corpus" "$findings"; mkdir -p "$corpus" "$findings"
  cp -r tests/fuzz/corpus/"$target"/. "$corpus"/ 2>/dev/null || true
  if [ -d tests/fuzz/regressions/"$target" ]; then
    "$bin" -rss_limit_mb=2048 -timeout=20 tests/fuzz/regressions/"$target"/* > "$findings/replay.log" 2>&1 \
      || { echo "fuzz $target: a regression input fails again"; tail -30 "$findings/replay.log"; status=1; }
  fi
  if "$bin" -max_total_time="$SECONDS_PER_TARGET" -rss_limit_mb=2048 -timeout=20 -max_len=65536 \
       -artifact_prefix="$findings/" "$corpus" > "$findings/fuzz.log" 2>&1; then
    runs=$(grep -o 'stat::number_of_executed_units: [0-9]*' "$findings/fuzz.log" | awk '{print $2}')
    [ -n "$runs" ] || runs=$(grep -oE '#[0-9]+' "$findings/fuzz.log" | tail -1 | tr -d '#')
    echo "fuzz $target: ${runs:-?} executions in ${SECONDS_PER_TARGET} s, no finding"
  else
    echo "fuzz $target: FINDING (input in $findings)"; tail -40 "$findings/fuzz.log"; status=1
  fi
done
exit $status
