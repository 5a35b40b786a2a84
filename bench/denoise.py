"""The denoiser judged by error at equal time (issue 45).

For every example scene that path traces (examples/*.json but quick_look), at half the scene's
film size: a reference of 2048 samples per pixel (rendered once with build/isotrace and cached
outside the repository, in $ISOTRACE_CACHE or ~/.cache/isotrace/denoise, keyed on the scene
without its spp and denoise keys, the size, the spp and the seed), then one render per sample
count (4, 16, 64, and raw 32 and 128 for the targets) through the Python module, each raw and
denoised in both modes from the same samples (Frame.denoised). Prints per scene and sample
count: relMSE (mean over pixels and channels of (x - ref)^2 / (ref^2 + 0.01)), SSIM (of the
luminance after the clamp curve and sRGB, 11x11 Gaussian windows) and the change of the image
mean that denoising makes, with render and denoise seconds; then the issue's targets, met or
not. --json writes every figure; --images DIR writes the PNGs (raw, quality, fast, reference);
--timing WxH times the denoiser alone on one frame of that size (median of 5).

    bench/denoise.py [--scenes a,b] [--spp 4,16,64] [--json FILE] [--images DIR]
                     [--references-only] [--threads N] [--timing 1920x1080]
    bench/denoise.py --report FILE.json [--plot OUT.png]   # the markdown table of a run (and
                     # time-against-error plots, one panel per scene, through gnuplot)

Needs Debian's python3 with numpy and the module build/python (./run.sh builds it).
"""
import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "build", "python"))

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ISOTRACE = os.environ.get("ISOTRACE_BINARY") or os.path.join(ROOT, "build", "isotrace")
REFERENCE_SPP = 2048
REFERENCE_SEED = 7919  # not a seed the measured renders use: the reference's noise is its own


def cache_dir():
    d = os.environ.get("ISOTRACE_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "isotrace", "denoise")
    os.makedirs(d, exist_ok=True)
    return d


def example_scenes():
    names = []
    for f in sorted(os.listdir(os.path.join(ROOT, "examples"))):
        if not f.endswith(".json"):
            continue
        with open(os.path.join(ROOT, "examples", f)) as fh:
            doc = json.load(fh)
        if doc.get("integrator", {}).get("type") in ("path", "direct", "compare"):
            names.append(f[:-5])
    return names


def scene_size(name):
    with open(os.path.join(ROOT, "examples", name + ".json")) as fh:
        film = json.load(fh).get("film", {})
    return max(1, film.get("width", 640) // 2), max(1, film.get("height", 480) // 2)


def scene_key(path):
    """What the reference depends on: the scene without the keys a reference overrides or that
    do not change the beauty (spp, film.denoise), so that retuning an example's samples keeps it."""
    with open(path) as fh:
        doc = json.load(fh)
    doc.get("integrator", {}).pop("spp", None)
    doc.get("film", {}).pop("denoise", None)
    return hashlib.sha1(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]


def reference(name, threads):
    path = os.path.join(ROOT, "examples", name + ".json")
    key = scene_key(path)
    w, h = scene_size(name)
    out = os.path.join(cache_dir(), "%s-%s-%dx%d-%dspp-s%d.exr" % (name, key, w, h, REFERENCE_SPP, REFERENCE_SEED))
    if not os.path.exists(out):
        print("denoise.py: rendering the reference of %s (%dx%d, %d spp) to %s" % (name, w, h, REFERENCE_SPP, out),
              file=sys.stderr, flush=True)
        subprocess.run([ISOTRACE, "render", path, "--resolution", "%dx%d" % (w, h), "--spp", str(REFERENCE_SPP),
                        "--seed", str(REFERENCE_SEED), "--threads", str(threads), "--quiet", "-o", out + ".tmp.exr"],
                       check=True, stdout=subprocess.DEVNULL)
        os.replace(out + ".tmp.exr", out)
    return out


def rel_mse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 1e-2)))


def display_luminance(x):
    """What a PNG shows, as luminance in [0, 1]: the clamp curve, then sRGB."""
    v = np.clip(x, 0, 1)
    v = np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)
    return 0.2126 * v[..., 0] + 0.7152 * v[..., 1] + 0.0722 * v[..., 2]


def gaussian_blur(img, sigma=1.5, radius=5):
    k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    k /= k.sum()
    pad = np.pad(img, radius, mode="reflect")
    h, w = img.shape
    tmp = sum(k[i] * pad[:, i:i + w] for i in range(2 * radius + 1))
    return sum(k[i] * tmp[i:i + h, :] for i in range(2 * radius + 1))


def ssim(x, ref):
    """Structural similarity (Wang et al. 2004) of the displayed luminance, Gaussian windows."""
    a, b = display_luminance(x), display_luminance(ref)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ma, mb = gaussian_blur(a), gaussian_blur(b)
    va = gaussian_blur(a * a) - ma * ma
    vb = gaussian_blur(b * b) - mb * mb
    cov = gaussian_blur(a * b) - ma * mb
    s = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
    return float(np.mean(s))


