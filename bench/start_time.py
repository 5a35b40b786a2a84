#!/usr/bin/env python3
"""Whole commands' wall time and peak memory, two builds alternating: what a user waits for,
start-up and image writing included (bench/ab_time.py times the render alone).

For each command, runs build A then build B, --pairs times, and prints each build's median wall
seconds and peak resident memory (the process's own, from wait4), and B's median over A's. The
default commands are short on purpose: they are the ones where a fixed cost per start shows.

Usage: bench/start_time.py [--pairs 10] BUILD_A BUILD_B [-- ARGS ...]
  e.g. bench/start_time.py /tmp/old/build/isotrace build/isotrace
  (ARGS: one command's arguments instead of the defaults; the word OUT stands for an output
   folder, e.g. -- render examples/quick_look.json -o OUT/x.png)
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULTS = [
    ["--version"],
    ["info", os.path.join(ROOT, "examples", "quick_look.json")],
    ["render", os.path.join(ROOT, "examples", "quick_look.json"), "--resolution", "320x180", "--quiet", "-o", "OUT/q.png"],
    ["render", os.path.join(ROOT, "examples", "default.json"), "--resolution", "160x90", "--spp", "4", "--denoise", "off",
     "--quiet", "-o", "OUT/d.exr"],
]


def run(binary, args, out):
    """Wall seconds and peak resident KiB of one run."""
    cmd = [binary] + [a.replace("OUT", out) for a in args]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    seconds = time.perf_counter() - t0
    err = p.stderr.read().decode()
    p.stderr.close()
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        sys.exit("start_time: %s failed (status %d):\n%s" % (" ".join(cmd), p.returncode, err.strip()))
    return seconds, usage.ru_maxrss


def main():
    argv = sys.argv[1:]
    extra = None
    if "--" in argv:
        extra = argv[argv.index("--") + 1:]
        argv = argv[:argv.index("--")]
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("a")
    parser.add_argument("b")
    parser.add_argument("--pairs", type=int, default=10)
    args = parser.parse_args(argv)
    if args.pairs < 1:
        sys.exit("start_time: --pairs must be at least 1")
    commands = [extra] if extra else DEFAULTS
    print("| command | A s | B s | B/A | A MiB | B MiB |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as out:
        for command in commands:
            a, b = [], []
            for _ in range(args.pairs):
                a.append(run(args.a, command, out))
                b.append(run(args.b, command, out))
            ma, mb = statistics.median(s for s, _ in a), statistics.median(s for s, _ in b)
            ra, rb = statistics.median(k for _, k in a) / 1024, statistics.median(k for _, k in b) / 1024
            shown = " ".join(os.path.relpath(c, ROOT) if c.startswith(ROOT) else c for c in command)
            print("| `%s` | %.3f | %.3f | %.2f | %.0f | %.0f |" % (shown, ma, mb, mb / ma, ra, rb), flush=True)


if __name__ == "__main__":
    main()
