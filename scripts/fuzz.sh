#!/usr/bin/env bash
# Builds the libFuzzer targets (fuzz/) with clang-14, ASan and UBSan into build-fuzz/, then fuzzes each target for
# SECONDS_PER_TARGET seconds on its corpus (build-fuzz/corpus/<target>/, seeded from fuzz/corpus/<target>/).
# Exits non-zero if any target crashed, leaked, hung (>10 s per input), went over FUZZ_RSS_LIMIT_MB of RSS (default
# 1024, ASan included: the targets idle at 350-500 MB) or asked for more than FUZZ_MALLOC_LIMIT_MB in one allocation
# (default 256; the decoders' legitimate allocations for libFuzzer's inputs of at most 4 KB stay under 100 MB, so a
# decompression bomb fails here), or violated a property; the offending input is printed and kept in
# build-fuzz/artifacts/<target>/. Reproduce with
#   build-fuzz/fuzz/fuzz_<target> build-fuzz/artifacts/<target>/crash-...
# and, once fixed, copy it to fuzz/corpus/<target>/ so the ctest fuzz_replay_<target> keeps it as a regression.
# Usage: scripts/fuzz.sh [SECONDS_PER_TARGET (default 60)] [TARGET...]   (targets: fuzz/fuzz_<target>.cpp)
# Env: FUZZ_BUILD_DIR (default build-fuzz), FUZZ_JOBS (build parallelism, default nproc), FUZZ_RSS_LIMIT_MB,
# FUZZ_MALLOC_LIMIT_MB (above).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

SECONDS_PER_TARGET="${1:-60}"
[ $# -gt 0 ] && shift
if ! [[ "$SECONDS_PER_TARGET" =~ ^[0-9]+$ ]] || [ "$SECONDS_PER_TARGET" -lt 1 ]; then
  echo "fuzz.sh: SECONDS_PER_TARGET must be a whole number >= 1, not '$SECONDS_PER_TARGET'" >&2
  exit 2
fi
BUILD_DIR="${FUZZ_BUILD_DIR:-build-fuzz}"
RSS_LIMIT_MB="${FUZZ_RSS_LIMIT_MB:-1024}"
MALLOC_LIMIT_MB="${FUZZ_MALLOC_LIMIT_MB:-256}"

targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  for f in fuzz/fuzz_*.cpp; do
    t="$(basename "$f" .cpp)"
    t="${t#fuzz_}"
    # upload_assembler only when the server has it (fuzz/CMakeLists.txt checks the same).
    [ "$t" = upload_assembler ] && [ ! -f server/upload_assembler.h ] && continue
    targets+=("$t")
  done
fi
for t in "${targets[@]}"; do
  if [ ! -f "fuzz/fuzz_$t.cpp" ]; then
    echo "fuzz.sh: unknown target '$t'; targets are the fuzz/fuzz_<target>.cpp files" >&2
    exit 2
  fi
done

scripts/setup.sh --no-build  # installs clang-14 and libclang-rt-14-dev among the rest, if missing
# CMAKE_BUILD_TYPE=Fuzz has no flags of its own: fuzz/CMakeLists.txt adds -O1, line tables and the sanitizers.
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 \
  -DCMAKE_BUILD_TYPE=Fuzz -DSURFACER_BUILD_FUZZ=ON -DSURFACER_BUILD_TESTS=OFF -DSURFACER_BUILD_BENCH=OFF >/dev/null
build_start=$SECONDS
cmake --build "$BUILD_DIR" -j"${FUZZ_JOBS:-$(nproc)}" --target "${targets[@]/#/fuzz_}"
echo "fuzz.sh: built ${#targets[@]} targets in $((SECONDS - build_start)) s"

export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1}"
failed=()
for t in "${targets[@]}"; do
  corpus="$BUILD_DIR/corpus/$t"
  artifacts="$BUILD_DIR/artifacts/$t"
  mkdir -p "$corpus" "$artifacts"
  cp -n fuzz/corpus/"$t"/* "$corpus"/ 2>/dev/null || true
  log="$BUILD_DIR/artifacts/$t.log"
  echo "fuzz.sh: fuzz_$t for $SECONDS_PER_TARGET s (log: $log)"
  dict=()
  [ -f "fuzz/$t.dict" ] && dict=(-dict="fuzz/$t.dict")
  status=0
  "$BUILD_DIR/fuzz/fuzz_$t" "$corpus" -max_total_time="$SECONDS_PER_TARGET" -timeout=10 -rss_limit_mb="$RSS_LIMIT_MB" \
    -malloc_limit_mb="$MALLOC_LIMIT_MB" -artifact_prefix="$artifacts/" -print_final_stats=1 "${dict[@]}" >"$log" 2>&1 || status=$?
  grep -E "^#[0-9]+[[:space:]]+DONE|^Done [0-9]+ runs|stat::number_of_executed_units|stat::average_exec_per_sec" "$log" || true
  if [ "$status" -ne 0 ]; then
    failed+=("$t")
    echo "fuzz.sh: fuzz_$t FAILED (exit $status); from $log:" >&2
    grep -E "ERROR:|SUMMARY:|runtime error|fuzz property violated|deadly signal|out-of-memory|timeout after|leak" \
      "$log" | head -n 10 >&2 || true
    grep -E "^ +#[0-9]+ 0x" "$log" | head -n 25 >&2 || true
    inputs="$(grep -oE "Test unit written to [^ ]+" "$log" | awk '{print $NF}' | sort -u | tr '\n' ' ')"
    echo "fuzz.sh: offending input: ${inputs:-see $log}" >&2
    echo "fuzz.sh: reproduce: $BUILD_DIR/fuzz/fuzz_$t ${inputs:-<input>}" >&2
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz.sh: ${#failed[@]} target(s) failed: ${failed[*]}" >&2
  exit 1
fi
echo "fuzz.sh: all ${#targets[@]} targets ran ${SECONDS_PER_TARGET} s each without a failure"
