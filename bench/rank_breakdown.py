#!/usr/bin/env python3
"""Where data-parallel ranks spend instructions that one process does not (callgrind, function by function).

Renders SCENE once in one process (counting inside renderFrame) and once data-parallel over N
ranks under mpirun (counting inside renderFrameDataParallel on every rank), all under valgrind's
callgrind with 1 thread, and prints what the ranks together execute beyond one process, grouped:

  MPI          Open MPI and the message loop (progress, probes, receives, the ranks' mutexes; mostly
               polling while a rank waits, so it grows with the waits valgrind's slowness makes)
  ask          choosing whom to ask about each ray (RankTracer::ask, its box tests)
  answer       answering (RankTracer::answer and its loop, less the walks it calls)
  memory       memset and memcpy (the frame's sums, messages' buffers)
  rest         everything else: walks and Embree traversals of answered rays, the driver

then the functions whose counts differ most. Self costs (callgrind_annotate --inclusive=no), so
each instruction is counted once. Counts repeat for the one process; the ranks' totals move with
their waits (polling), the functions' own counts much less.
Usage: bench/rank_breakdown.py SCENE.json [--ranks 2] [--resolution 240x135] [--spp 8]
       [--replicate F] [--isotrace BINARY] [--top 20] [--json FILE]
"""
import argparse
import collections
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from stage_breakdown import ROOT, valgrind_env  # noqa: E402

GROUPS = [
    ("MPI", r"mca_|opal_|PMPI_|ompi_|handleWhatCame|pthread_mutex|Outbox|mpi::receive|libnbc|mca_btl|mca_pml"),
    ("ask", r"RankTracer::ask|RankTracer::Box::|RankTracer::whomToAsk|RankTracer::SplitVolume"),
    ("answer", r"RankTracer::answer|start_for<.*RankTracer::parallel"),
    ("memory", r"memset|memmove|memcpy"),
]


def self_costs(out):
    """{function: self instructions} from callgrind_annotate (object files of unnamed functions kept)."""
    text = subprocess.run(["callgrind_annotate", "--inclusive=no", "--threshold=100", out], stdout=subprocess.PIPE,
                          stderr=subprocess.DEVNULL, text=True).stdout
    costs = collections.Counter()
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+)\s+\(\s*[\d.]+%\)\s+(.*)$", line)
        if not m or "PROGRAM TOTALS" in m.group(2):
            continue
        name = m.group(2).replace("(anonymous namespace)", "anon")
        obj = re.search(r"\[([^\]]*)\]\s*$", name)
        name = re.sub(r"\s*\[[^\]]*\]\s*$", "", name)
        name = re.sub(r"^\S*?:", "", name, count=1)  # the source file
        name = re.sub(r"\(.*", "", name)
        if name.startswith("0x") and obj:
            name = os.path.basename(obj.group(1)) + ":" + name
        costs[name[:110]] += int(m.group(1).replace(",", ""))
    return costs


def group_of(name):
    for group, pattern in GROUPS:
        if re.search(pattern, name):
            return group
    return "rest"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--ranks", type=int, default=2)
    ap.add_argument("--resolution", default="240x135")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--replicate")
    ap.add_argument("--isotrace", default=os.path.join(ROOT, "build", "isotrace"))
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--json", help="also write every function's self costs here (one process, each rank) to compare runs")
    args = ap.parse_args()
    if args.ranks < 2 or args.ranks > 16:
        sys.exit("rank_breakdown: --ranks: 2 to 16")
    for tool in ("valgrind", "mpirun", "callgrind_annotate"):
        if not shutil.which(tool):
            sys.exit("rank_breakdown: needs %s" % tool)
    with tempfile.TemporaryDirectory() as work:
        env = valgrind_env(args.isotrace, work)
        common = ["render", args.scene, "--resolution", args.resolution, "--spp", str(args.spp), "--threads", "1",
                  "--seed", "7", "--quiet", "--denoise", "off"]
        single = os.path.join(work, "single.out")
        r = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=" + single,
                            "--toggle-collect=iso::renderFrame(*", args.isotrace] + common +
                           ["-o", os.path.join(work, "one.exr")], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
        if r.returncode != 0:
            sys.exit("rank_breakdown: one process failed:\n" + r.stderr[-2000:])
        mpi = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(args.ranks)]
        if "LD_PRELOAD" in env:
            mpi += ["-x", "LD_PRELOAD=" + env["LD_PRELOAD"]]
        extra = ["--data-parallel"] + (["--replicate", args.replicate] if args.replicate else [])
        r = subprocess.run(mpi + ["valgrind", "--tool=callgrind",
                                  "--callgrind-out-file=" + os.path.join(work, "rank.%q{OMPI_COMM_WORLD_RANK}.out"),
                                  "--toggle-collect=iso::renderFrameDataParallel(*", args.isotrace] + common + extra +
                           ["-o", os.path.join(work, "ranks.exr")], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
        if r.returncode != 0:
            sys.exit("rank_breakdown: the ranks failed:\n" + r.stderr[-2000:])
        one = self_costs(single)
        ranks = [self_costs(os.path.join(work, "rank.%d.out" % q)) for q in range(args.ranks)]
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"one": one, "ranks": ranks}, f)
    both = collections.Counter()
    for c in ranks:
        both.update(c)
    base = sum(one.values())
    print("one process: %.1f M; ranks: %s = %.1f M (%+.1f%%)" % (
        base / 1e6, " + ".join("%.1f" % (sum(c.values()) / 1e6) for c in ranks), sum(both.values()) / 1e6,
        100.0 * (sum(both.values()) - base) / base))
    extra_by_group = collections.Counter()
    for name in set(one) | set(both):
        extra_by_group[group_of(name)] += both[name] - one[name]
    print("%-8s %12s %14s" % ("group", "extra M", "of one process"))
    for group in [g for g, _ in GROUPS] + ["rest"]:
        print("%-8s %+12.1f %13.1f%%" % (group, extra_by_group[group] / 1e6, 100.0 * extra_by_group[group] / base))
    print("\nfunctions (one process M, ranks M, extra M):")
    names = sorted(set(one) | set(both), key=lambda n: -abs(both[n] - one[n]))
    for n in names[:args.top]:
        print("%10.1f %10.1f %+10.1f  %s" % (one[n] / 1e6, both[n] / 1e6, (both[n] - one[n]) / 1e6, n))


if __name__ == "__main__":
    main()