def mean_shift(x, raw):
    """The relative change of the image mean (luminance) that denoising made."""
    lx, lr = float(np.mean(x @ LUM)), float(np.mean(raw @ LUM))
    return (lx - lr) / lr if lr > 0 else 0.0


def render(name, spp, seed, threads):
    w, h = scene_size(name)
    return isotrace.render(os.path.join(ROOT, "examples", name + ".json"), spp=spp, seed=seed, threads=threads,
                           resolution=(w, h), denoise="off", progress=lambda done, total: None)


def save_png(rgb, path):
    isotrace._core.save_image(np.ascontiguousarray(rgb, dtype=np.float32), {}, path, 0.0, "clamp", False)


def measure_scene(name, spp_list, raw_only, threads, images):
    ref = isotrace.read_image(reference(name, threads))[..., :3]
    rows = []
    for spp in sorted(set(spp_list) | set(raw_only)):
        frame = render(name, spp, 1, threads)
        row = {"scene": name, "spp": spp, "render_seconds": frame.stats["seconds"]["render"],
               "raw": {"relmse": rel_mse(frame.rgb, ref), "ssim": ssim(frame.rgb, ref)}}
        if images:
            save_png(frame.rgb, os.path.join(images, "%s.raw%d.png" % (name, spp)))
        if spp in spp_list:
            for mode in ("quality", "fast"):
                d = frame.denoised(mode, threads=threads)
                row[mode] = {"relmse": rel_mse(d.rgb, ref), "ssim": ssim(d.rgb, ref),
                             "mean_shift": mean_shift(d.rgb, frame.rgb), "seconds": d.stats["seconds"]["denoise"]}
                if images:
                    save_png(d.rgb, os.path.join(images, "%s.%s%d.png" % (name, mode, spp)))
        rows.append(row)
        r = row
        line = "%-14s %5d spp  render %6.2fs  raw relMSE %.5f SSIM %.4f" % (name, spp, r["render_seconds"],
                                                                      r["raw"]["relmse"], r["raw"]["ssim"])
        for mode in ("quality", "fast"):
            if mode in r:
                m = r[mode]
                line += "  | %s %.5f SSIM %.4f mean %+.2f%% %.3fs" % (mode, m["relmse"], m["ssim"],
                                                                    100 * m["mean_shift"], m["seconds"])
        print(line, flush=True)
    if images:
        save_png(ref, os.path.join(images, "%s.reference.png" % name))
    return rows


def targets(rows):
    """The issue's targets on the measured rows: denoised (quality) 16 spp against raw 128 and 32."""
    by = {(r["scene"], r["spp"]): r for r in rows}
    scenes = sorted({r["scene"] for r in rows})
    beat128 = never_worse32 = 0
    worst_shift = 0.0
    out = []
    for s in scenes:
        d16, r32, r128 = by.get((s, 16)), by.get((s, 32)), by.get((s, 128))
        if not (d16 and r32 and r128 and "quality" in d16):
            continue
        q = d16["quality"]["relmse"]
        b128, b32 = q < r128["raw"]["relmse"], q <= r32["raw"]["relmse"]
        beat128 += b128
        never_worse32 += b32
        out.append((s, q, r128["raw"]["relmse"], r32["raw"]["relmse"], b128, b32))
    for r in rows:
        for mode in ("quality", "fast"):
            if mode in r:
                worst_shift = max(worst_shift, abs(r[mode]["mean_shift"]))
    return out, beat128, never_worse32, worst_shift


def timing(size, threads):
    w, h = (int(v) for v in size.split("x"))
    frame = isotrace.render(os.path.join(ROOT, "examples", "default.json"), spp=4, resolution=(w, h), threads=threads,
                            denoise="off", progress=lambda done, total: None)
    result = {}
    for mode in ("quality", "fast"):
        times = [frame.denoised(mode, threads=threads).stats["seconds"]["denoise"] for _ in range(5)]
        result[mode] = statistics.median(times)
        print("denoise %s %dx%d, %d threads: median %.3f s of 5 (%s)" % (
            mode, w, h, threads, result[mode], ", ".join("%.3f" % t for t in times)), flush=True)
    return result


