#!/usr/bin/env bash
# bench/exactness.sh [OPTIONS]: exactness at scale. `isotrace watertight` on rough generated
# fields (bench/rough_field.py: blobs + ripple, float32, anisotropic spacing, placed at 1e5;
# three iso values each) and on every real volume of examples/data (three iso values each,
# bench/exactness_real.json, at the origin and at 1e5), then one table: rays, parity errors,
# self hits, inside escapes, shadow mismatches, and crossings lost and extra per 1e7 reference
# crossings (per ray: the reference's crossings the walk did not find, the walk's it has not).
# Every failing ray is dumped (OUT_DIR/*.failures.txt) to replay with `isotrace watertight
# SCENE --replay FILE`, and so is every parity ray whose crossings differ from the reference's
# count on its line (`--dump-lost`: the lost and extra pairs, to trace without running again).
#
# Options: --rough-rays N (default 100000000 per surface), --real-rays N (default 10000000),
#          --seeds "1 2 3" (rough fields), --intersector NAME (default isolation; `reference`
#          is the double-precision control), --ray-flow F (default wavefront: every query through
#          the packet walk; scalar: one ray at a time), --threads N, --out DIR (default out/exactness),
#          --resume (keep the runs OUT_DIR already has a report of: the run is a sequence of parts,
#          one rough field or one real volume at one offset each, so a stopped run goes on where it
#          stopped; use it only with the same build and options). The run uses its own copy of
#          build/isotrace (OUT_DIR/isotrace, kept by --resume), so rebuilding while it runs is safe.
# Time: the machine does about 1e5 rays per second per core: the defaults take hours. For a
# quick look: bench/exactness.sh --rough-rays 1000000 --real-rays 100000.
set -euo pipefail
cd "$(dirname "$0")/.."
roughRays=100000000
realRays=10000000
seeds="1 2 3"
intersector=isolation
rayFlow=wavefront
threads=0
out=out/exactness
resume=0
while [ $# -gt 0 ]; do
  case "$1" in
    --rough-rays) roughRays="$2"; shift 2 ;;
    --real-rays) realRays="$2"; shift 2 ;;
    --seeds) seeds="$2"; shift 2 ;;
    --intersector) intersector="$2"; shift 2 ;;
    --ray-flow) rayFlow="$2"; shift 2 ;;
    --threads) threads="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --resume) resume=1; shift ;;
    *) echo "exactness: unknown option '$1' (see the head of bench/exactness.sh)" >&2; exit 2 ;;
  esac
done
for n in "$roughRays" "$realRays" "$threads"; do
  [[ "$n" =~ ^[0-9]+$ ]] || { echo "exactness: '$n' is not a count" >&2; exit 2; }
done
[ -x build/isotrace ] || { echo "exactness: build first (./run.sh or ./test.sh)" >&2; exit 2; }
mkdir -p "$out"
# A copy of the binary: the parts of one table come from one build even if build/ changes.
isotrace="$out/isotrace"
if [ $resume = 0 ] || [ ! -x "$isotrace" ]; then cp build/isotrace "$isotrace"; fi
commit=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
echo "exactness: intersector $intersector, $rayFlow flow, commit $commit, $(date -u +%Y-%m-%dT%H:%MZ), $(nproc) cores" | tee -a "$out/README.txt"

run() {  # NAME SCENE RAYS OFFSET
  local name=$1 scene=$2 rays=$3 offset=$4
  [ "$rays" -gt 0 ] || return 0
  if [ $resume = 1 ] && [ -s "$out/$name.json" ]; then echo "exactness: $name: kept from before" >&2; return 0; fi
  echo "exactness: $name: $rays rays per surface, offset $offset ..." >&2
  "$isotrace" watertight "$scene" --rays "$rays" --intersector "$intersector" --ray-flow "$rayFlow" --offset "$offset" --threads "$threads" \
    --json "$out/$name.json" --dump "$out/$name.failures.txt" --dump-lost > "$out/$name.txt"
}
for seed in $seeds; do
  # The rough fields are placed at 1e5 by their own origin.
  scene=$(bench/rough_field.py "$out/fields" --seed "$seed")
  run "rough_$seed" "$scene" "$roughRays" 0,0,0
done
# One scene per real volume (its three iso values), so each finishes and reports on its own.
volumes=$(python3 - "$out/scenes" <<'PY'
import json, os, sys
os.makedirs(sys.argv[1], exist_ok=True)
for i, v in enumerate(json.load(open("bench/exactness_real.json"))["volumes"]):
    v = dict(v, file=os.path.abspath(os.path.join("bench", v["file"])))
    json.dump({"volumes": [v]}, open(os.path.join(sys.argv[1], "real_v%d.json" % i), "w"))
    print(i)
PY
)
for offset in 0,0,0 1e5,1e5,1e5; do
  for v in $volumes; do
    run "real_at_${offset%%,*}_v$v" "$out/scenes/real_v$v.json" "$realRays" "$offset"
  done
done

python3 - "$out" "$intersector" <<'PY'
import glob, json, os, sys
out, intersector = sys.argv[1:3]
real = json.load(open("bench/exactness_real.json"))["volumes"]
per1e7 = lambda n, ref: n / ref * 1e7 if ref else 0.0
rows = []
lost = extra = reference = 0
for path in sorted(glob.glob(os.path.join(out, "*.json"))):
    name = os.path.basename(path)[:-5]
    report = json.load(open(path))
    for s in report["surfaces"]:
        if name.startswith("rough"):
            what = "%s (1e5)" % name
        else:  # real_at_OFFSET_vN: volume N of bench/exactness_real.json alone
            offset, volume = name[len("real_at_"):].rsplit("_v", 1)
            what = "%s (%s)" % (os.path.basename(real[int(volume)]["file"]), "1e5" if offset == "1e5" else "origin")
        ref = s["reference_crossings"]
        lost, extra, reference = lost + s["lost_crossings"], extra + s["extra_crossings"], reference + ref
        rows.append((what, "%g" % s["iso"], s["rays"], s["parity_errors"], s["self_hits"], s["inside_escapes"],
                     s["shadow_mismatches"], s["crossings"], ref, per1e7(s["lost_crossings"], ref), per1e7(s["extra_crossings"], ref)))
head = ("volume", "iso", "rays", "parity", "self hits", "inside escapes", "shadow", "crossings", "reference", "lost / 1e7",
        "extra / 1e7")
lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
for r in rows:
    lines.append("| %s | %s | %d | %d | %d | %d | %d | %d | %d | %.2f | %.2f |" % r)
errors = sum(r[3] + r[4] + r[5] + r[6] for r in rows)
lines.append("")
lines.append("%s: %d surfaces, %d errors of any kind; of %d reference crossings %d lost (%.2f per 1e7), %d extra (%.2f per 1e7)"
             % (intersector, len(rows), errors, reference, lost, per1e7(lost, reference), extra, per1e7(extra, reference)))
text = "\n".join(lines)
open(os.path.join(out, "table.md"), "w").write(text + "\n")
print(text)
PY
