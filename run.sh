#!/usr/bin/env bash
# ./run.sh [SCENE] [FLAGS...]: installs what is missing, builds, renders SCENE
# (default examples/default.json) and prints where the image is.
set -euo pipefail
cd "$(dirname "$0")"
./scripts/setup.sh
scene="examples/default.json"
if [ $# -gt 0 ] && [[ "$1" != -* ]]; then scene="$1"; shift; fi
args=("$@")
has_output=0
for a in "${args[@]+"${args[@]}"}"; do
  case "$a" in -o|--output|-o*|--output=*) has_output=1 ;; esac
done
if [ $has_output -eq 0 ]; then
  mkdir -p out
  name=$(basename "$scene"); name=${name%.json}
  args+=(-o "out/$name.png")
fi
images=$(./build/isotrace render "$scene" "${args[@]}")
if [ "$(printf '%s\n' "$images" | wc -l)" -gt 1 ]; then
  echo "isotrace: images written to:"; printf '  %s\n' $images
else
  echo "isotrace: image written to $images"
fi
