#!/usr/bin/env python3
"""The exact iso-surface against the same surface as triangles, rendered the same way.

For each scene (default: bench/scenes/*.json) every iso-surface is extracted with
`isotrace mesh` and a twin scene is written with those meshes (same materials) in place of
the volumes; then both are rendered with the same camera, lights, spp and seed, interleaved
(iso, mesh, iso, mesh, ...) so that the shared machine's noise hits both alike. Modes:

  path     the scene's own path tracing (16 spp, depth 4), 2 threads
  camera   the normals integrator, 1 thread: camera rays only
  shadow   ambient occlusion with an unbounded distance, 1 thread: camera + occlusion rays

Prints per scene and mode the median render seconds, rays per second, the iso/mesh ratio of
the medians and the relative image difference (mean |iso - mesh| / mean mesh, path mode).
Usage: bench/iso_vs_mesh.py [--runs N] [--resolution WxH] [--modes path,camera,shadow]
       [--json FILE] [--isotrace BINARY] [--instructions] [--ray-flow F | --flows] [SCENE.json ...]
--ray-flow renders every image with that ray flow (wavefront, the default, or scalar).
--flows measures both flows of the same build, interleaved (iso scalar, iso wavefront, mesh
scalar, mesh wavefront, ...): the speed-up of the wavefront flow for each twin, and the iso/mesh
ratio within each flow; with --instructions, instruction counts of the same four renders.
--isotrace renders with another build (e.g. an older commit's, to compare before and after;
the meshes are always extracted with this checkout's build/isotrace).
--instructions counts instructions instead of seconds: each twin is rendered once under
valgrind's callgrind (160x90 unless --resolution says otherwise, 4 spp, 1 thread), counting only
inside the integrator's per-ray function, so loading, building and writing the image are left
out. The counts repeat exactly from run to run and do not depend on what else the machine is
doing, which is how a step of a few percent can be judged on a shared machine (needs valgrind;
about a minute per scene and mode).
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import stage_breakdown  # noqa: E402  (valgrind_env)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ISOTRACE = os.path.join(ROOT, "build", "isotrace")


def run(args):
    r = subprocess.run(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("iso_vs_mesh: %s failed:\n%s" % (" ".join(args), r.stderr))
    return r.stdout


def absolute(scene_path, file):
    return file if os.path.isabs(file) else os.path.abspath(os.path.join(os.path.dirname(scene_path), file))


def twin_scenes(scene_path, work):
    """The scene with absolute paths (iso), and its twin with the volumes as meshes (mesh)."""
    with open(scene_path) as f:
        scene = json.load(f)
    for m in scene.get("meshes", []):
        if "file" in m:
            m["file"] = absolute(scene_path, m["file"])
    for v in scene.get("volumes", []):
        if "file" in v:
            v["file"] = absolute(scene_path, v["file"])
    name = os.path.splitext(os.path.basename(scene_path))[0]
    iso_path = os.path.join(work, name + ".iso.json")
    with open(iso_path, "w") as f:
        json.dump(scene, f)
    mesh = json.loads(json.dumps(scene))
    mesh["volumes"] = []
    triangles = 0
    for vi, v in enumerate(scene.get("volumes", [])):
        for si, s in enumerate(v["isosurfaces"]):
            glb = os.path.join(work, "%s.v%d.s%d.glb" % (name, vi, si))
            r = subprocess.run([ISOTRACE, "mesh", iso_path, "-o", glb, "--volume", str(vi), "--surface", str(si)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            if r.returncode != 0:
                sys.exit("iso_vs_mesh: isotrace mesh failed: " + r.stderr)
            triangles += int(r.stderr.split(": ")[-1].split(" triangles")[0])
            entry = {"file": glb}
            if "material" in s:
                entry["material"] = s["material"]
            mesh.setdefault("meshes", []).append(entry)
    mesh_path = os.path.join(work, name + ".mesh.json")
    with open(mesh_path, "w") as f:
        json.dump(mesh, f)
    return name, iso_path, mesh_path, triangles


def mode_scene(path, mode, work):
    """A copy of the scene for one mode (path: unchanged)."""
    if mode == "path":
        return path, []
    with open(path) as f:
        scene = json.load(f)
    if mode == "camera":
        scene["integrator"] = {"type": "normals", "spp": 4}
    else:
        scene["integrator"] = {"type": "ao", "spp": 4, "ao_distance": 1e30}
    out = path.replace(".json", "." + mode + ".json")
    with open(out, "w") as f:
        json.dump(scene, f)
    return out, ["--threads", "1"]


RENDERER = ISOTRACE


RAY_FLOW = []  # ["--ray-flow", F] when --ray-flow is given


def render(scene, extra, resolution, image, stats):
    run([RENDERER, "render", scene, "-o", image, "--resolution", resolution, "--quiet", "--seed", "7",
         "--stats", stats] + extra + RAY_FLOW)
    with open(stats) as f:
        s = json.load(f)
    return s["seconds"]["render"], s["rays"]


def count_instructions(scene, mode, resolution, image, work, flow=None):
    """Instructions executed inside the tiles' passes for one render (callgrind, counting only in
    TileRenderer::renderPass: the camera rays, the integrator's stages and every ray they trace, in
    either ray flow; loading, building and writing the image are left out). The run itself is
    stage_breakdown.callgrind's (with the Highway timer stand-in valgrind needs on some CPUs)."""
    out = stage_breakdown.callgrind(RENDERER, ["render", scene, "-o", image, "--resolution", resolution, "--quiet",
                                               "--seed", "7", "--spp", "4", "--threads", "1"] +
                                    (["--ray-flow", flow] if flow else RAY_FLOW), work)
    with open(out) as f:
        for line in f:
            if line.startswith("totals:") or line.startswith("summary:"):
                return int(line.split()[1])
    sys.exit("iso_vs_mesh: no instruction total in callgrind's output")


