#!/usr/bin/env bash
# Renders a scene's bidirectional reference from data/<scene>/bdpt.toml as two
# independent halves (seeds 1 and 2, half the samples each), averages them,
# and prints the RMSE between the halves over the whole image and per region
# (the four quadrants, and for volumetric-caustic the crop below the rows
# that hold the light). The halves' difference is the reference's noise
# record: the average of two halves has half the RMSE of their difference
# (each half's error is RMSE / sqrt 2, the mean's RMSE / 2).
#
#   tools/render_bdpt_references.sh [--build DIR] [--spp N] [--threads N] [--out DIR] [--install] SCENE ...
#
# --spp: samples per pixel of the reference, split between the halves
#   (default: the per-scene counts below).
# --out: where the halves and the average go (default out/bdpt-references/<scene>/).
# --install: make the average the scene's reference, data/<scene>/reference/reference.exr
#   (half-float, with the halves' noise in its metadata), and its preview data/<scene>/preview.png.
set -euo pipefail
cd "$(dirname "$0")/.."

build=build
threads=0
out_root=out/bdpt-references
install=0
spp_override=
scenes=()
while (($#)); do
  case "$1" in
    --build) build="$2"; shift 2 ;;
    --spp) spp_override="$2"; shift 2 ;;
    --threads) threads="$2"; shift 2 ;;
    --out) out_root="$2"; shift 2 ;;
    --install) install=1; shift ;;
    -h|--help) sed -n '2,16p' "$0"; exit 0 ;;
    -*) echo "render_bdpt_references.sh: unknown option $1" >&2; exit 2 ;;
    *) scenes+=("$1"); shift ;;
  esac
done
((${#scenes[@]})) || { echo "render_bdpt_references.sh: name at least one scene (e.g. volumetric-caustic)" >&2; exit 2; }

# Samples per pixel of each reference (both halves together).
declare -A spp=(
  [cornell-box]=4096
  [volumetric-caustic]=8192
  [spot-fog]=4096
  [gold-ring]=16384
  [water-wave]=4096
  [metal-ring]=16384
)
# Exposure of each preview, in stops (as tools/render_references.sh's).
declare -A exposure=(
  [spot-fog]=1
  [water-wave]=-0.5
)
# Regions whose noise is reported besides the whole image: name=WxH+X+Y (128 x 128 jobs).
declare -A extra_regions=(
  [volumetric-caustic]="below-light=128x112+0+16"
)

binary="$build/fluxgraph"
[[ -x "$binary" ]] || { echo "render_bdpt_references.sh: no $binary; build first (cmake --build $build)" >&2; exit 2; }
command -v oiiotool >/dev/null || { echo "render_bdpt_references.sh: needs oiiotool (OpenImageIO tools)" >&2; exit 2; }

rmse() {  # rmse A B [crop x,y,w,h]
  local crop=()
  [[ $# -ge 3 ]] && crop=(--crop "$3")
  "$binary" compare "$1" "$2" --metric rmse "${crop[@]}" | awk '{print $2}'
}

for scene in "${scenes[@]}"; do
  job="data/$scene/bdpt.toml"
  [[ -f "$job" ]] || { echo "render_bdpt_references.sh: '$scene' has no $job" >&2; exit 2; }
  total=${spp_override:-${spp[$scene]:-4096}}
  half=$((total / 2))
  ((half >= 1)) || { echo "render_bdpt_references.sh: --spp must be at least 2" >&2; exit 2; }
  out="$out_root/$scene"
  mkdir -p "$out"
  for seed in 1 2; do
    "$binary" render "$job" --out "$out" --threads "$threads" -q \
      --set "seed=$seed" --set "passes.bdpt.spp=$half" --set "output.name=half$seed" --set output.png=false
  done
  oiiotool "$out/half1.exr" --ch R,G,B "$out/half2.exr" --ch R,G,B --add --mulc 0.5 -o "$out/reference.exr"
  size=$(oiiotool --info "$out/half1.exr" | grep -oE '[0-9]+ x +[0-9]+' | head -1 | tr -d ' ')
  width=${size%x*}
  height=${size#*x}
  hw=$((width / 2))
  hh=$((height / 2))
  echo "$scene: $total spp ($half per half), $width x $height -> $out/reference.exr"
  printf '  %-22s %s\n' "region" "RMSE between halves (reference noise = half of it)"
  printf '  %-22s %s\n' "whole image" "$(rmse "$out/half1.exr" "$out/half2.exr")"
  printf '  %-22s %s\n' "top left" "$(rmse "$out/half1.exr" "$out/half2.exr" "0,0,$hw,$hh")"
  printf '  %-22s %s\n' "top right" "$(rmse "$out/half1.exr" "$out/half2.exr" "$hw,0,$((width - hw)),$hh")"
  printf '  %-22s %s\n' "bottom left" "$(rmse "$out/half1.exr" "$out/half2.exr" "0,$hh,$hw,$((height - hh))")"
  printf '  %-22s %s\n' "bottom right" "$(rmse "$out/half1.exr" "$out/half2.exr" "$hw,$hh,$((width - hw)),$((height - hh))")"
  for region in ${extra_regions[$scene]:-}; do
    name=${region%%=*}
    geometry=${region#*=}
    # WxH+X+Y -> x,y,w,h
    w=${geometry%%x*}; rest=${geometry#*x}; h=${rest%%+*}; rest=${rest#*+}; x=${rest%%+*}; y=${rest#*+}
    printf '  %-22s %s\n' "$name" "$(rmse "$out/half1.exr" "$out/half2.exr" "$x,$y,$w,$h")"
  done
  if ((install)); then
    # The average becomes the scene's reference: half-float, ZIP, with the
    # halves' job and timings (oiiotool keeps the first input's metadata), the
    # command that made it and the noise record in its metadata; and its preview.
    mkdir -p "data/$scene/reference"
    noise="RMSE between halves: whole image $(rmse "$out/half1.exr" "$out/half2.exr")"
    for region in ${extra_regions[$scene]:-}; do
      name=${region%%=*}; geometry=${region#*=}
      w=${geometry%%x*}; rest=${geometry#*x}; h=${rest%%+*}; rest=${rest#*+}; x=${rest%%+*}; y=${rest#*+}
      noise+=", $name $(rmse "$out/half1.exr" "$out/half2.exr" "$x,$y,$w,$h")"
    done
    oiiotool "$out/reference.exr" -d half --compression zip \
      --attrib "fluxgraph:command" "tools/render_bdpt_references.sh --spp $total --install $scene (seeds 1 and 2, $half spp each, averaged)" \
      --attrib "fluxgraph:reference_noise" "$noise" -o "data/$scene/reference/reference.exr"
    gain=$(python3 -c "print(2 ** float('${exposure[$scene]:-0}'))")
    oiiotool "$out/reference.exr" --ch R,G,B --mulc "$gain" --colorconvert linear sRGB -d uint8 -o "data/$scene/preview.png"
    echo "  installed data/$scene/reference/reference.exr and data/$scene/preview.png ($noise)"
  fi
done
