#!/usr/bin/env bash
# Fresh Debian 12 machine -> built fluxgraph and a rendered default job.
#   tools/setup.sh            (writes out/quickstart.exr and out/quickstart.png)
set -euo pipefail
cd "$(dirname "$0")/.."
tools/install-deps.sh
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release
cmake --build build -j2
build/fluxgraph render data/jobs/quickstart.toml --out out
