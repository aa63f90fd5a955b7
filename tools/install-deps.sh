#!/usr/bin/env bash
# Installs the Debian 12 packages fluxgraph builds against (skips apt when all are present).
set -euo pipefail
packages=(
  build-essential cmake pkg-config
  libembree-dev libtbb-dev libopenimageio-dev libopenexr-dev libpng-dev libglm-dev
  libtomlplusplus-dev libtinyobjloader-dev libpugixml-dev libcli11-dev zlib1g-dev
  openimageio-tools   # oiiotool: tools/render_bdpt_references.sh averages the halves
  libgtest-dev libbenchmark-dev python3 python3-numpy python3-skimage python3-matplotlib
  python3-sklearn   # tests/tools/check_em_sklearn.py: scikit-learn's EM as the yardstick of em_fit
  embree-tools   # tools/bench_vs_embree.sh: Embree's tutorial path tracer as a yardstick
  slurm-wlm munge   # the Slurm test's local cluster (tools/slurm_local.sh)
  clang libfuzzer-14-dev   # tools/test.sh --sanitize: ASan/UBSan build and fuzz targets (clang 14)
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "install-deps: installing ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
# Where installing starts the system's SLURM and munge daemons, stop them: the
# test starts its own, and nothing else here needs them.
for service in slurmctld slurmd munge; do
  $SUDO service "$service" stop >/dev/null 2>&1 || true
done