def print_report(path, plot):
    with open(path) as f:
        r = json.load(f)
    rows = r["rows"]
    scenes = sorted({x["scene"] for x in rows})
    by = {(x["scene"], x["spp"]): x for x in rows}
    spps = sorted({x["spp"] for x in rows if "quality" in x})
    print("| scene | " + " | ".join("raw %d" % s for s in sorted({x["spp"] for x in rows})) + " | " +
          " | ".join("quality %d" % s for s in spps) + " | " + " | ".join("fast %d" % s for s in spps) + " |")
    print("|---" * (1 + len({x["spp"] for x in rows}) + 2 * len(spps)) + "|")
    for s in scenes:
        cells = ["%.4f" % by[(s, n)]["raw"]["relmse"] for n in sorted({x["spp"] for x in rows}) if (s, n) in by]
        for mode in ("quality", "fast"):
            cells += ["%.4f" % by[(s, n)][mode]["relmse"] if (s, n) in by and mode in by[(s, n)] else "" for n in spps]
        print("| %s | %s |" % (s, " | ".join(cells)))
    print()
    print("| scene | SSIM raw 16 | quality 16 | fast 16 | raw 128 | mean shift quality (largest) | fast | render s 16 | denoise s quality, fast |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in scenes:
        a, b = by.get((s, 16)), by.get((s, 128))
        if not (a and b and "quality" in a):
            continue
        shift = {m: max(abs(by[(s, n)][m]["mean_shift"]) for n in spps if (s, n) in by) for m in ("quality", "fast")}
        print("| %s | %.3f | %.3f | %.3f | %.3f | %.2f%% | %.2f%% | %.2f | %.3f, %.3f |" % (
            s, a["raw"]["ssim"], a["quality"]["ssim"], a["fast"]["ssim"], b["raw"]["ssim"], 100 * shift["quality"],
            100 * shift["fast"], a["render_seconds"], a["quality"]["seconds"], a["fast"]["seconds"]))
    if not plot:
        return
    import tempfile
    tmp = tempfile.mkdtemp()
    for s in scenes:
        with open(os.path.join(tmp, s + ".raw"), "w") as raw, open(os.path.join(tmp, s + ".den"), "w") as den:
            for n in sorted({x["spp"] for x in rows}):
                x = by.get((s, n))
                if not x:
                    continue
                t = x["render_seconds"]
                raw.write("%g %g\n" % (t, x["raw"]["relmse"]))
                if "quality" in x:
                    den.write("%g %g %g %g\n" % (t + x["quality"]["seconds"], x["quality"]["relmse"],
                                                 t + x["fast"]["seconds"], x["fast"]["relmse"]))
    cols = 4
    rows_n = (len(scenes) + cols - 1) // cols
    script = ["set terminal pngcairo size %d,%d font 'DejaVu Sans,9'" % (300 * cols, 240 * rows_n),
              "set output '%s'" % plot, "set multiplot layout %d,%d" % (rows_n, cols),
              "set logscale xy", "set key top right", "set termoption noenhanced", "set xlabel 'seconds (render + denoise)'", "set ylabel 'relMSE'"]
    for s in scenes:
        d = os.path.join(tmp, s)
        script.append("set title '%s (points: 4, 16, 32, 64 ... spp)'" % s)
        script.append("plot '%s.raw' u 1:2 w lp t 'raw', '%s.den' u 1:2 w lp t 'quality', '' u 3:4 w lp t 'fast'" % (d, d))
    script.append("unset multiplot")
    subprocess.run(["gnuplot"], input="\n".join(script), text=True, check=True)
    print("\nplot: " + plot)


LUM = None
np = None
isotrace = None


def main():
    global np, isotrace, LUM
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", default="")
    p.add_argument("--spp", default="4,16,64")
    p.add_argument("--raw-spp", default="32,128", help="sample counts rendered raw only (the targets')")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", default="")
    p.add_argument("--images", default="")
    p.add_argument("--timing", default="", help="WxH: time the denoiser alone at this size")
    p.add_argument("--references-only", action="store_true")
    p.add_argument("--report", default="", help="a --json file: print its tables")
    p.add_argument("--plot", default="", help="with --report: time-against-error plots to this PNG")
    a = p.parse_args()
    if a.report:
        print_report(a.report, a.plot)
        return
    scenes = a.scenes.split(",") if a.scenes else example_scenes()
    if scenes == ["none"]:
        scenes = []
    for s in scenes:
        reference(s, a.threads)
    if a.references_only:
        return
    import numpy
    import isotrace as module
    np, isotrace = numpy, module
    LUM = np.array([0.2126, 0.7152, 0.0722], dtype=np.float64)
    report = {"machine": os.uname().nodename, "threads": a.threads, "reference_spp": REFERENCE_SPP}
    if a.timing:
        report["timing"] = {"size": a.timing, "seconds": timing(a.timing, a.threads)}
    if a.images:
        os.makedirs(a.images, exist_ok=True)
    rows = []
    spp = [int(v) for v in a.spp.split(",") if v]
    raw = [int(v) for v in a.raw_spp.split(",") if v]
    for s in scenes:
        rows += measure_scene(s, spp, raw, a.threads, a.images)
    report["rows"] = rows
    t, beat128, worse32, shift = targets(rows)
    if t:
        print("\ntargets (quality 16 spp against raw 128 and raw 32 spp, relMSE):")
        for s, q, r128, r32, b128, b32 in t:
            print("  %-14s %.5f vs %.5f (128: %s)  vs %.5f (32: %s)" % (s, q, r128, "lower" if b128 else "HIGHER",
                                                                     r32, "ok" if b32 else "WORSE"))
        print("  beats raw 128 spp on %d of %d scenes; never worse than raw 32: %s; largest mean shift %.2f%%"
              % (beat128, len(t), "yes" if worse32 == len(t) else "no (%d of %d)" % (worse32, len(t)), 100 * shift))
        report["targets"] = {"beats_raw128": beat128, "scenes": len(t), "not_worse_than_raw32": worse32,
                             "largest_mean_shift": shift}
    if a.json:
        with open(a.json, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
