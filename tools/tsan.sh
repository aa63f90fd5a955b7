#!/usr/bin/env bash
# ThreadSanitizer run of the jobs/ and scheduler tests against a oneTBB that
# is itself built with -fsanitize=thread. Against Debian's libtbb (not
# instrumented) TSan cannot see oneTBB's own synchronisation and reports
# races between a task and the thread that waits for it, which are not real.
#
#   tools/tsan.sh [cache-dir] [build-dir]   (defaults: ~/.cache/fluxgraph-tsan, build-tsan)
#
# Needs network the first time: it downloads the oneTBB release that Debian 12
# ships (v2021.8.0, the version the normal build links) into cache-dir and
# installs an instrumented copy there. TBB_SOURCE_DIR=/path/to/oneTBB uses a
# local checkout instead. FLUXGRAPH_TSAN_FILTER overrides the gtest filter.
# The instrumented libtbb.so.12 comes first on LD_LIBRARY_PATH, so Embree and
# OpenImageIO (linked to libtbb.so.12 too) load the same instrumented copy.
set -euo pipefail
cd "$(dirname "$0")/.."
cache_dir="${1:-${XDG_CACHE_HOME:-$HOME/.cache}/fluxgraph-tsan}"
build_dir="${2:-build-tsan}"
tbb_version="2021.8.0"
filter="${FLUXGRAPH_TSAN_FILTER:-ParallelFor*:DeterministicReduce.*:ThreadLimit.*:WorkContext.*:TaskGraph.*:Rng.*:RandomStreams.*:ExecutionPlan*:Execute.*:Streams.*:RepeatBlock.*:DemandDrivenStream.*}"
tsan_flags="-fsanitize=thread -g -O1"
prefix="$cache_dir/onetbb-$tbb_version-tsan"

if [ ! -f "$prefix/lib/cmake/TBB/TBBConfig.cmake" ]; then
  mkdir -p "$cache_dir"
  source_dir="${TBB_SOURCE_DIR:-}"
  if [ -z "$source_dir" ]; then
    source_dir="$cache_dir/oneTBB-$tbb_version"
    if [ ! -d "$source_dir" ]; then
      archive="$cache_dir/oneTBB-$tbb_version.tar.gz"
      curl -fL --retry 3 -o "$archive.part" \
        "https://github.com/oneapi-src/oneTBB/archive/refs/tags/v$tbb_version.tar.gz"
      mv "$archive.part" "$archive"
      tar -xzf "$archive" -C "$cache_dir"
    fi
  fi
  CC=clang CXX=clang++ cmake -S "$source_dir" -B "$cache_dir/onetbb-build" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_C_FLAGS="$tsan_flags" -DCMAKE_CXX_FLAGS="$tsan_flags" -DCMAKE_EXE_LINKER_FLAGS=-fsanitize=thread \
    -DCMAKE_SHARED_LINKER_FLAGS=-fsanitize=thread -DTBB_TEST=OFF -DTBB_STRICT=OFF -DTBBMALLOC_BUILD=OFF \
    -DCMAKE_INSTALL_PREFIX="$prefix" -DCMAKE_INSTALL_LIBDIR=lib
  nice -n 10 cmake --build "$cache_dir/onetbb-build" -j2
  cmake --install "$cache_dir/onetbb-build"
fi

CC=clang CXX=clang++ cmake -S . -B "$build_dir" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DCMAKE_CXX_FLAGS="$tsan_flags" -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=thread -Wl,-rpath,$prefix/lib" \
  -DTBB_DIR="$prefix/lib/cmake/TBB" -DFLUXGRAPH_BUILD_BENCHMARKS=OFF
nice -n 10 cmake --build "$build_dir" -j2 --target fluxgraph_tests
export LD_LIBRARY_PATH="$prefix/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export TSAN_OPTIONS="halt_on_error=0:second_deadlock_stack=1:history_size=4:exitcode=66"
"$build_dir/tests/fluxgraph_tests" --gtest_filter="$filter"
echo "tsan: no ThreadSanitizer warnings in $filter"
