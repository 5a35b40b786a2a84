#!/usr/bin/env bash
# bench/same_images.sh OTHER_ISOTRACE [SCENE.json ...]: whether this checkout's build renders the
# same image bits as another build (an older commit's, say), for every integrator, both ray flows
# and 1 and 2 threads. An optimisation that claims "nothing changed" proves it here: each scene is
# rendered small (96x54, 4 spp, seed 7, denoiser off) by both binaries, and the EXR pixels are
# compared with idiff (any difference at all fails). Default scenes: bench/scenes/*.json and the
# examples that mix meshes, glass, emitters, clips and colour by data.
# Prints one line per render and a summary; exits 1 if any image differs.
set -euo pipefail
cd "$(dirname "$0")/.."
other=${1:?usage: bench/same_images.sh OTHER_ISOTRACE [SCENE.json ...]}
shift
mine=${ISOTRACE:-build/isotrace}  # the build under test (ISOTRACE=... for a copy)
scenes=("$@")
if [ ${#scenes[@]} -eq 0 ]; then
  scenes=(bench/scenes/*.json examples/default.json examples/cornell_torus.json examples/ct_chest_cut.json
          examples/iso_lamp.json examples/color_by.json examples/mri_brain.json)
fi
# Builds from before the denoiser (issue 45) know no --denoise (nor film.denoise: give them scenes
# without it, such as bench/scenes/*.json); their images are the raw ones anyway.
denoise=()
if "$other" render --help 2>&1 | grep -q -- --denoise; then denoise=(--denoise off); fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
same=0
differ=0
for scene in "${scenes[@]}"; do
  for integrator in normals eyelight ao direct path compare; do
    for flow in wavefront scalar; do
      for threads in 1 2; do
        args=(render "$scene" --resolution 96x54 --spp 4 --seed 7 --quiet "${denoise[@]}" --integrator "$integrator"
              --ray-flow "$flow" --threads "$threads")
        rm -f "$work"/*.exr
        "$mine" "${args[@]}" -o "$work/mine.exr" >/dev/null 2>"$work/err" || { cat "$work/err"; exit 2; }
        "$other" "${args[@]}" -o "$work/other.exr" >/dev/null 2>"$work/err" || { cat "$work/err"; exit 2; }
        # Every layer file the render wrote (compare writes .direct, .global and .indirect too).
        verdict=same
        for theirs in "$work"/other*.exr; do
          ours="$work/mine${theirs#"$work"/other}"
          if ! idiff -fail 0 -failpercent 0 -warn 0 "$ours" "$theirs" >/dev/null 2>&1; then verdict=DIFFERENT; fi
        done
        if [ "$verdict" = same ]; then same=$((same + 1)); else differ=$((differ + 1)); fi
        printf '%-32s %-9s %-9s %d thread(s): %s\n' "$(basename "$scene")" "$integrator" "$flow" "$threads" "$verdict"
      done
    done
  done
done
echo "same_images: $same renders identical, $differ different (this build: $mine, other: $other)"
[ "$differ" -eq 0 ]
