#!/usr/bin/env python3
"""Where a render's instructions go, stage by stage (callgrind, inside the tiles' passes).

Renders SCENE once under valgrind's callgrind (1 thread, 160x90, 4 spp unless told otherwise),
counting only inside TileRenderer::renderPass, and splits the count into the wavefront flow's
stages by callgrind's inclusive costs:

  camera      Wave::start: camera rays and samplers, the integrator's start
  collect     Wave::collect: gathering each stage's rays into a batch
  embree      Embree's BVH traversal and triangle tests (rtcIntersect1/8, rtcOccluded1/8 less the
              iso-surface callbacks they call)
  iso walk    the iso-surface brick callbacks (cell walks, solves, refinement)
  hit records the World's queries around Embree: rays moved onto volume boxes, packets packed,
              Embree's hits turned into Hits (World::fillHit, fillIsoHit, smooth normals)
  shading     Wave::deliver: the integrator's stages (BSDFs, light sampling, spawning rays)
  sums        the rest of the pass: pixel sums in sample order (Wave::finish, addSample)

Counts repeat exactly for the same binary and inputs, whatever else the machine does, so two
builds can be compared on a shared machine (--isotrace OTHER for the second column).
Usage: bench/stage_breakdown.py SCENE.json [--integrator NAME] [--ray-flow F] [--resolution WxH]
       [--spp N] [--isotrace BINARY ...] [--json FILE]

Debian 12's Highway (libhwy, loaded by OpenImageIO's JPEG XL plugin) runs `rdtscp` in a
constructor, which valgrind 3.19 does not decode on every CPU (SIGILL before main): where the
binary loads libhwy, a one-function library built here in a temporary folder stands in for
hwy::platform::TimerResolution (LD_PRELOAD). The render itself never calls Highway's timer.
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COUNTED = "iso::TileRenderer::renderPass(*"
SHIM = "#include <cstdint>\nnamespace hwy { namespace platform { uint64_t TimerResolution() { return 1; } } }\n"


def valgrind_env(binary, work):
    """The environment callgrind runs `binary` in (with the Highway timer shim where needed)."""
    env = dict(os.environ)
    ldd = subprocess.run(["ldd", binary], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True).stdout
    if "libhwy" in ldd:
        src, lib = os.path.join(work, "hwy_shim.cpp"), os.path.join(work, "hwy_shim.so")
        if not os.path.exists(lib):
            with open(src, "w") as f:
                f.write(SHIM)
            subprocess.run(["c++", "-O2", "-shared", "-fPIC", src, "-o", lib], check=True)
        env["LD_PRELOAD"] = lib
    return env


def callgrind(binary, args, work):
    """Runs `binary args` under callgrind counting inside renderPass; returns the output file."""
    out = os.path.join(work, "callgrind.%d.out" % len(os.listdir(work)))
    r = subprocess.run(["valgrind", "--tool=callgrind", "--callgrind-out-file=" + out, "--toggle-collect=" + COUNTED,
                        binary] + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                       env=valgrind_env(binary, work))
    if r.returncode != 0:
        sys.exit("stage_breakdown: %s failed:\n%s" % (binary, r.stderr[-2000:]))
    return out


def inclusive(out):
    """{function name: inclusive instructions} from callgrind_annotate."""
    text = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", out], stdout=subprocess.PIPE,
                          stderr=subprocess.DEVNULL, text=True).stdout
    costs = {}
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+) \([ \d.]+%\)\s+\S*?:(.*?)( \[[^\]]*\])?$", line)
        if m:
            name = m.group(2)
            costs[name] = max(costs.get(name, 0), int(m.group(1).replace(",", "")))
    return costs


def total(costs, pattern):
    return sum(v for k, v in costs.items() if re.match(pattern, k))


def stages(costs):
    all_ = total(costs, r"iso::TileRenderer::renderPass\(")
    camera = total(costs, r"iso::Wave::start\(")
    collect = total(costs, r"iso::Wave::collect\(")
    embree_all = total(costs, r"rtc(Intersect|Occluded)(1|8|16)$")
    iso = total(costs, r"iso::\(anonymous namespace\)::(intersect|occluded)Callback")
    traced = total(costs, r"iso::traceBatch\(")
    shading = total(costs, r"iso::Wave::deliver\(")
    if traced == 0:  # the scalar flow: its queries are World::intersect/occluded under Li
        traced = total(costs, r"iso::World::(intersect|occluded)\(") + total(costs, r"iso::World::(intersect|occluded)Packet\(")
    out = {
        "camera": camera,
        "collect": collect,
        "embree": embree_all - iso,
        "iso walk": iso,
        "hit records": traced - embree_all,
        "shading": shading,
    }
    out["sums"] = all_ - sum(out.values())
    out["all"] = all_
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--isotrace", action="append", help="binaries to compare (default: build/isotrace)")
    ap.add_argument("--integrator")
    ap.add_argument("--ray-flow", default="wavefront")
    ap.add_argument("--resolution", default="160x90")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--json")
    args = ap.parse_args()
    if not shutil.which("valgrind"):
        sys.exit("stage_breakdown: needs valgrind (apt-get install valgrind)")
    binaries = args.isotrace or [os.path.join(ROOT, "build", "isotrace")]
    results = []
    with tempfile.TemporaryDirectory() as work:
        for b in binaries:
            extra = ["--integrator", args.integrator] if args.integrator else []
            out = callgrind(b, ["render", args.scene, "-o", os.path.join(work, "x.exr"), "--resolution", args.resolution,
                                "--spp", str(args.spp), "--threads", "1", "--seed", "7", "--quiet",
                                "--ray-flow", args.ray_flow] + extra, work)
            results.append(stages(inclusive(out)))
    names = ["camera", "collect", "embree", "iso walk", "hit records", "shading", "sums", "all"]
    print("%-12s" % "stage" + "".join("%14s" % ("M #%d" % i) for i in range(len(binaries))) +
          ("%10s" % "ratio" if len(binaries) == 2 else ""))
    for n in names:
        row = "%-12s" % n + "".join("%14.1f" % (r[n] / 1e6) for r in results)
        if len(binaries) == 2:
            row += "%10.3f" % (results[0][n] / results[1][n] if results[1][n] else float("nan"))
        print(row)
    for i, b in enumerate(binaries):
        print("#%d: %s" % (i, b))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"scene": args.scene, "binaries": binaries, "stages": results,
                       "integrator": args.integrator, "ray_flow": args.ray_flow, "resolution": args.resolution,
                       "spp": args.spp}, f, indent=1)


if __name__ == "__main__":
    main()
