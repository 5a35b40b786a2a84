#!/usr/bin/env python3
"""Two builds timed on the same render, alternating run by run, with what the machine's noise allows.

This machine's speed swings by ~30% from one run to the next (two states: the same 1-thread render
takes ~2.05 s or ~2.7 s, docs/BENCHMARKS.md "The machine's two speeds"), so a 1-5% change cannot be
read off medians of 3. This script renders with A, then B, N times, and prints:
  - each build's median render seconds (from --stats) and B's median over A's;
  - the median of the per-pair ratios B/A (a pair runs back to back, so it more often shares a state);
  - in how many pairs B was faster, with the two-sided sign-test p-value (how often k or more of N
    pairs would go one way if the builds were equally fast).
A p-value above ~0.05 says the difference is within what this machine can resolve at this N.

Usage: bench/ab_time.py [--pairs 10] BUILD_A BUILD_B -- render SCENE.json [render flags...]
  e.g. bench/ab_time.py /tmp/old/isotrace build/isotrace -- render bench/scenes/lidc2.json \\
           --resolution 960x540 --spp 4 --integrator normals --threads 1
(--stats, -o and --quiet are added; mpirun is not: a command that starts with `mpirun` runs as given,
 with the build's path in place of the word ISOTRACE.)
"""
import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile


def seconds(command, binary, work, tag):
    stats, image = os.path.join(work, tag + ".json"), os.path.join(work, tag + ".exr")
    if command[0] == "mpirun":
        cmd = [binary if word == "ISOTRACE" else word for word in command]
    else:
        cmd = [binary] + command
    cmd += ["--stats", stats, "-o", image, "--quiet"]
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("ab_time: %s failed (status %d):\n%s" % (" ".join(cmd), r.returncode, r.stderr.strip()))
    with open(stats) as f:
        return json.load(f)["seconds"]["render"]


def sign_test(k, n):
    """Two-sided p-value of k or more (or n - k or fewer) of n fair coin flips going one way."""
    tail = sum(math.comb(n, i) for i in range(max(k, n - k), n + 1)) / 2.0 ** n
    return min(1.0, 2 * tail)


def main():
    argv = sys.argv[1:]
    if "--" not in argv:
        sys.exit("usage: bench/ab_time.py [--pairs N] BUILD_A BUILD_B -- render SCENE.json [flags...]")
    split = argv.index("--")
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pairs", type=int, default=10)
    parser.add_argument("a")
    parser.add_argument("b")
    args = parser.parse_args(argv[:split])
    command = argv[split + 1:]
    if not command:
        sys.exit("ab_time: no render command after --")
    if args.pairs < 1 or args.pairs > 1000:
        sys.exit("ab_time: --pairs must be 1 to 1000")
    for build in (args.a, args.b):
        if not os.access(build, os.X_OK):
            sys.exit("ab_time: %s is not an executable build" % build)
    a, b = [], []
    with tempfile.TemporaryDirectory() as work:
        for i in range(args.pairs):
            a.append(seconds(command, args.a, work, "a"))
            b.append(seconds(command, args.b, work, "b"))
            print("pair %d: A %.3f s, B %.3f s, B/A %.3f" % (i + 1, a[-1], b[-1], b[-1] / a[-1]), file=sys.stderr)
    ratios = [y / x for x, y in zip(a, b)]
    faster = sum(1 for r in ratios if r < 1)
    ma, mb = statistics.median(a), statistics.median(b)
    print("A %s: median %.3f s (%.3f-%.3f)" % (args.a, ma, min(a), max(a)))
    print("B %s: median %.3f s (%.3f-%.3f)" % (args.b, mb, min(b), max(b)))
    print("B/A: medians %.3f, median of the pairs %.3f; B faster in %d of %d pairs (sign test p = %.3f)" % (
        mb / ma, statistics.median(ratios), faster, len(ratios), sign_test(faster, len(ratios))))


if __name__ == "__main__":
    main()
