#!/usr/bin/env bash
# Overhead of `fluxgraph batch` over the work it schedules: 64 tiny runs of one
# scene (Cornell box, 16x16, 1 spp, path tracer, one seed each). Prints the
# batch's wall time, the sum of the runs' pass times (passes_seconds in
# results.csv) and their ratio. What the ratio measures beyond 1 is per-run
# bookkeeping: job parsing and validation, the up-to-date check, writing the
# EXR and PNG, comparing, appending the rows; the scene is loaded and its
# Embree scene built once for all 64 runs.
#   tools/bench_batch.sh [build/fluxgraph] [threads]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
binary=$(realpath "${1:-$root/build/fluxgraph}")
threads=${2:-1}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

cat >"$work/pt.toml" <<JOB
scene = "$root/data/cornell-box/cornell-box.toml"
pipeline = "pt"
JOB
seeds=$(seq -s ', ' 1 64)
cat >"$work/plan.toml" <<PLAN
output = "$work/out"
set = { "film.width" = 16, "film.height" = 16, "passes.pt.spp" = 1 }
[[sweep]]
job = "pt.toml"
set = { seed = [$seeds] }
PLAN

# Process start-up (dynamic linking of Embree, TBB, OpenEXR ...), for scale.
start=$(date +%s.%N)
"$binary" pipelines >/dev/null
startup=$(echo "$(date +%s.%N) - $start" | bc)

start=$(date +%s.%N)
"$binary" batch "$work/plan.toml" --threads "$threads" >/dev/null
end=$(date +%s.%N)

# wall_seconds of a row: the run from its up-to-date check to its rows, scene
# loading included where it happened.
awk -F, -v start="$start" -v end="$end" -v startup="$startup" '
NR == 1 { for (i = 1; i <= NF; ++i) column[$i] = i; next }
{ passes += $column["passes_seconds"]; rows += $column["wall_seconds"]; runs += 1 }
END {
    wall = end - start
    printf "runs %d: batch wall %.4f s (process start-up alone %.4f s), sum of run wall times %.4f s, sum of pass times %.4f s\n", runs, wall, startup, rows, passes
    printf "ratio batch wall / pass times %.2f; per run (run wall / pass times) %.2f\n", wall / passes, rows / passes
}' "$work/out/results.csv"
