#!/usr/bin/env python3
"""Benchmark report of the `bre` pipeline (volumetric photon mapping with the
beam radiance estimate, the baseline of Jakob et al. 2011) on one scene, for
several volume-photon counts:

  - preprocessing: photon tracing, pilot radii, BVH build (wall and CPU time);
  - rendering: the beam query (wall and CPU), and the surface part beside it;
  - BVH nodes and photons visited per camera ray, photons that contributed;
  - RMSE / relMSE / SSIM against the path-traced reference: over the whole
    image, over --crop (volumetric-caustic: without the rows that hold the
    light, whose few very bright pixels decide the whole-image RMSE), and
    over that crop in 4 x 4-pixel blocks (the reference's own noise, fireflies
    of rare caustic paths, averages down there);
  - the per-pass profile (the `fluxgraph batch` results table, with counters);
  - the per-pixel query cost (the query_cost AOV: BVH nodes + photons tested)
    as a false-colour image, the time-per-pixel image of Jakob et al. Fig. 1;
  - optionally a sweep of the BVH leaf size at one photon count.

Writes results/bre/README.md and the images next to it.

Usage:
  tools/bre_report.py [--build build] [--scene volumetric-caustic]
                      [--counts 250000,1000000,4000000] [--max-count N]
                      [--threads N] [--leaf-sweep 4,8,16,24,32] [--sweep-count 1000000]
                      [--reference PATH] [--crop X,Y,W,H] [--out results/bre]

The job is data/<scene>/bre.toml with passes.photon.volume_photons set per
run, all runs rendered by one `fluxgraph batch` (results/bre/runs: plan,
images, results table; a rerun renders only what changed); the reference is
data/<scene>/reference/reference.exr unless given.
Counts above --max-count are listed as not run. Passes of the pipeline run
concurrently (the surface part beside the volume part), so per-pass wall times
overlap; CPU times are each pass's own.
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path


def fail(message):
    """Bad input or a missing prerequisite: one line on stderr, exit status 2."""
    print(message, file=sys.stderr)
    sys.exit(2)


ROOT = Path(__file__).resolve().parent.parent


def run(cmd, **kwargs):
    return subprocess.run([str(c) for c in cmd], check=True, capture_output=True, text=True, **kwargs)


def batch(binary, job, out_dir, sweeps, threads):
    """Renders every run of `sweeps` ([{parameter: [values]}], each a cartesian
    product over the job) with one `fluxgraph batch`, resumable: a run whose
    image matches its job and settings is not rendered again. Returns, per run
    in plan order, (exr, png, passes by instance, the run's row)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    plan = out_dir / "plan.toml"
    lines = [f"output = {json.dumps(str(out_dir))}"]
    for sweep in sweeps:
        values = ", ".join(f"{json.dumps(key)} = [{', '.join(str(v) for v in vals)}]" for key, vals in sweep.items())
        lines += ["[[sweep]]", f"job = {json.dumps(str(job))}", f"set = {{ {values} }}"]
    plan.write_text("\n".join(lines) + "\n")
    table = out_dir / "results.jsonl"
    before = len(table.read_text().splitlines()) if table.exists() else 0
    cmd = [binary, "batch", plan]
    if threads:
        cmd += ["--threads", str(threads)]
    subprocess.run([str(c) for c in cmd], check=True)
    rows = [json.loads(line) for line in table.read_text().splitlines()[before:]]
    for row in rows:
        if row["status"] == "failed":
            fail(f"{row['run']}: {row['error']}")
    results = []
    for row in rows:
        exr = Path(row["exr"][0])
        if "passes" not in row:  # skipped: rendered by an earlier invocation; its stats are in that row
            earlier = [json.loads(line) for line in table.read_text().splitlines()[:before]]
            row = next(r for r in reversed(earlier) if r["run"] == row["run"] and "passes" in r)
        results.append((exr, exr.with_suffix(".png"), {p["instance"]: p for p in row["passes"]}, row))
    return results


def compare(binary, image, reference, heatmap=None, extra=()):
    cmd = [binary, "compare", image, reference, "--metric", "all", *extra]
    if heatmap:
        cmd += ["--heatmap", heatmap]
    metrics = {}
    for line in run(cmd).stdout.splitlines():
        parts = line.split()
        if len(parts) == 2:
            metrics[parts[0]] = float(parts[1])
    return metrics


DEFAULT_CROPS = {"volumetric-caustic": "0,16,128,112"}


def block_average(src, dst, factor):
    geometry = run(["oiiotool", "--info", "-v", src]).stdout
    size = re.search(r"(\d+)\s*x\s*(\d+)", geometry)
    width, height = int(size.group(1)), int(size.group(2))
    run(["oiiotool", src, "--ch", "R,G,B", "--resize:filter=box", f"{width // factor}x{height // factor}", "-o", dst])


def reference_metrics(binary, exr, reference, crop, out, name, block=4):
    """Metrics over the whole image, over the crop, and over the crop in block x block averages."""
    metrics = {"full": compare(binary, exr, reference, out / f"{name}-error.png")}
    upscale(out / f"{name}-error.png", out / f"{name}-error.png")
    if crop:
        metrics["crop"] = compare(binary, exr, reference, extra=["--crop", crop])
        x, y, w, h = (int(v) for v in crop.split(","))
        blocks = f"{x // block},{y // block},{w // block},{h // block}"
    else:
        metrics["crop"] = metrics["full"]
        blocks = None
    small_test, small_ref = out / f"{name}-blocks.exr", out / f"{name}-reference-blocks.exr"
    block_average(exr, small_test, block)
    block_average(reference, small_ref, block)
    metrics["blocks"] = compare(binary, small_test, small_ref, extra=["--crop", blocks] if blocks else [])
    small_test.unlink()
    small_ref.unlink()
    return metrics


def mean_luminance(exr, crop):
    """Rec.709 luminance of the mean RGB over the crop (x,y,w,h) or the whole image."""
    single = Path(str(exr) + ".mean.exr")
    cmd = ["oiiotool", exr, "--ch", "R,G,B"]
    if crop:
        x, y, w, h = (int(v) for v in crop.split(","))
        cmd += ["--cut", f"{w}x{h}+{x}+{y}"]
    run(cmd + ["-o", single])
    stats = run(["oiiotool", "--stats", single]).stdout
    single.unlink()
    r, g, b = (float(v) for v in re.search(r"Avg:\s*([-0-9.e+]+)\s+([-0-9.e+]+)\s+([-0-9.e+]+)", stats).groups())
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def cost_image(exr, png, channel="query_cost", scale=4, percentile=0.995):
    """False-colour PNG of one AOV channel (inferno from 0 to a high percentile, so that a few
    pixels whose thread was preempted do not darken the rest), upscaled.
    Returns (that percentile, mean, max)."""
    single = Path(png).with_suffix(".channel.exr")
    run(["oiiotool", exr, "--ch", channel, "-o", single])
    values = sorted(float(m.group(1)) for m in re.finditer(r"Pixel \(\d+, \d+\):\s*([-0-9.e+]+)",
                                                           run(["oiiotool", "--dumpdata", single]).stdout))
    single.unlink()
    top = values[min(len(values) - 1, int(percentile * len(values)))]
    factor = 1.0 / top if top > 0 else 1.0
    geometry = run(["oiiotool", "--info", "-v", exr]).stdout
    size = re.search(r"(\d+)\s*x\s*(\d+)", geometry)
    width, height = int(size.group(1)), int(size.group(2))
    run(["oiiotool", exr, "--ch", channel, "--mulc", f"{factor:.9g}", "--clamp:min=0:max=1", "--colormap", "inferno",
         "--resize:filter=box", f"{width * scale}x{height * scale}", "-o", png])
    return top, sum(values) / len(values), values[-1]


def upscale(src, dst, scale=4):
    geometry = run(["oiiotool", "--info", "-v", src]).stdout
    size = re.search(r"(\d+)\s*x\s*(\d+)", geometry)
    width, height = int(size.group(1)), int(size.group(2))
    run(["oiiotool", src, "--resize:filter=box", f"{width * scale}x{height * scale}", "-o", dst])


def pass_time(passes, name, key="wall_seconds"):
    return passes[name][key] if name in passes else float("nan")


def human(n):
    if n >= 1e6:
        return f"{n / 1e6:g}M"
    if n >= 1e3:
        return f"{n / 1e3:g}k"
    return str(n)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--scene", default="volumetric-caustic")
    ap.add_argument("--counts", default="250000,1000000,4000000")
    ap.add_argument("--max-count", type=int, default=None, help="counts above this are not run")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--leaf-sweep", default="", help="BVH leaf sizes to compare at --sweep-count, e.g. 4,8,16,24,32")
    ap.add_argument("--sweep-count", type=int, default=1000000)
    ap.add_argument("--reference", default=None)
    ap.add_argument("--crop", default=None, help="x,y,w,h compared besides the whole image "
                    "(default for volumetric-caustic: 0,16,128,112, without the light's rows)")
    ap.add_argument("--out", default="results/bre")
    args = ap.parse_args()

    binary = (ROOT / args.build / "fluxgraph").resolve()
    if not binary.exists():
        fail(f"{binary}: not built (cmake --build {args.build} -j2)")
    if not shutil.which("oiiotool"):
        fail("oiiotool not found (Debian: openimageio-tools)")
    job = ROOT / "data" / args.scene / "bre.toml"
    if not job.exists():
        fail(f"{job}: no bre job for scene {args.scene}")
    reference = Path(args.reference) if args.reference else ROOT / "data" / args.scene / "reference" / "reference.exr"
    out = Path(args.out)
    if not out.is_absolute():
        out = ROOT / out
    out.mkdir(parents=True, exist_ok=True)
    counts = [int(c) for c in args.counts.split(",") if c]
    crop = args.crop if args.crop is not None else DEFAULT_CROPS.get(args.scene)
    args.crop = crop

    skipped = [c for c in counts if args.max_count is not None and c > args.max_count]
    counts = [c for c in counts if c not in skipped]
    leaves = [int(x) for x in args.leaf_sweep.split(",") if x]
    if args.max_count is not None and args.sweep_count > args.max_count:
        leaves = []
    sweeps = [{"passes.photon.volume_photons": counts}] if counts else []
    if leaves:
        sweeps.append({"passes.photon.volume_photons": [args.sweep_count], "passes.photon_bvh.leaf_size": leaves})
    runs = batch(binary, job, out / "runs", sweeps, args.threads) if sweeps else []

    rows = []
    for count, (exr, png, passes, data) in zip(counts, runs):
        name = f"{args.scene}-{human(count)}"
        row = {"count": count, "name": name, "passes": passes, "data": data}
        bq = passes["beam_query"]["counters"]
        rays = max(1, bq["camera_samples"])
        row["nodes_per_ray"] = bq["nodes_visited"] / rays
        row["tested_per_ray"] = bq["photons_tested"] / rays
        row["used_per_ray"] = bq["photons_used"] / rays
        row["segments"] = bq["segments"]
        if reference.exists():
            row["metrics"] = reference_metrics(binary, exr, reference, crop, out, name)
            row["mean_ratio"] = mean_luminance(exr, crop) / mean_luminance(reference, crop)
        row["cost_top"], row["cost_mean"], row["cost_max"] = cost_image(exr, out / f"{name}-cost.png")
        # Wall time per pixel is disturbed by other work on the machine: scaled to its 95th percentile.
        row["time_top"], row["time_mean"], row["time_max"] = cost_image(exr, out / f"{name}-time.png",
                                                                         "query_time_ns", percentile=0.95)
        upscale(png, out / f"{name}-x4.png")
        rows.append(row)
    sweep = [(leaf, passes) for leaf, (_, _, passes, _) in zip(leaves, runs[len(counts):])]

    write_markdown(out, args, job, reference, rows, skipped, sweep)
    print(f"wrote {out / 'README.md'}", file=sys.stderr)


def write_markdown(out, args, job, reference, rows, skipped, sweep):
    host = os.uname()
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    lines = [f"# `bre` on {args.scene}", ""]
    lines += [
        f"Job `{job.relative_to(ROOT)}` (128 x 128, its spp and photon settings), volume photons per run as below; "
        f"{os.cpu_count()} hardware threads ({cpu}), `--threads {args.threads or 'all'}`, {host.sysname} {host.release}. "
        f"Generated by `tools/bre_report.py` on {time.strftime('%Y-%m-%d %H:%M')}.",
        "",
        "Passes run as a task graph: the surface part (volume_eye, photon indices, gather) runs beside the volume "
        "part (photon -> photon_radius -> photon_bvh -> beam_query), so wall times of concurrent passes share the "
        "cores; CPU times are each pass's own. Preprocessing = photon tracing + radii + BVH (a chain, wall times "
        "added). Per ray = per camera sample (pixels x spp).",
        "",
    ]
    if not reference.exists():
        lines += [f"**No reference** at `{reference}`: RMSE columns are empty.", ""]
    lines += [f"Reference: `{reference.relative_to(ROOT) if reference.is_relative_to(ROOT) else reference}`. "
              f"Error columns: whole image / crop `{args.crop or 'none'}` / that crop in 4 x 4-pixel block averages; "
              "the last column compares mean luminance over the crop. Where the reference is a path-traced image "
              "of a caustic scene, its own noise (fireflies of rare caustic paths) sets a floor under these errors: "
              "once the estimate's error is below it they stop falling (see tests/passes/volume/test_bre.cpp, which shows "
              "the fall at 2k-32k photons).", ""]
    header = ("| volume photons | paths | photon tracing s (cpu) | radii s (cpu) | BVH s (cpu) | preprocess s | "
              "beam query s (cpu) | total s | nodes / ray | photons tested / ray | used / ray | mean r | "
              "RMSE | relMSE | SSIM (crop) | mean / reference (crop) |")
    lines += [header, "|" + "---:|" * (header.count("|") - 1)]
    for r in rows:
        p = r["passes"]
        pre = sum(pass_time(p, n) for n in ("photon", "photon_radius", "photon_bvh"))
        m = r.get("metrics", {})
        nan = float("nan")
        triple = lambda key: " / ".join(f"{m.get(part, {}).get(key, nan):.4f}" for part in ("full", "crop", "blocks"))
        mean_r = p["photon_radius"]["counters"].get("mean_radius_1e-6", 0) * 1e-6
        lines.append(
            f"| {human(r['count'])} | {p['photon']['counters'].get('emitted_paths', 0):,} "
            f"| {pass_time(p, 'photon'):.2f} ({pass_time(p, 'photon', 'cpu_seconds'):.2f}) "
            f"| {pass_time(p, 'photon_radius'):.2f} ({pass_time(p, 'photon_radius', 'cpu_seconds'):.2f}) "
            f"| {pass_time(p, 'photon_bvh'):.2f} ({pass_time(p, 'photon_bvh', 'cpu_seconds'):.2f}) "
            f"| {pre:.2f} "
            f"| {pass_time(p, 'beam_query'):.2f} ({pass_time(p, 'beam_query', 'cpu_seconds'):.2f}) "
            f"| {r['data']['passes_seconds']:.2f} "
            f"| {r['nodes_per_ray']:.0f} | {r['tested_per_ray']:.0f} | {r['used_per_ray']:.0f} | {mean_r:.4f} "
            f"| {triple('rmse')} | {triple('relmse')} | {m.get('crop', {}).get('ssim', nan):.3f} "
            f"| {r.get('mean_ratio', nan):.4f} |")
    for c in skipped:
        lines.append(f"| {human(c)} | not run (above --max-count {args.max_count}) |" + " |" * 14)
    lines.append("")

    for r in rows:
        lines += [f"## {human(r['count'])} volume photons", ""]
        images = [f"![image]({r['name']}-x4.png)", f"![query cost]({r['name']}-cost.png)",
                  f"![query time]({r['name']}-time.png)"]
        captions = ["image",
                    f"query_cost per pixel, nodes + photons tested (inferno, 0 .. {r['cost_top']:.0f}, the 99.5th "
                    f"percentile; mean {r['cost_mean']:.0f}, max {r['cost_max']:.0f})",
                    f"query_time_ns per pixel (0 .. {r['time_top'] / 1e3:.0f} us, the 95th percentile; "
                    f"mean {r['time_mean'] / 1e3:.1f} us, max {r['time_max'] / 1e3:.0f} us)"]
        if "metrics" in r:
            images.append(f"![relative error]({r['name']}-error.png)")
            captions.append("relative error vs reference (log scale, 1e-3 .. 1)")
        lines += ["| " + " | ".join(captions) + " |", "|" + "---|" * len(captions), "| " + " | ".join(images) + " |", ""]
        lines += ["| pass | wall s | cpu s | items | output | counters |", "|---|---:|---:|---:|---:|---|"]
        for name, p in r["passes"].items():
            counters = ", ".join(f"{k} {v:,}" for k, v in p["counters"].items())
            lines.append(f"| {name} | {p['wall_seconds']:.3f} | {p['cpu_seconds']:.3f} | {p['items']:,} "
                         f"| {p['output_bytes'] / 2**20:.1f} MiB | {counters} |")
        lines.append("")

    if sweep:
        lines += [f"## BVH leaf size at {human(args.sweep_count)} volume photons", "",
                  "| leaf size | nodes | BVH build s (cpu) | beam query s (cpu) | nodes / ray | photons tested / ray |",
                  "|---:|---:|---:|---:|---:|---:|"]
        for leaf, p in sweep:
            bq = p["beam_query"]["counters"]
            rays = max(1, bq["camera_samples"])
            lines.append(f"| {leaf} | {p['photon_bvh']['counters']['nodes']:,} "
                         f"| {pass_time(p, 'photon_bvh'):.3f} ({pass_time(p, 'photon_bvh', 'cpu_seconds'):.3f}) "
                         f"| {pass_time(p, 'beam_query'):.3f} ({pass_time(p, 'beam_query', 'cpu_seconds'):.3f}) "
                         f"| {bq['nodes_visited'] / rays:.0f} | {bq['photons_tested'] / rays:.0f} |")
        lines.append("")
    (out / "README.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
