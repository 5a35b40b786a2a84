#!/usr/bin/env bash
# bench/sparse_vdb.sh [RADIUS]: peak memory of rendering a sparse OpenVDB level-set sphere
# (default radius 300 voxels: box 605^3, 6.8 M active voxels, 0.9 GB as a dense float grid),
# against the peak of the same render with the sphere as a procedural 64^3 grid (the process's
# own memory: libraries, film, Embree). Needs a built tree (./scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
radius=${1:-300}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
build/bench/make_vdb_sphere "$radius" "$work/sphere.vdb"
scene() {  # scene VOLUME_JSON
  cat <<JSON
{ "camera": { "position": [0.5, 1.2, 3.5], "look_at": [0, 0, 0], "fov": 40 },
  "film": { "width": 640, "height": 480 },
  "integrator": { "type": "path", "spp": 16, "max_depth": 4 },
  "meshes": [ { "shape": "quad", "transform": { "scale": 10, "translate": [0, -1.0, 0] } } ],
  "volumes": [ $1 ],
  "lights": [ { "type": "directional", "direction": [-0.4, -1, -0.5], "irradiance": [3, 2.9, 2.7] },
              { "type": "environment", "radiance": [0.35, 0.42, 0.55] } ] }
JSON
}
scene "{ \"file\": \"$work/sphere.vdb\", \"isosurfaces\": [ { \"value\": 0, \"inside\": \"below\" } ] }" > "$work/vdb.json"
scene '{ "procedural": { "field": "sphere", "resolution": [64, 64, 64] }, "isosurfaces": [ { "value": 1, "inside": "below" } ] }' > "$work/small.json"
for s in vdb small; do
  /usr/bin/time -f "%M" -o "$work/$s.rss" build/isotrace render "$work/$s.json" -o "$work/$s.png" --quiet \
    --stats "$work/$s.stats" > /dev/null
  python3 - "$s" "$work/$s.rss" "$work/$s.stats" <<'PY'
import json, sys
name, rss, stats = sys.argv[1:4]
s = json.load(open(stats))["seconds"]
print("%-6s peak RSS %7.1f MB   load %.2f s, build %.2f s, render %.2f s" % (name, int(open(rss).read().split()[-1]) / 1024, s["load"], s["build"], s["render"]))
PY
done
build/isotrace info "$work/vdb.json" | grep -E "float32|held sparse"
