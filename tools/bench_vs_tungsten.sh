#!/usr/bin/env bash
# Photon paths per CPU second of fluxgraph's `photon` pass against Tungsten's
# photon tracer (its `photon_map` integrator, volume photons as points) on
# the volumetric caustic (Bitterli's scene; data/volumetric-caustic is its
# transcription).
#
#   tools/bench_vs_tungsten.sh TUNGSTEN [--build build] [--threads "1 2"] [--runs 3]
#                              [--paths 200000] [--scene scene.tungsten.json]
#
# TUNGSTEN is the path of a `tungsten` binary (nothing is built or installed
# here). Both sides trace the same paths: at most 16 scattering events (medium
# or surface) per path, no Russian roulette, every path counted whether or not
# it stores a photon, surface photons stored at every non-specular event and
# volume photons at every medium event. Each side traces `paths` and
# `paths / 4` paths; a run's CPU time per path is the difference of the two
# CPU times over the difference of the counts, so start-up and scene loading
# cancel out.
#   fluxgraph: `fluxgraph replay` of the photon pass of data/volumetric-caustic/bre.toml
#     (the pass alone: its threads' CPU seconds).
#   Tungsten: `perf record -e cpu-clock` over the whole run (one sample per
#     millisecond of CPU time, user and system, as fluxgraph's); the samples
#     in its photon-map build (kd-tree sorts, volume hierarchy, compaction),
#     which grows with the photon count, are left out. Its camera pass is
#     4 x 4 pixels at 1 spp with fixed radii.
# Tungsten ends a path after max_bounces - 1 events and counts crossings of the
# index-matched front wall as events; max_bounces = 17 gives 16 events, after
# which Tungsten still traces one ray that fluxgraph does not. The runs
# alternate between the tools; the ratio of paths per CPU second,
# fluxgraph / Tungsten, is taken run by run and its median printed per thread
# count (above 1: fluxgraph is faster).
set -euo pipefail

build=build
threads="1 2"
runs=3
paths=200000
root="$(cd "$(dirname "$0")/.." && pwd)"
scene="$root/../shared/scenes/bitterli-volumetric-caustic/scene.tungsten.json"
tungsten=""
while [ $# -gt 0 ]; do
  case "$1" in
    --build) build="$2"; shift 2 ;;
    --threads) threads="$2"; shift 2 ;;
    --runs) runs="$2"; shift 2 ;;
    --paths) paths="$2"; shift 2 ;;
    --scene) scene="$2"; shift 2 ;;
    -h|--help) sed -n 2,30p "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) tungsten="$1"; shift ;;
  esac
done

. "$root/tools/bench_common.sh"
bench_find_fluxgraph bench_vs_tungsten "$build" "$root"
if [ -z "$tungsten" ] || [ ! -x "$tungsten" ]; then
  echo "bench_vs_tungsten: give the path of a tungsten binary (tools/bench_vs_tungsten.sh --help)" >&2
  exit 2
fi
if [ ! -f "$scene" ]; then
  echo "bench_vs_tungsten: no Tungsten scene at $scene (--scene)" >&2
  exit 2
fi
if ! command -v perf >/dev/null 2>&1; then
  echo "bench_vs_tungsten: needs 'perf' (linux-perf) to leave Tungsten's photon-map build out" >&2
  exit 2
fi
bench_require_multiple_of_four bench_vs_tungsten --paths "$paths"
lowPaths=$((paths / 4))

bench_make_work_dir

# Volume photon capacity: the same in both runs (Tungsten allocates and clears
# per-thread caches in proportion to it, which then cancels), and above what
# the larger run stores (fluxgraph stores 6.3 per path).
volumeCapacity=$((paths * 8))
for n in "$paths" "$lowPaths"; do
  python3 - "$scene" "$work/tungsten-$n.json" "$n" "$volumeCapacity" "$work" <<'EOF'