def image_difference(a, b):
    """mean |a - b| over the mean of b, from oiiotool's statistics."""
    def mean(args):
        out = run(["oiiotool"] + args + ["--printstats"])
        for line in out.splitlines():
            if "Stats Avg:" in line:
                values = [float(x) for x in line.split(":")[1].split()[:3]]
                return sum(values) / len(values)
        sys.exit("iso_vs_mesh: no statistics from oiiotool")
    return mean([a, b, "--absdiff"]) / max(mean([b]), 1e-30)


SECONDS_HEADER = "%-12s %-7s %9s %9s %10s %10s %7s %9s %10s" % (
    "scene", "mode", "iso s", "mesh s", "iso Mr/s", "mesh Mr/s", "ratio", "img diff", "triangles")
INSTRUCTIONS_HEADER = "%-12s %-7s %12s %12s %7s" % ("scene", "mode", "iso Minstr", "mesh Minstr", "ratio")


def measure_seconds(name, mode, scenes_of_mode, triangles, resolution, runs, work):
    """Median render seconds of `runs` interleaved renders of each twin: the table row and its record."""
    times = {"iso": [], "mesh": []}
    rays = {}
    for r in range(runs):
        for kind in ("iso", "mesh"):
            s, extra = scenes_of_mode[kind]
            image = os.path.join(work, "%s.%s.%s.exr" % (name, mode, kind))
            seconds, ray_counts = render(s, extra, resolution, image, os.path.join(work, "stats.json"))
            times[kind].append(seconds)
            rays[kind] = ray_counts
    med = {k: statistics.median(v) for k, v in times.items()}
    rate = {k: rays[k]["total"] / med[k] / 1e6 for k in med}
    diff = image_difference(os.path.join(work, "%s.%s.iso.exr" % (name, mode)),
                            os.path.join(work, "%s.%s.mesh.exr" % (name, mode))) if mode == "path" else None
    ratio = med["iso"] / med["mesh"]
    line = "%-12s %-7s %9.3f %9.3f %10.2f %10.2f %7.2f %9s %10d" % (
        name, mode, med["iso"], med["mesh"], rate["iso"], rate["mesh"], ratio,
        "%.4f" % diff if diff is not None else "-", triangles)
    return line, {"iso_seconds": times["iso"], "mesh_seconds": times["mesh"], "iso_median": med["iso"],
                  "mesh_median": med["mesh"], "ratio": ratio, "iso_rays": rays["iso"], "mesh_rays": rays["mesh"],
                  "image_difference": diff}


def measure_instructions(name, mode, scenes_of_mode, triangles, resolution, runs, work):
    """Instructions of one render of each twin under callgrind: the table row and its record."""
    counts = {kind: count_instructions(scenes_of_mode[kind][0], mode, resolution, os.path.join(work, "i.exr"), work)
              for kind in ("iso", "mesh")}
    ratio = counts["iso"] / counts["mesh"]
    line = "%-12s %-7s %12.1f %12.1f %7.2f" % (name, mode, counts["iso"] / 1e6, counts["mesh"] / 1e6, ratio)
    return line, {"iso_instructions": counts["iso"], "mesh_instructions": counts["mesh"], "ratio": ratio}


