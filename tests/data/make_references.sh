#!/usr/bin/env bash
# Re-makes the stored reference images of the image regression tests (tests/render_test.cpp).
# Run after a deliberate change of what the renderer computes, look at the result, commit it.
set -euo pipefail
cd "$(dirname "$0")/../.."
build/isotrace render examples/cornell_torus.json --resolution 48x36 --spp 4096 --seed 1000 \
  --aov variance --quiet -o tests/data/cornell_torus_ref.exr
