#!/usr/bin/env bash
# Re-makes the images of docs/gallery.md (about 4 minutes on 2 cores). Each line below is the
# command of one image; variants of an example (another material, other normals) are written
# by `variant` into a scratch directory with the data paths made absolute.
set -euo pipefail
cd "$(dirname "$0")/../.."
out=docs/gallery
bin=build/isotrace
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# variant SCENE NAME PYTHON: SCENE's JSON as `s`, changed by PYTHON, written to $tmp/NAME.json.
variant() {
  python3 - "$1" "$tmp/$2.json" "$3" <<'PY'
import json, os, sys
src, dst, change = sys.argv[1:4]
s = json.load(open(src))
base = os.path.dirname(os.path.abspath(src))
for item in s.get("meshes", []) + s.get("volumes", []):
    if "file" in item and not os.path.isabs(item["file"]):
        item["file"] = os.path.join(base, item["file"])
exec(change)
json.dump(s, open(dst, "w"))
PY
}
render() { "$bin" render "$@" --quiet > /dev/null; }

# The examples.
render examples/default.json --resolution 320x240 --spp 96 -o $out/default.png
render examples/quick_look.json --resolution 320x240 --spp 16 -o $out/quick_look.png
render examples/color_by.json --resolution 320x240 --spp 64 -o $out/color_by.png
render examples/mri_slices.json --resolution 320x240 --spp 32 -o $out/mri_slices.png
render examples/ct_chest_cut.json --resolution 320x240 --spp 64 --colorbar -o $out/ct_chest_cut.png
render examples/cornell_torus.json --resolution 320x320 --spp 256 -o $out/cornell_torus.png
render examples/mri_brain.json --resolution 320x240 --spp 64 -o $out/mri_brain.png
render examples/smoke.json --resolution 240x320 --spp 64 -o $out/smoke.png
render examples/cornell_obj.json --resolution 320x320 --spp 128 -o $out/cornell_obj.png
render examples/ct_chest.json --resolution 320x240 --spp 128 -o $out/ct_chest.png
render examples/ct_head.json --resolution 320x240 --spp 128 -o $out/ct_head.png
render examples/engine_volume.json --resolution 320x240 --spp 64 -o $out/engine_volume.png
render examples/iso_lamp.json --resolution 320x240 --spp 128 --tonemap aces -o $out/iso_lamp.png
# A volume that changes over time, as a video (and its first frame as a still).
render examples/4d_mri.json --resolution 320x240 --spp 16 --frames 48 --orbit 90 --fps 12 -o $out/4d_mri.mp4
render examples/4d_mri.json --resolution 320x240 --spp 16 --frames 1 -o $out/4d_mri.png

# Smooth shading normals against the cell's own gradient: the CT head's skin, lit from the eye.
variant examples/ct_head.json head_skin 's["volumes"][0]["isosurfaces"] = [{"value": 500, "color": [0.9, 0.75, 0.65]}]; s["camera"] = {"position": [60, 20, 190], "look_at": [0, 0, 40], "fov": 35}'
variant examples/ct_head.json head_skin_cell 's["volumes"][0]["isosurfaces"] = [{"value": 500, "color": [0.9, 0.75, 0.65], "normals": "cell"}]; s["camera"] = {"position": [60, 20, 190], "look_at": [0, 0, 40], "fov": 35}'
render $tmp/head_skin.json --integrator eyelight --resolution 320x240 --spp 16 -o $out/normals_smooth.png
render $tmp/head_skin_cell.json --integrator eyelight --resolution 320x240 --spp 16 -o $out/normals_cell.png

# Glass skin: solid glass (the sun cannot reach the bone by next-event estimation) and thin.
variant examples/ct_chest.json chest_solid 's["materials"]["skin"]["thin"] = False'
render $tmp/chest_solid.json --resolution 320x240 --spp 128 -o $out/glass_solid.png

# Fireflies: a diffuse floor under a spot light and a gold gyroid, 64 spp, then the indirect
# clamp, then adaptive sampling in about the same time.
render bench/noise/fireflies.json --resolution 320x214 --spp 64 -o $out/fireflies.png
render bench/noise/fireflies.json --resolution 320x214 --spp 64 --clamp 1 -o $out/fireflies_clamp.png
render bench/noise/fireflies.json --resolution 320x214 --spp 256 --adaptive 0.2 -o $out/fireflies_adaptive.png

# Exposure and tone mapping of the iso-surface lamp: clamp, and ACES one stop brighter.
render examples/iso_lamp.json --resolution 320x240 --spp 64 --exposure 1 -o $out/tonemap_clamp.png
render examples/iso_lamp.json --resolution 320x240 --spp 64 --exposure 1 --tonemap aces -o $out/tonemap_aces.png

# A transparent background.
render examples/quick_look.json --resolution 320x240 --spp 16 --alpha -o $out/alpha.png
echo "gallery images written to $out"