FLOWS_HEADER = "%-12s %-7s %9s %9s %8s %9s %9s %8s %9s %9s" % (
    "scene", "mode", "iso scal", "iso wave", "speedup", "mesh scal", "mesh wave", "speedup", "i/m scal", "i/m wave")


def measure_flows(name, mode, scenes_of_mode, triangles, resolution, runs, work, instructions=False):
    """Both ray flows of both twins, interleaved: medians (or instruction counts), speed-ups, ratios."""
    values = {(kind, flow): [] for kind in ("iso", "mesh") for flow in ("scalar", "wavefront")}
    for r in range(1 if instructions else runs):
        for kind in ("iso", "mesh"):
            s, extra = scenes_of_mode[kind]
            for flow in ("scalar", "wavefront"):
                image = os.path.join(work, "%s.%s.%s.%s.exr" % (name, mode, kind, flow))
                if instructions:
                    values[(kind, flow)].append(count_instructions(s, mode, resolution, image, work, flow) / 1e6)
                else:
                    seconds, _ = render(s, extra + ["--ray-flow", flow], resolution, image,
                                        os.path.join(work, "stats.json"))
                    values[(kind, flow)].append(seconds)
    med = {k: statistics.median(v) for k, v in values.items()}
    line = "%-12s %-7s %9.3f %9.3f %8.2f %9.3f %9.3f %8.2f %9.2f %9.2f" % (
        name, mode, med[("iso", "scalar")], med[("iso", "wavefront")],
        med[("iso", "scalar")] / med[("iso", "wavefront")], med[("mesh", "scalar")], med[("mesh", "wavefront")],
        med[("mesh", "scalar")] / med[("mesh", "wavefront")], med[("iso", "scalar")] / med[("mesh", "scalar")],
        med[("iso", "wavefront")] / med[("mesh", "wavefront")])
    return line, {"%s_%s" % k: v for k, v in values.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenes", nargs="*")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--resolution")
    parser.add_argument("--modes", default="path,camera,shadow")
    parser.add_argument("--json")
    parser.add_argument("--isotrace", help="the isotrace binary that renders (default: build/isotrace)")
    parser.add_argument("--ray-flow", choices=("wavefront", "scalar"))
    parser.add_argument("--flows", action="store_true", help="measure both ray flows, interleaved")
    parser.add_argument("--instructions", action="store_true",
                        help="count instructions under callgrind instead of timing renders")
    args = parser.parse_args()
    if args.instructions and not shutil.which("valgrind"):
        sys.exit("iso_vs_mesh: --instructions needs valgrind (apt-get install valgrind)")
    resolution = args.resolution or ("160x90" if args.instructions else "960x540")
    global RENDERER, RAY_FLOW
    if args.ray_flow:
        RAY_FLOW = ["--ray-flow", args.ray_flow]
    if args.isotrace:
        RENDERER = os.path.abspath(args.isotrace)
    if args.runs < 1:
        sys.exit("iso_vs_mesh: --runs must be at least 1")
    scenes = args.scenes or sorted(
        os.path.join(ROOT, "bench", "scenes", f) for f in os.listdir(os.path.join(ROOT, "bench", "scenes")))
    modes = args.modes.split(",")
    for m in modes:
        if m not in ("path", "camera", "shadow"):
            sys.exit("iso_vs_mesh: unknown mode '%s' (path, camera, shadow)" % m)
    measure = measure_instructions if args.instructions else measure_seconds
    if args.flows:
        measure = lambda *a: measure_flows(*a, instructions=args.instructions)
    results = []
    with tempfile.TemporaryDirectory() as work:
        print(FLOWS_HEADER if args.flows else INSTRUCTIONS_HEADER if args.instructions else SECONDS_HEADER)
        for scene in scenes:
            name, iso_path, mesh_path, triangles = twin_scenes(scene, work)
            for mode in modes:
                scenes_of_mode = {kind: mode_scene(path, mode, work)
                                  for kind, path in (("iso", iso_path), ("mesh", mesh_path))}
                line, result = measure(name, mode, scenes_of_mode, triangles, resolution, args.runs, work)
                print(line, flush=True)
                results.append(dict(scene=name, mode=mode, triangles=triangles, **result))
    if args.json:
        setup = {"spp": 4, "threads": 1} if args.instructions else {"runs": args.runs}
        with open(args.json, "w") as f:
            json.dump(dict(resolution=resolution, results=results, **setup), f, indent=1)

if __name__ == "__main__":
    main()
