#!/usr/bin/env python3
"""Noise at equal time: renders one scene with several configurations (a build and flags each),
interleaved, and compares each image with a reference image of many samples.

    bench/equal_time.py --reference REF.exr SCENE.json LABEL=BIN:FLAGS [LABEL=BIN:FLAGS ...]

For each configuration it prints the median render seconds (from --stats), the median RMS
error against the reference (oiiotool --diff, over R, G, B), and RMSE * sqrt(seconds): the
error the configuration would reach in one second (error falls as 1/sqrt(time) for an
unbiased estimator), with its ratio to the first configuration's. A biased configuration
(--clamp) has an error floor that this extrapolation does not see: compare its error at the
time measured. Make the reference with the build you trust at many samples, e.g.
`isotrace render SCENE --spp 1024 --seed 99 -o REF.exr`.
"""
import argparse
import json
import math
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile


def render(binary, scene, flags, seed, workdir):
    image = os.path.join(workdir, "image.exr")
    stats = os.path.join(workdir, "stats.json")
    cmd = [binary, "render", scene, "-o", image, "--stats", stats, "--seed", str(seed), "--quiet"] + flags
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(stats) as f:
        seconds = json.load(f)["seconds"]["render"]
    return image, seconds


def rms_error(image, reference):
    out = subprocess.run(["oiiotool", image, "--ch", "R,G,B", reference, "--ch", "R,G,B", "--diff"],
                         capture_output=True, text=True).stdout
    m = re.search(r"RMS error = ([0-9.eE+-]+)", out)
    if not m:
        sys.exit("equal_time.py: cannot read the RMS error from oiiotool:\n" + out)
    return float(m.group(1))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--reference", required=True)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("scene")
    p.add_argument("configs", nargs="+", help="LABEL=BIN:FLAGS")
    a = p.parse_args()
    configs = []
    for c in a.configs:
        label, _, rest = c.partition("=")
        binary, _, flags = rest.partition(":")
        if not label or not binary:
            sys.exit("equal_time.py: expected LABEL=BIN:FLAGS, got " + c)
        configs.append((label, binary, shlex.split(flags)))
    results = {label: ([], []) for label, _, _ in configs}
    with tempfile.TemporaryDirectory() as work:
        for run in range(a.runs):
            for label, binary, flags in configs:
                image, seconds = render(binary, a.scene, flags, 1 + run, work)
                results[label][0].append(seconds)
                results[label][1].append(rms_error(image, a.reference))
    print(f"scene {a.scene}, reference {a.reference}, {a.runs} interleaved runs (seeds 1..{a.runs})")
    print(f"{'configuration':<28} {'render s':>9} {'RMSE':>9} {'RMSE*sqrt(s)':>13} {'vs first':>9}")
    first = None
    for label, binary, flags in configs:
        s = statistics.median(results[label][0])
        e = statistics.median(results[label][1])
        norm = e * math.sqrt(s)
        first = first or norm
        print(f"{label:<28} {s:9.3f} {e:9.5f} {norm:13.5f} {norm / first:9.2f}")


if __name__ == "__main__":
    main()
