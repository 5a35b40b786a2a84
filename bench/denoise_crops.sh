#!/usr/bin/env bash
# docs/gallery/denoise_*.png: raw and denoised crops side by side, from the images that
# `bench/denoise.py --images DIR` wrote (half the scenes' film size; pixels doubled, not filtered):
# raw 16 spp | quality 16 | fast 16 | raw 128 | reference (2048 spp).
#   bench/denoise_crops.sh [DIR] (default out/denoise_bench/img)
set -euo pipefail
cd "$(dirname "$0")/.."
dir="${1:-out/denoise_bench/img}"
# scene and crop (WxH+X+Y at half size): the ribs through the glass skin, the protein's lobes,
# the engine's fins and shadow, the head's bone under the skin, the Cornell box's torus.
crops=("ct_chest 140x100+110+50" "default 110x80+195+60" "engine_volume 120x80+20+75" "ct_head 120x90+100+60"
       "cornell_torus 120x90+100+40")
for entry in "${crops[@]}"; do
  read -r scene box <<<"$entry"
  w=${box%%x*}; rest=${box#*x}; h=${rest%%+*}
  parts=()
  for image in raw16 quality16 fast16 raw128 reference; do
    parts+=("$dir/$scene.$image.png" --cut "$box" --resample "$((2 * w))x$((2 * h))")
  done
  oiiotool "${parts[@]}" --mosaic:pad=4 5x1 -o "docs/gallery/denoise_$scene.png"
  echo "docs/gallery/denoise_$scene.png"
done
