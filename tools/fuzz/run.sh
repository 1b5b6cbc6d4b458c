#!/usr/bin/env bash
# Builds the libFuzzer targets with clang (-fsanitize=fuzzer,address,undefined)
# and runs each for a while:
#     tools/fuzz/run.sh [seconds per target]     (default 30)
# Corpora grow in .build/fuzz/corpus/<target> (seeded from test/vectors);
# a crash leaves its input in .build/fuzz/artifacts/. Prints executions and
# crashes per target; exits non-zero if any target crashed or failed to build.
# Needs clang with the libFuzzer runtime (Debian: clang libclang-rt-14-dev).
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
SECS="${1:-30}"
case "$SECS" in '' | *[!0-9]*) echo "usage: $0 [seconds per target]" >&2; exit 2 ;; esac
CXX="${CXX_FUZZ:-clang++}"
OUT=.build/fuzz
mkdir -p "$OUT/artifacts"
SRC="$(echo src/*.cpp)"  # the whole core: a new file cannot be forgotten here
FLAGS="-std=gnu++11 -g -O1 -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all -Isrc -Iconfig"

status=0
for target in fuzz_map_decode fuzz_m721 fuzz_planner; do
  if ! $CXX $FLAGS $SRC "tools/fuzz/$target.cpp" -o "$OUT/$target"; then
    echo "$target: BUILD FAILED" >&2
    status=1
    continue
  fi
  corpus="$OUT/corpus/$target"
  mkdir -p "$corpus"
  extra=()
  if [ "$target" = fuzz_map_decode ]; then
    # Seeds: every vector as a full image (mode byte 0) and the append records (mode 1).
    for f in test/vectors/*.bkm; do
      { printf '\x00'; cat "$f"; } > "$corpus/seed_$(basename "$f" .bkm)"
    done
    for f in test/vectors/*.bkr; do
      { printf '\x01'; cat "$f"; } > "$corpus/seed_$(basename "$f" .bkr)"
    done
  elif [ "$target" = fuzz_m721 ]; then
    for f in test/vectors/*.m721; do
      grep -v '^;' "$f" > "$corpus/seed_$(basename "$f" .m721)"
    done
    extra=(-dict=tools/fuzz/m721.dict -max_len=8192)
  else
    # fuzz_planner builds its map and print from the bytes themselves: no seeds
    extra=(-max_len=4096)
  fi
  log="$OUT/$target.log"
  "$OUT/$target" "$corpus" -max_total_time="$SECS" -print_final_stats=1 \
    -artifact_prefix="$OUT/artifacts/$target-" "${extra[@]}" > "$log" 2>&1
  rc=$?
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  crashes=$(grep -c '^==[0-9]*==ERROR\|^SUMMARY: \|deadly signal' "$log")
  if [ "$rc" -ne 0 ]; then
    status=1
    echo "$target: FAILED (exit $rc) after ${execs:-?} executions; see $log and $OUT/artifacts/"
    grep -m5 'ERROR\|SUMMARY\|Test unit written' "$log"
  else
    echo "$target: ${execs:-?} executions in ${SECS} s, 0 crashes (corpus $(ls "$corpus" | wc -l) inputs)"
  fi
done
exit $status
