#!/usr/bin/env bash
# Runs the libFuzzer targets of a FLUXGRAPH_FUZZ build (tests/fuzz/), each for
# a bounded time, from its checked-in corpus and regression inputs.
#   tools/fuzz.sh [build-dir] [seconds-per-target] [target...]
#   (defaults: build-sanitize, 30, all of job toml_scene xml_scene obj ply image)
# New inputs go to <build-dir>/fuzz/corpus-<target>/ (the checked-in corpus is
# only read); a crash, a hang over 10 s or an allocation over 2 GB leaves its
# input in <build-dir>/fuzz/findings-<target>/ and makes this script fail.
# Copy such an input to tests/fuzz/regressions/<target>/ once it is fixed.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir="${1:-build-sanitize}"
seconds="${2:-30}"
shift $(( $# < 2 ? $# : 2 ))
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(job toml_scene xml_scene obj ply image)
source_dir="$PWD"
supp="$source_dir/tools/sanitizers"
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:suppressions=$supp/asan.supp}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$supp/lsan.supp:print_suppressions=0}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1:suppressions=$supp/ubsan.supp}"

failed=()
for target in "${targets[@]}"; do
  binary="$build_dir/fuzz/fuzz_$target"
  [ -x "$binary" ] || { echo "fuzz: $binary missing (configure with -DFLUXGRAPH_FUZZ=ON)" >&2; exit 2; }
  work="$build_dir/fuzz/corpus-$target"
  findings="$build_dir/fuzz/findings-$target"
  log="$build_dir/fuzz/fuzz_$target.log"
  mkdir -p "$work" "$findings"
  status=0
  # -timeout: a hang is one input over 10 s; -rss_limit_mb and -malloc_limit_mb:
  # a process over 2 GB, or one allocation over 2 GB, is a finding.
  # FLUXGRAPH_FUZZ_SEED fixes libFuzzer's random choices, so that a run of
  # the suite (tools/test.sh --sanitize) tries the same inputs every time.
  seed_option=()
  [ -z "${FLUXGRAPH_FUZZ_SEED:-}" ] || seed_option=(-seed="$FLUXGRAPH_FUZZ_SEED")
  "$binary" "${seed_option[@]}" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=2048 \
    -print_final_stats=1 -artifact_prefix="$findings/" \
    "$work" "tests/fuzz/corpus/$target" "tests/fuzz/regressions/$target" >"$log" 2>&1 || status=$?
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
  rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$log" | tail -1)
  if [ "$status" -eq 0 ]; then
    echo "fuzz_$target: ${runs:-?} executions in ${seconds} s, peak RSS ${rss:-?} MB, no findings"
  else
    echo "fuzz_$target: FAILED (exit $status) after ${runs:-?} executions; input in $findings/, log $log" >&2
    grep -E "^==[0-9]+==ERROR|SUMMARY|ALARM|out-of-memory|runtime error" "$log" | head -5 >&2 || true
    failed+=("$target")
  fi
done
[ ${#failed[@]} -eq 0 ] || { echo "fuzz: findings in ${failed[*]}" >&2; exit 1; }
