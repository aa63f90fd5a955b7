#!/usr/bin/env bash
# Renders the reference of each scene in data/ with its pt.toml job
# (128 x 128) at a high sample count: data/<scene>/reference/reference.exr,
# half-float RGB (the time_ns / samples AOVs stay 32-bit), ZIP-compressed, with
# the command line, job text, seed, overrides (the sample count) and pass
# timings in its metadata; the sRGB preview goes to data/<scene>/preview.png.
# The scenes whose light a path tracer rarely finds (volumetric-caustic,
# spot-fog, gold-ring, water-wave, metal-ring) are handed to
# tools/render_bdpt_references.sh, which renders them with bdpt.
#
#   tools/render_references.sh [--build DIR] [--divide N] [SCENE ...]
#   tools/render_references.sh --caustic [--build DIR] [--divide N] [SCENE ...]
#   tools/render_references.sh --lt [--build DIR] [--divide N] [SCENE ...]
#
# --divide N renders with 1/N of the reference sample counts (a trial run; the
# result is written to out/references/ instead of data/). The sample counts
# below take a few minutes per scene on a 2-core machine.
#
# --caustic renders the caustic-only references of the caustic case studies
# instead (water-wave, water-wave-collimated, water-wave-sine, metal-ring,
# metal-ring-collimated): standard photon mapping with ~10 million caustic
# photons (40 million under collimated light),
# data/<scene>/caustic-reference.toml as it stands (its photon count
# is in the job file; --divide divides it), to
# data/<scene>/reference/caustic-reference.exr with the same half-float
# colour and metadata; no preview. Water-wave ~30 s, water-wave-collimated
# and water-wave-sine ~4.5 minutes each, metal-ring 5-8 minutes,
# metal-ring-collimated ~2 minutes.
#
# --lt renders the light-traced caustic references of the collimated case
# studies (water-wave-collimated, water-wave-sine) from
# data/<scene>/lt-reference.toml to data/<scene>/reference/lt-reference.exr,
# likewise: every caustic photon connected to the camera, no density
# estimation (~4 minutes each).
set -euo pipefail
cd "$(dirname "$0")/.."

build=build
divide=1
photon_references=0
kind=caustic-reference
scenes=()
while (($#)); do
  case "$1" in
    --build) build="$2"; shift 2 ;;
    --divide) divide="$2"; shift 2 ;;
    --caustic) photon_references=1; shift ;;
    --lt) photon_references=1; kind=lt-reference; shift ;;
    -h|--help) sed -n '2,34p' "$0"; exit 0 ;;
    *) scenes+=("$1"); shift ;;
  esac
done

# Samples per pixel of each path-traced reference, and the preview's exposure (stops).
declare -A spp=(
  [cornell-box]=8192
  [conference]=16384
  [window-room]=16384
)
declare -A exposure=(
  [cornell-box]=0
  [conference]=2
  [window-room]=2.5
)
# Scenes whose reference is rendered by bdpt (tools/render_bdpt_references.sh,
# which these scenes are handed to), with its sample count.
declare -A bidirectional=(
  [volumetric-caustic]=4096
  [spot-fog]=4096
  [gold-ring]=16384
  [water-wave]=4096
  [metal-ring]=16384
)
binary="$build/fluxgraph"
[[ -x "$binary" ]] || { echo "render_references.sh: no $binary; build first (cmake --build $build)" >&2; exit 2; }

if ((photon_references)); then
  if [[ $kind == caustic-reference ]]; then
    ((${#scenes[@]})) || scenes=(water-wave water-wave-collimated water-wave-sine metal-ring metal-ring-collimated)
  else
    ((${#scenes[@]})) || scenes=(water-wave-collimated water-wave-sine)
  fi
  for scene in "${scenes[@]}"; do
    job="data/$scene/$kind.toml"
    [[ -f "$job" ]] || { echo "render_references.sh: '$scene' has no $job" >&2; exit 2; }
    overrides=(--set output.name=$kind --set output.half=true --set output.png=false)
    if ((divide == 1)); then
      out="data/$scene/reference"
    else
      out="out/references/$scene"
      photons=$(python3 -c 'import sys, tomllib; print(tomllib.load(open(sys.argv[1], "rb"))["passes"]["photon"]["photons"])' "$job")
      overrides+=(--set passes.photon.photons=$(( photons / divide > 0 ? photons / divide : 1 )))
    fi
    echo "== $scene: $kind"
    start=$(date +%s)
    if ! "$binary" render "$job" --out "$out" "${overrides[@]}"; then
      echo "render_references.sh: rendering the $kind of '$scene' failed" >&2
      exit 1
    fi
    echo "== $scene: $(( $(date +%s) - start )) s -> $out/$kind.exr"
  done
  exit 0
fi

if ((${#scenes[@]} == 0)); then
  scenes=(cornell-box volumetric-caustic gold-ring water-wave metal-ring spot-fog conference window-room)
fi

for scene in "${scenes[@]}"; do
  if [[ -n "${bidirectional[$scene]:-}" ]]; then
    # A path tracer rarely finds these scenes' small lights through glass,
    # mirrors or fog: their references are bidirectional.
    bdpt_options=(--build "$build" --spp $(( bidirectional[$scene] / divide > 1 ? bidirectional[$scene] / divide : 2 )))
    if ((divide == 1)); then bdpt_options+=(--install); else bdpt_options+=(--out out/references); fi
    tools/render_bdpt_references.sh "${bdpt_options[@]}" "$scene"
    continue
  fi
  [[ -n "${spp[$scene]:-}" ]] || { echo "render_references.sh: unknown scene '$scene'" >&2; exit 2; }
  samples=$(( spp[$scene] / divide ))
  ((samples >= 1)) || samples=1
  if ((divide == 1)); then
    out="data/$scene/reference"
    preview="data/$scene/preview.png"
  else
    out="out/references/$scene"
    preview="$out/preview.png"
  fi
  echo "== $scene: $samples spp"
  start=$(date +%s)
  if ! "$binary" render "data/$scene/pt.toml" --out "$out" \
    --set passes.pt.spp="$samples" --set output.name=reference --set output.half=true \
    --set output.exposure="${exposure[$scene]}"; then
    echo "render_references.sh: rendering the reference of '$scene' failed" >&2
    exit 1
  fi
  mv "$out/reference.png" "$preview"
  echo "== $scene: $(( $(date +%s) - start )) s -> $out/reference.exr, $preview"
done
