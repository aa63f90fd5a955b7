#!/usr/bin/env bash
# Builds fluxgraph (Release) and runs the whole test suite with ctest.
#   tools/test.sh [build-dir]                (default: build)
# With --sanitize: a clang build with AddressSanitizer, UndefinedBehaviorSanitizer
# and the libFuzzer targets; runs the tests labelled `sanitize` (loaders, job
# parser, scheduler and jobs/, the passes, the CLI), then each fuzz target for
# FLUXGRAPH_FUZZ_SECONDS (default 20) seconds (tools/fuzz.sh).
#   tools/test.sh --sanitize [build-dir]     (default: build-sanitize)
set -euo pipefail
cd "$(dirname "$0")/.."
sanitize=0
if [ "${1:-}" = "--sanitize" ]; then
  sanitize=1
  shift
fi
tools/install-deps.sh

if [ "$sanitize" -eq 0 ]; then
  build_dir="${1:-build}"
  cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=Release
  cmake --build "$build_dir" -j2
  cd "$build_dir"
  ctest -j2 --output-on-failure --timeout 900
  exit 0
fi

build_dir="${1:-build-sanitize}"
supp="$PWD/tools/sanitizers"
# The build runs the test binary too (test discovery), so the options apply to it.
export ASAN_OPTIONS="detect_leaks=1:strict_init_order=1:suppressions=$supp/asan.supp"
export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:suppressions=$supp/ubsan.supp"
# A from-scratch build of this configuration takes most of the time; ccache,
# where installed, makes the next one short.
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
start=$(date +%s)
CC=clang CXX=clang++ cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=RelWithDebInfo "${launcher[@]}" \
  -DFLUXGRAPH_SANITIZE=ON -DFLUXGRAPH_FUZZ=ON -DFLUXGRAPH_BUILD_BENCHMARKS=OFF
nice -n 10 cmake --build "$build_dir" -j2
built=$(date +%s)
(cd "$build_dir" && nice -n 10 ctest -L sanitize -j2 --output-on-failure)
tested=$(date +%s)
FLUXGRAPH_FUZZ_SEED="${FLUXGRAPH_FUZZ_SEED:-1}" tools/fuzz.sh "$build_dir" "${FLUXGRAPH_FUZZ_SECONDS:-20}"
echo "test.sh --sanitize: build $((built - start)) s, tests $((tested - built)) s, fuzzing $(( $(date +%s) - tested )) s"
