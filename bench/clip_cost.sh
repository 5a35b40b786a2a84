#!/usr/bin/env bash
# bench/clip_cost.sh [SCENE] [ROUNDS]: what a clip costs. Renders SCENE (default
# examples/default.json: a glTF engine and the neghip protein, path traced) three ways, the ways
# interleaved ROUNDS times (default 7) so that the machine's drift hits all alike:
#   none     the scene as it is
#   nothing  with a scene clip plane that cuts nothing (it lies beyond everything)
#   half     with a scene clip plane through the point the camera looks at, cutting away what is above it
# and prints each way's median render time, its ratio to `none`, and the traversal counters
# (cells visited and solved: the same counts mean the same work).
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-examples/default.json}
rounds=${2:-7}
isotrace=${ISOTRACE:-build/isotrace}  # (ISOTRACE=path: another build)
[ -x $isotrace ] || { echo "clip_cost: build first (./run.sh or ./test.sh)" >&2; exit 2; }
[[ "$rounds" =~ ^[0-9]+$ ]] && [ "$rounds" -ge 1 ] || { echo "clip_cost: ROUNDS must be a whole number >= 1" >&2; exit 2; }
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
# Where the scene is (`isotrace info`): its meshes' bounds, for a plane beyond everything, and the
# point the camera looks at, for a plane through what the image shows.
read -r cx cy cz size < <(python3 - "$scene" "$isotrace" <<'PY'
import json, re, subprocess, sys
scene, isotrace = sys.argv[1:3]
info = subprocess.run([isotrace, "info", scene], capture_output=True, text=True, check=True).stdout
lo = [float("inf")] * 3
hi = [-float("inf")] * 3
for m in re.finditer(r"bounds \(([^)]*)\) to \(([^)]*)\)", info):
    a = [float(v) for v in m.group(1).split(",")]
    b = [float(v) for v in m.group(2).split(",")]
    lo = [min(x, y) for x, y in zip(lo, a)]
    hi = [max(x, y) for x, y in zip(hi, b)]
if lo[0] == float("inf"):
    lo, hi = [-1, -1, -1], [1, 1, 1]
m = re.search(r"looking at \(([^)]*)\)", info)
centre = [float(v) for v in m.group(1).split(",")] if m else [(x + y) / 2 for x, y in zip(lo, hi)]
size = max(max(abs(v) for v in lo + hi), max(y - x for x, y in zip(lo, hi)))
print(*centre, size)
PY
)
far=$(python3 -c "print(10 * $size + 10)")
nothing="[{\"plane\": {\"point\": [$far, 0, 0], \"normal\": [1, 0, 0]}}]"
half="[{\"plane\": {\"point\": [$cx, $cy, $cz], \"normal\": [0, 1, 0]}}]"
for r in $(seq "$rounds"); do
  $isotrace render "$scene" -o "$out/none.png" --stats "$out/none_$r.json" 2>/dev/null >/dev/null
  $isotrace render "$scene" -o "$out/nothing.png" --set "/clip=$nothing" --stats "$out/nothing_$r.json" 2>/dev/null >/dev/null
  $isotrace render "$scene" -o "$out/half.png" --set "/clip=$half" --stats "$out/half_$r.json" 2>/dev/null >/dev/null
done
python3 - "$out" "$rounds" "$scene" <<'PY'
import json, statistics, sys
out, rounds, scene = sys.argv[1], int(sys.argv[2]), sys.argv[3]
def load(way):
    runs = [json.load(open(f"{out}/{way}_{r}.json")) for r in range(1, rounds + 1)]
    return statistics.median(x["seconds"]["render"] for x in runs), runs[0]["counters"]
base, baseCounters = load("none")
print(f"clip_cost: {scene}, {rounds} interleaved rounds, median render seconds")
print(f"{'way':8} {'render s':>9} {'ratio':>7} {'cells visited':>14} {'cells solved':>13}")
for way in ("none", "nothing", "half"):
    t, c = load(way)
    print(f"{way:8} {t:9.3f} {t / base:7.3f} {c.get('Iso/CellsVisited', 0):14d} {c.get('Iso/CellsSolved', 0):13d}")
PY
