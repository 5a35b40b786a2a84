#!/usr/bin/env bash
# ./test.sh: installs what is missing, builds, and runs every test through ctest.
set -euo pipefail
cd "$(dirname "$0")"
./scripts/setup.sh
ctest --test-dir build --output-on-failure -j2
