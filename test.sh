#!/usr/bin/env bash
# ./test.sh [--sanitize]: installs what is missing, builds, and runs every test through ctest.
# --sanitize builds with AddressSanitizer and UndefinedBehaviorSanitizer in build-sanitize/
# (a separate folder; any finding fails the test that made it) and runs every test there.
set -euo pipefail
cd "$(dirname "$0")"
if [ "${1:-}" = "--sanitize" ]; then
  ISOTRACE_SKIP_BUILD=1 ./scripts/setup.sh
  cmake -S . -B build-sanitize -DCMAKE_BUILD_TYPE=Release -DISOTRACE_SANITIZE=ON >/dev/null
  cmake --build build-sanitize -j2 -- --no-print-directory 2>&1 | grep -Ev '^\[ *[0-9]+%\]|^Consolidate|^Scanning' || true
  export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:strict_string_checks=1"
  export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp:print_suppressions=0"
  export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
  ctest --test-dir build-sanitize --output-on-failure -j2 --timeout 900 </dev/null
  exit
fi
./scripts/setup.sh
# --timeout: a safety net, not a timing assumption (the slowest test takes about 80 s): a test
# that hangs fails by name after 15 minutes instead of holding the run. No test reads stdin.
ctest --test-dir build --output-on-failure -j2 --timeout 900 </dev/null
