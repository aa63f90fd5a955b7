#!/usr/bin/env bash
# Time per sample of fluxgraph's `pt` against Embree's tutorial path tracer
# (`pathtracer` from Debian's embree-tools, installed by tools/install-deps.sh)
# on the same scene: Mitsuba's Cornell-box meshes merged into one OBJ (the
# luminaire left out), white diffuse albedo 1, one point light under the
# ceiling, 256 x 256, path length 8.
#
#   tools/bench_vs_embree.sh [BUILD_DIR] [--threads "1 2"] [--runs 5] [--spp 64]
#
# Each tool renders at spp and at spp / 4; a run's time per sample is the
# difference of the two wall times over the difference of the sample counts,
# so process start-up, scene loading and the BVH build cancel out. The four
# renders of a run alternate between the tools; the ratio fluxgraph / Embree is
# taken run by run and its median printed per thread count (above 1: fluxgraph
# is slower).
set -euo pipefail

build=build
threads="1 2"
runs=5
spp=64
while [ $# -gt 0 ]; do
  case "$1" in
    --threads) threads="$2"; shift 2 ;;
    --runs) runs="$2"; shift 2 ;;
    --spp) spp="$2"; shift 2 ;;
    -h|--help) sed -n 2,15p "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) build="$1"; shift ;;
  esac
done

root="$(cd "$(dirname "$0")/.." && pwd)"
. "$root/tools/bench_common.sh"
bench_find_fluxgraph bench_vs_embree "$build" "$root"
if ! command -v pathtracer >/dev/null 2>&1; then
  echo "bench_vs_embree: Embree's 'pathtracer' is not installed; run tools/install-deps.sh (package embree-tools)" >&2
  exit 2
fi
bench_require_multiple_of_four bench_vs_embree --spp "$spp"
lowSpp=$((spp / 4))

bench_make_work_dir

python3 - "$root/data/cornell-box/meshes" "$work" <<'EOF'
import pathlib, sys
meshes, work = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
out = ["mtllib white.mtl", "usemtl white"]
base = 0
for name in ["floor", "ceiling", "back", "greenwall", "redwall", "smallbox", "largebox"]:
    count = 0
    for line in (meshes / f"cbox_{name}.obj").read_text().splitlines():
        fields = line.split()
        if not fields:
            continue
        if fields[0] == "v":
            out.append(line)
            count += 1
        elif fields[0] == "f":
            out.append("f " + " ".join(str(int(f.split("/")[0]) + base) for f in fields[1:]))
    base += count
(work / "cornell.obj").write_text("\n".join(out) + "\n")
(work / "white.mtl").write_text("newmtl white\nKd 1 1 1\nKs 0 0 0\n")
EOF

light_position="278 540 279.5"
light_intensity=100000
cat >"$work/cornell.toml" <<EOF
[camera]
eye = [278, 273, -800]
target = [278, 273, -799]
up = [0, 1, 0]
fov = 39.3077
width = 256
height = 256

[[material]]
name = "white"
type = "diffuse"
reflectance = [1, 1, 1]

[[shape]]
type = "obj"
file = "cornell.obj"
material = "white"

[[light]]
type = "point"
position = [${light_position// /, }]
intensity = $light_intensity
EOF

job() {  # job SPP
  cat >"$work/job-$1.toml" <<EOF
scene = "cornell.toml"
pipeline = "pt"
seed = 1
[film]
width = 256
height = 256
filter = "box"
[output]
name = "fluxgraph"
[passes.pt]
spp = $1
max_depth = 8
EOF
}
job "$spp"
job "$lowSpp"

seconds() {  # seconds COMMAND...: wall time of the command, its output discarded
  local start end
  start=$(date +%s.%N)
  "$@" >/dev/null 2>&1 || { echo "bench_vs_embree: failed: $*" >&2; exit 1; }
  end=$(date +%s.%N)
  echo "$end - $start" | bc -l
}

embree() {  # embree THREADS SPP
  seconds pathtracer -i "$work/cornell.obj" --vp 278 273 -800 --vi 278 273 -799 --vu 0 1 0 --fov 39.3077 \
    --size 256 256 --pointlight $light_position $light_intensity $light_intensity $light_intensity \
    --spp "$2" --max-path-length 8 --threads "$1" -o "$work/embree.ppm"
}
flux() {  # flux THREADS SPP
  seconds "$fluxgraph" render "$work/job-$2.toml" --threads "$1" --out "$work/out"
}

printf '%-8s %14s %16s %8s\n' threads "embree ms/spp" "fluxgraph ms/spp" ratio
for t in $threads; do
  ratios=()
  embreeTimes=()
  fluxTimes=()
  for ((r = 0; r < runs; ++r)); do
    eHigh=$(embree "$t" "$spp"); fHigh=$(flux "$t" "$spp")
    eLow=$(embree "$t" "$lowSpp"); fLow=$(flux "$t" "$lowSpp")
    e=$(echo "($eHigh - $eLow) / ($spp - $lowSpp) * 1000" | bc -l)
    f=$(echo "($fHigh - $fLow) / ($spp - $lowSpp) * 1000" | bc -l)
    embreeTimes+=("$e"); fluxTimes+=("$f")
    ratios+=("$(echo "$f / $e" | bc -l)")
  done
  median() { printf '%s\n' "$@" | sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
  printf '%-8s %14.2f %16.2f %8.3f\n' "$t" "$(median "${embreeTimes[@]}")" "$(median "${fluxTimes[@]}")" \
    "$(median "${ratios[@]}")"
done