import json, sys
source, target, paths, capacity, work = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
scene = json.load(open(source))
scene["camera"]["resolution"] = [4, 4]
scene["integrator"] = {
    "type": "photon_map",
    "min_bounces": 0,
    "max_bounces": 17,
    "enable_consistency_checks": False,
    "enable_two_sided_shading": True,
    "photon_count": paths,
    "volume_photon_count": capacity,
    "gather_photon_count": 20,
    "gather_radius": 0.01,
    "volume_gather_radius": 0.01,
    "fixed_volume_radius": True,
    "volume_photon_type": "points",
    "include_surfaces": True,
    "low_order_scattering": True,
}
renderer = scene["renderer"]
renderer.update({"output_file": work + "/tungsten.png", "overwrite_output_files": True, "spp": 1, "spp_step": 1,
                 "enable_resume_render": False, "checkpoint_interval": "0", "timeout": "0"})
renderer.pop("hdr_output_file", None)
json.dump(scene, open(target, "w"), indent=1)
EOF
done

# Tungsten's CPU seconds (user and system) outside its photon-map build. At
# 88ea020 a worker may read the integrator's task group before the main
# thread has stored it and crash at the start of photon tracing; such a run
# is repeated.
tungstenSeconds() {  # tungstenSeconds THREADS PATHS
  local try
  for try in 1 2 3 4 5 6 7 8; do
    perf record -q -e cpu-clock -c 1000000 -o "$work/perf.data" -- \
      "$tungsten" -t "$1" "$work/tungsten-$2.json" >/dev/null 2>&1 && break
    if [ "$try" -eq 8 ]; then echo "bench_vs_tungsten: tungsten failed on $work/tungsten-$2.json" >&2; exit 1; fi
  done
  perf report -i "$work/perf.data" --stdio --sort sym -F sample,sym 2>/dev/null | awk '
    /^#/ || NF < 2 { next }
    { total += $1 }
    /KdTree|introsort|insertion_sort|adjust_heap|heap_select|unguarded|move_median|Box<.*grow|streamCompact|buildPhotonDataStructures|buildVolumeHierarchy/ { build += $1 }
    END { printf "%.6f\n", (total - build) / 1000 }'
}
fluxSeconds() {  # fluxSeconds THREADS PATHS
  "$fluxgraph" replay "$root/data/volumetric-caustic/bre.toml" --pass photon --repeat 1 --threads "$1" \
    --set passes.photon.photons="$2" --set passes.photon.volume_photons=0 --set passes.photon.max_depth=16 \
    --set passes.photon.rr_depth=4096 --set passes.photon.store_direct=true --set passes.photon.differentials=false \
    --set film.width=4 --set film.height=4 2>/dev/null | awk '$1 == "median" { print $3 }' |
    grep . || { echo "bench_vs_tungsten: fluxgraph replay failed" >&2; exit 1; }
}

median() { printf '%s\n' "$@" | sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
printf '%-8s %18s %18s %8s\n' threads "tungsten k paths/s" "fluxgraph k paths/s" ratio
for t in $threads; do
  ratios=()
  tungstenRates=()
  fluxRates=()
  for ((r = 0; r < runs; ++r)); do
    tHigh=$(tungstenSeconds "$t" "$paths"); fHigh=$(fluxSeconds "$t" "$paths")
    tLow=$(tungstenSeconds "$t" "$lowPaths"); fLow=$(fluxSeconds "$t" "$lowPaths")
    tRate=$(echo "($paths - $lowPaths) / ($tHigh - $tLow) / 1000" | bc -l)
    fRate=$(echo "($paths - $lowPaths) / ($fHigh - $fLow) / 1000" | bc -l)
    tungstenRates+=("$tRate"); fluxRates+=("$fRate")
    ratios+=("$(echo "$fRate / $tRate" | bc -l)")
  done
  printf '%-8s %18.1f %18.1f %8.3f\n' "$t" "$(median "${tungstenRates[@]}")" "$(median "${fluxRates[@]}")" \
    "$(median "${ratios[@]}")"
done
