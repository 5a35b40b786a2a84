#!/bin/sh
# The watertightness tables of docs/BENCHMARKS.md: every intersector on the six real volumes of
# bench/real_volumes.json, then isolation (the default) on the examples and on
# bench/watertight_sweep.json (real volumes at several iso values, gyroid, Marschner-Lobb),
# each at the origin and with the volumes moved to 1e5. 100,000 rays per test and iso-surface.
# Usage: bench/watertight_tables.sh [OUT.txt]   (default docs/watertight_results.txt)
set -e
cd "$(dirname "$0")/.."
out=${1:-docs/watertight_results.txt}
isotrace=build/isotrace
rays=100000
: > "$out"
for intersector in linear neubauer:3 schwarze isolation:1 isolation:3 isolation reference; do
  for offset in 0,0,0 1e5,1e5,1e5; do
    echo "== $intersector bench/real_volumes.json offset $offset" >> "$out"
    $isotrace watertight bench/real_volumes.json --rays $rays --intersector $intersector --offset $offset | tail -n +2 >> "$out"
  done
done
for scene in examples/default.json examples/engine_volume.json examples/cornell_torus.json examples/ct_chest.json \
             bench/watertight_sweep.json; do
  for offset in 0,0,0 1e5,1e5,1e5; do
    echo "== isolation $scene offset $offset" >> "$out"
    $isotrace watertight $scene --rays $rays --intersector isolation --offset $offset | tail -n +2 >> "$out"
  done
done
echo "wrote $out"
