#!/usr/bin/env python3
"""One process against N MPI ranks, the same render, interleaved.

For each scene, renders with one process (--threads T) and with `mpirun -np N` (--threads T
per rank), alternating, --runs times; prints the median render seconds of each, the speed-up,
pieces per second, the balance (busiest over idlest rank's busy seconds, from --stats) and the
busy seconds of each rank, and checks that both images are the same bits. ISOTRACE=path runs
another build.

--against OTHER: each run also renders the N ranks with another build (e.g. an older commit's), in
turn with this build's; prints its median and this build's speed-up over it (the shared machine's
noise hits both alike).

--with-threads: each run also renders one process with ranks x threads threads (the same cores
as the ranks, in one process); prints its median and the ranks' time over it: what running as
separate processes costs against threads on this machine, measured in the same runs (the
machine's speed can change by 30% from one run to the next).

--data-parallel: both renders with --data-parallel (the ranks each hold part of every volume
and answer each other's rays; one process is the same render whole); also prints the rays the
ranks asked each other about, the bytes they sent per frame and the seconds they spent in the
exchanges. --replicate F: the ranks also hold copies of the bricks around their parts, up to F of
each volume (render --replicate).

Usage: bench/mpi_scaling.py [--runs 3] [--ranks 2] [--threads 1] [--resolution 960x540]
       [--spp 16] [--data-parallel [--replicate F]] [--against OTHER_ISOTRACE] [--with-threads] [SCENE.json ...]      (default: bench/scenes/gyroid_ball.json)
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ISOTRACE = os.environ.get("ISOTRACE", os.path.join(ROOT, "build", "isotrace"))  # ISOTRACE=path: another build


def render(prefix, scene, args, image, stats, binary=None):
    cmd = prefix + [binary or ISOTRACE, "render", scene, "-o", image, "--quiet", "--stats", stats] + args
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("mpi_scaling: %s failed:\n%s" % (" ".join(cmd), r.stderr))
    with open(stats) as f:
        return json.load(f)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="*")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--ranks", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--resolution", default="960x540")
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--data-parallel", action="store_true")
    parser.add_argument("--replicate", type=float, help="with --data-parallel: each rank's copies of other ranks' bricks "
                        "(render --replicate), a fraction of each volume")
    parser.add_argument("--against", help="another build's isotrace: its N-rank renders in turn with this one's")
    parser.add_argument("--with-threads", action="store_true",
                        help="also one process with ranks x threads threads, in the same runs")
    a = parser.parse_args()
    scenes = a.scenes or [os.path.join(ROOT, "bench", "scenes", "gyroid_ball.json")]
    mpirun = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-np", str(a.ranks)]
    args = ["--resolution", a.resolution, "--spp", str(a.spp), "--threads", str(a.threads), "--seed", "7"]
    if a.data_parallel:
        args.append("--data-parallel")
        if a.replicate is not None:
            args += ["--replicate", repr(a.replicate)]
    elif a.replicate is not None:
        sys.exit("mpi_scaling: --replicate is for --data-parallel")
    # busy per rank: the seconds each rank's render threads spent in pieces (wall time of the
    # pieces): their sum over the 1-process seconds is what running beside MPI costs the work.
    print("| scene | 1 process s | %d ranks s | speed-up | pieces/s | balance | busy per rank s | same image |" % a.ranks)
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as work:
        for scene in scenes:
            one, many, pieces, balance, busy, traffic, other, threaded = [], [], [], [], [], [], [], []
            same = True
            for _ in range(a.runs):
                s1 = render([], scene, args, os.path.join(work, "one.exr"), os.path.join(work, "one.json"))
                if a.against:
                    so = render(mpirun, scene, args, os.path.join(work, "other.exr"), os.path.join(work, "other.json"),
                                a.against)
                    other.append(so["seconds"]["render"])
                if a.with_threads:
                    wide = args[:args.index("--threads")] + ["--threads", str(a.ranks * a.threads)] + \
                        args[args.index("--threads") + 2:]
                    st = render([], scene, wide, os.path.join(work, "threads.exr"), os.path.join(work, "threads.json"))
                    threaded.append(st["seconds"]["render"])
                sn = render(mpirun, scene, args, os.path.join(work, "many.exr"), os.path.join(work, "many.json"))
                same = same and s1["rays"] == sn["rays"] and pixels_equal(work)
                one.append(s1["seconds"]["render"])
                many.append(sn["seconds"]["render"])
                pieces.append(sum(sn["tiles_per_rank"]) / sn["seconds"]["render"])
                balance.append(sn["balance"])
                busy.append(sn["busy_seconds_per_rank"])
                if a.data_parallel:
                    traffic.append((sum(sn["rays_asked_per_rank"]), sum(sn["bytes_sent_per_rank"]),
                                    sn["exchange_seconds_per_rank"], sn["rays_received_per_rank"]))
            m1, mn = statistics.median(one), statistics.median(many)
            busyMedian = [statistics.median(b[r] for b in busy) for r in range(a.ranks)]
            print("| %s | %.3f | %.3f | **%.2f** | %.0f | %.3f | %s | %s |" % (
                os.path.splitext(os.path.basename(scene))[0], m1, mn, m1 / mn, statistics.median(pieces),
                statistics.median(balance), " / ".join("%.2f" % b for b in busyMedian), "yes" if same else "NO"))
            if traffic:
                t = traffic[len(traffic) // 2]
                print("  data-parallel: %d rays of all ranks' paths, %.1f MiB sent per frame, rays received per rank %s, "
                      "seconds waiting per rank %s" % (t[0], t[1] / 2**20, " / ".join("%d" % x for x in t[3]),
                                                       " / ".join("%.2f" % x for x in t[2])))
            if other:
                mo = statistics.median(other)
                print("  against %s: %d ranks %.3f s (runs %s), speed-up of this build %.2f" % (
                    a.against, a.ranks, mo, ", ".join("%.3f" % x for x in other), mo / mn))
            if threaded:
                mt = statistics.median(threaded)
                print("  one process x %d threads: %.3f s (runs %s), speed-up %.2f; %d ranks over it: %.3f "
                      "(per run %s)" % (a.ranks * a.threads, mt, ", ".join("%.3f" % x for x in threaded), m1 / mt,
                                        a.ranks, mn / mt, ", ".join("%.3f" % (n / t) for n, t in zip(many, threaded))))
            print("  runs: 1 process %s; %d ranks %s" % (", ".join("%.3f" % x for x in one), a.ranks,
                                                       ", ".join("%.3f" % x for x in many)), file=sys.stderr)


def pixels_equal(work):
    """The EXR files can differ in bytes the writer does not control; compare their pixels."""
    r = subprocess.run(["oiiotool", os.path.join(work, "one.exr"), os.path.join(work, "many.exr"), "--diff"],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return r.returncode == 0 and "PASS" in r.stdout


if __name__ == "__main__":
    main()
