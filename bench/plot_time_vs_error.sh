#!/usr/bin/env bash
# Plots time per ray against error from `isotrace bench --json` (docs/bench_results.json):
# one point per intersector, secondary rays, averaged over the scene's iso-surfaces, with the
# Pareto front (no other intersector is both faster and more accurate).
#   bench/plot_time_vs_error.sh [RESULTS.json] [OUT.png]
# Needs python3 and gnuplot (Debian: gnuplot-nox; installed here if missing).
set -euo pipefail
cd "$(dirname "$0")/.."
in="${1:-docs/bench_results.json}"
out="${2:-docs/time_vs_error.png}"
if ! command -v gnuplot >/dev/null; then
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends gnuplot-nox >/dev/null
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 - "$in" "$tmp" <<'PY'
import json, sys
results = json.load(open(sys.argv[1]))["results"]
agg = {}
for r in results:
    if r["rays"] != "secondary":
        continue
    a = agg.setdefault(r["intersector"], {"ns": [], "misses": 0, "false": 0, "hits": 0, "count": 0, "p99": 0.0})
    a["ns"].append(r["ns_per_ray"]); a["misses"] += r["misses"]; a["false"] += r["false_hits"]
    a["hits"] += r["reference_hits"]; a["count"] += r["count"]; a["p99"] = max(a["p99"], r["p99_dt"])
rows = []
for name, a in agg.items():
    ns = sum(a["ns"]) / len(a["ns"])
    err = (a["misses"] + a["false"]) / max(a["hits"], 1)
    rows.append((ns, max(err, 1e-6), max(a["p99"], 1e-9), name, err))
rows.sort()
with open(sys.argv[2] + "/points.dat", "w") as f:
    for ns, err, p99, name, raw in rows:
        f.write(f"{ns:.1f} {err:.6g} {p99:.6g} {name}\n")
# Labels. Left panel: intersectors with the same error rate share one label ("isolation:1/2/8").
# Right panel: one label each, alternately above and below its point so that neighbours do not
# overwrite each other.
groups = {}
for ns, err, p99, name, raw in rows:
    groups.setdefault(err, []).append((ns, name))
with open(sys.argv[2] + "/labels_rate.dat", "w") as f:
    for err, members in groups.items():
        by_base = {}
        for ns, name in members:
            base, _, steps = name.partition(":")
            by_base.setdefault(base, []).append(steps)
        text = ", ".join(base + (":" + "/".join(s for s in steps if s) if any(steps) else "") for base, steps in by_base.items())
        f.write(f"{min(ns for ns, _ in members):.1f} {err:.6g} \"{text}\"\n")
with open(sys.argv[2] + "/labels_dt.dat", "w") as f:
    for i, (ns, err, p99, name, raw) in enumerate(sorted(rows, key=lambda r: r[2])):
        f.write(f"{ns:.1f} {p99:.6g} {name} {1.0 if i % 2 == 0 else -1.0}\n")
# Pareto fronts per panel: no other intersector is both at least as fast and as accurate.
for k, col in ((1, "front_rate.dat"), (2, "front_dt.dat")):
    front = [r for r in rows if not any(o[0] <= r[0] and o[k] <= r[k] and (o[0] < r[0] or o[k] < r[k]) for o in rows)]
    with open(sys.argv[2] + "/" + col, "w") as f:
        for r in sorted(front):
            f.write(f"{r[0]:.1f} {r[k]:.6g} {r[3]}\n")
PY
gnuplot <<GP
set terminal pngcairo size 1200,520 font "sans,10"
set output "$out"
set multiplot layout 1,2 title "isotrace intersectors: time per secondary ray against error vs reference (mean over 6 iso-surfaces)"
set logscale y
set grid
set xlabel "ns per ray (single thread, whole-grid traversal)"
set ylabel "(misses + false hits) / reference hits   (0 drawn at 1e-6)"
set key center right
set offsets 0, 90, 0, 0
plot "$tmp/points.dat" using 1:2 with points pt 7 ps 1.2 title "intersector", \
     "$tmp/labels_rate.dat" using 1:2:3 with labels left offset 0.5,0.8 font ",8" notitle, \
     "$tmp/front_rate.dat" using 1:2 with steps lw 2 title "Pareto front"
set ylabel "worst p99 |dt| over the iso-surfaces (cells)"
plot "$tmp/points.dat" using 1:3 with points pt 7 ps 1.2 title "intersector", \
     "$tmp/labels_dt.dat" using 1:(\$4 > 0 ? \$2 : 1/0):3 with labels left offset 0.5,0.7 font ",8" notitle, \
     "$tmp/labels_dt.dat" using 1:(\$4 < 0 ? \$2 : 1/0):3 with labels left offset 0.5,-0.7 font ",8" notitle, \
     "$tmp/front_dt.dat" using 1:2 with steps lw 2 title "Pareto front"
unset multiplot
GP
echo "$out"
