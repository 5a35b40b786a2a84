#!/usr/bin/env bash
# scripts/soak_tests.sh N [--loaded] [--sanitize]: runs ./test.sh N times in a row on a fresh clone
# of this checkout's HEAD (in /tmp/isotrace-soak; the first run builds it, the others reuse the
# build) and counts the runs that fail. --loaded keeps every core busy with `stress-ng --cpu`
# for the whole soak (a loaded machine); --sanitize passes --sanitize to ./test.sh. The logs of
# failed runs stay in /tmp/isotrace-soak-logs. Ends with "N passed, M failed"; exit 1 if any failed.
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-}"
if ! [[ "$runs" =~ ^[1-9][0-9]{0,3}$ ]]; then
  echo "usage: scripts/soak_tests.sh N [--loaded] [--sanitize]   (N from 1 to 9999)" >&2
  exit 2
fi
shift
loaded=0
testArgs=()
for a in "$@"; do
  case "$a" in
    --loaded) loaded=1 ;;
    --sanitize) testArgs+=(--sanitize) ;;
    *) echo "soak_tests: unknown option '$a' (--loaded, --sanitize)" >&2; exit 2 ;;
  esac
done
ISOTRACE_SKIP_BUILD=1 ./scripts/setup.sh  # stress-ng is among the packages it installs
clone=/tmp/isotrace-soak
logs=/tmp/isotrace-soak-logs
rm -rf "$clone" "$logs"
mkdir -p "$logs"
git clone -q . "$clone"
echo "soak: $runs runs of ./test.sh ${testArgs[*]:-} on $(git rev-parse --short HEAD)$([ $loaded = 1 ] && echo ", under stress-ng --cpu $(nproc)")"
stress=""
if [ $loaded = 1 ]; then
  stress-ng --cpu "$(nproc)" --quiet &
  stress=$!
  trap 'kill $stress 2>/dev/null || true; wait $stress 2>/dev/null || true' EXIT
fi
passed=0
failed=0
for i in $(seq 1 "$runs"); do
  start=$(date +%s)
  if (cd "$clone" && ./test.sh ${testArgs[@]+"${testArgs[@]}"}) > "$logs/run-$i.log" 2>&1; then
    passed=$((passed + 1))
    verdict="passed"
    rm -f "$logs/run-$i.log"
  else
    failed=$((failed + 1))
    verdict="FAILED ($(grep -E '^\s+[0-9]+ - ' "$logs/run-$i.log" | sed 's/^ *//' | tr '\n' ';' | head -c 300); log: $logs/run-$i.log)"
  fi
  echo "soak: run $i: $verdict in $(( $(date +%s) - start )) s"
done
echo "soak: $passed passed, $failed failed"
[ $failed -eq 0 ]
