#!/usr/bin/env python3
"""Final gathering in the Cornell box's corners: photon maps against photon ray splatting.

Herzog et al. 2007, §8.4 and Fig. 7(a): with final gathering, photon mapping
overestimates the light near concave features, where many gather rays land
within the photon search radius of where they left; photon ray splatting,
which estimates density in ray space, should come closer. This renders
data/cornell-box/pm-fg.toml and prs-fg.toml (or the jobs given) with several
photon seeds and reports, per crop (default: the two ceiling, back-wall and
side-wall corners, 20,20,16,16 and 92,20,16,16 of the 128 x 128 image, and
the whole image), the mean signed error against
data/cornell-box/reference/reference.exr in percent of the reference's mean
there, averaged over the seeds, with its standard error; prs-fg once per
--origin-boundary given (fg_splat's origin_boundary: cut, the paper's
estimator, and renormalise; without it once, as the job and --set-prs say)
and, seed by seed, each prs-fg row less pm-fg with its standard error.
Each seed sets both the photon paths and the eye samples, and with them the
gather rays (--fixed-eye keeps the job's seed for the eye pass and the
gather rays of every run): with one such seed the gather rays' own error in
a crop is one offset per job, which no number of photon seeds shows.
pm-fg and prs-fg share each seed's photon paths and eye vertices; their
gather rays are drawn apart (the stream is the pass's, final_gather or
fg_splat), so the paired difference removes the photon set's error but
not the gather rays'. Renders of different seeds and jobs may run side by
side (--jobs); each is on one thread, so the images do not depend on it.
Also the splat / gather time T_S (fg_splat's splat_us against
final_gather's gather_cpu_us, process CPU time; the paper's 0.66x) and the
gather rays' trace time. Renders run on one thread (--threads 1); on a
shared machine CPU times are still noisy.

With --indirect the jobs run without direct light (eye direct_light = false)
and are compared with the reference less a one-bounce pt image (rendered
once, --direct-spp samples): per-pixel RMSE and the RMS error of 8 x 8 block
means (the low-frequency error the density estimate leaves; the per-pixel
error is mostly the gather rays' noise), both as means over the seeds, and
the mean bandwidths (fg_splat's mean_hit_radius_ppm, final_gather's
mean_gather_radius_ppm).

Usage: tools/prs_fg_report.py [--build DIR] [--seeds 1 2 3 4] [--fixed-eye] [--jobs N] [--photons N] [--fg-rays N]
                              [--origin-boundary cut renormalise] [--indirect [--direct-spp N]]
                              [--set-prs KEY=VALUE ...] [--set-pm KEY=VALUE ...]
"""
import argparse
import concurrent.futures
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from caustics_report import read_exr_rgb  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CROPS = ((20, 20, 16, 16), (92, 20, 16, 16))
WHOLE = (0, 0, 128, 128)


def seed_settings(seed, fixed_eye):
    """--set arguments of one seed: the photon paths, and the eye samples unless they stay the job's."""
    return ["--set", f"passes.photon.seed={seed}"] + ([] if fixed_eye else ["--set", f"seed={seed}"])


def paired_errors(errors, baseline):
    """Mean and standard error, per crop, of errors - baseline seed by seed (lists of per-seed values per crop)."""
    return [mean_and_error([a - b for a, b in zip(e, base)]) for e, base in zip(errors, baseline)]


def crop_mean(pixels, width, crop):
    x0, y0, w, h = crop
    total = 0.0
    for y in range(y0, y0 + h):
        for x in range(x0, x0 + w):
            total += sum(pixels[y * width + x]) / 3.0
    return total / (w * h)


def counters(stats, instance):
    for p in stats["passes"]:
        if p["instance"] == instance:
            return p["counters"]
    raise SystemExit(f"no pass '{instance}' in the render's statistics")


def render(binary, job, out, seed, fixed_eye, photons, fg_rays, extra=()):
    stats = out / "stats.json"
    command = [str(binary), "render", str(job), "-q", "--threads", "1", "--out", str(out), "--stats", str(stats)]
    command += seed_settings(seed, fixed_eye)
    for setting in extra:
        command += ["--set", setting]
    if photons:
        command += ["--set", f"passes.photon.photons={photons}"]
    if fg_rays:
        gather = "fg_splat" if job.stem == "prs-fg" else "final_gather"
        command += ["--set", f"passes.{gather}.fg_rays={fg_rays}"]
    subprocess.run(command, check=True)
    images = sorted(out.glob("*.exr"))
    if len(images) != 1:
        raise SystemExit(f"{out}: expected one EXR image, found {len(images)}")
    return read_exr_rgb(images[0]), json.loads(stats.read_text())


def mean_and_error(values):
    mean = sum(values) / len(values)
    if len(values) < 2:
        return mean, float("nan")
    var = sum((v - mean) ** 2 for v in values) / (len(values) - 1)
    return mean, math.sqrt(var / len(values))


def indirect_reference(binary, work, reference, spp):
    """The reference less a one-bounce path-traced image (emission and direct light)."""
    out = work / "pt-direct"
    subprocess.run([str(binary), "render", str(ROOT / "data" / "cornell-box" / "pt.toml"), "-q", "--out", str(out),
                    "--set", "passes.pt.max_depth=1", "--set", f"passes.pt.spp={spp}"], check=True)
    direct = read_exr_rgb(next(out.glob("*.exr")))
    return [tuple(a - b for a, b in zip(r, d)) for r, d in zip(reference, direct)]


def image_errors(pixels, target, width, block=8):
    """Per-pixel RMSE and the RMS error of block x block means (channel means)."""
    se = sum(sum((a - b) ** 2 for a, b in zip(p, q)) / 3.0 for p, q in zip(pixels, target)) / len(target)
    blocks = []
    for by in range(0, width, block):
        for bx in range(0, width, block):
            d = 0.0
            for y in range(by, by + block):
                for x in range(bx, bx + block):
                    d += (sum(pixels[y * width + x]) - sum(target[y * width + x])) / 3.0
            blocks.append((d / (block * block)) ** 2)
    return math.sqrt(se), math.sqrt(sum(blocks) / len(blocks))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default=str(ROOT / "build"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[11, 12, 13, 14])
    parser.add_argument("--fixed-eye", action="store_true",
                        help="keep the job's eye samples for every seed (only the photon paths change)")
    parser.add_argument("--jobs", type=int, default=1, help="renders side by side (each on one thread)")
    parser.add_argument("--photons", type=int, default=0, help="override the jobs' photon count")
    parser.add_argument("--fg-rays", type=int, default=0, help="override the jobs' final-gather rays")
    parser.add_argument("--origin-boundary", nargs="+", default=[], choices=["cut", "renormalise"],
                        help="fg_splat's origin_boundary, one prs-fg row each (default: one row, as the job and --set-prs)")
    parser.add_argument("--indirect", action="store_true", help="indirect light only, with RMSE and block error")
    parser.add_argument("--direct-spp", type=int, default=1024, help="samples of the one-bounce pt image")
    parser.add_argument("--set-prs", nargs="*", default=[], help="extra --set for prs-fg (e.g. passes.ray_bandwidth.smoothness=1)")
    parser.add_argument("--set-pm", nargs="*", default=[], help="extra --set for pm-fg")
    args = parser.parse_args()
    binary = Path(args.build) / "fluxgraph"
    scene_dir = ROOT / "data" / "cornell-box"
    reference = read_exr_rgb(scene_dir / "reference" / "reference.exr")
    width = 128
    if len(reference) != width * width:
        raise SystemExit("the reference is not 128 x 128")
    crops = list(CROPS) + [WHOLE]

    methods = [("pm-fg", "pm-fg", "final_gather", "gather_cpu_us", "mean_gather_radius_ppm", args.set_pm)]
    for boundary in args.origin_boundary or [None]:
        settings = [f"passes.fg_splat.origin_boundary={boundary}"] if boundary else []
        methods.append((f"prs-fg ({boundary})" if boundary else "prs-fg", "prs-fg", "fg_splat", "splat_cpu_us",
                        "mean_hit_radius_ppm", list(args.set_prs) + settings))
    rows, quality, per_seed = {}, {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        target = reference
        if args.indirect:
            target = indirect_reference(binary, work, reference, args.direct_spp)
        ref_means = [crop_mean(target, width, c) for c in crops]

        def run(index, seed):
            label, job, _, _, _, extra = methods[index]
            extra = list(extra) + (["passes.eye.direct_light=false"] if args.indirect else [])
            out = work / f"{index}-{seed}"
            pixels, stats = render(binary, scene_dir / f"{job}.toml", out, seed, args.fixed_eye, args.photons,
                                   args.fg_rays, extra)
            errors = [100.0 * (crop_mean(pixels, width, c) - m) / m for c, m in zip(crops, ref_means)]
            print(f"{label}, seed {seed}: " + ", ".join(f"{e:+.2f} %" for e in errors), file=sys.stderr, flush=True)
            return errors, stats, image_errors(pixels, target, width)

        # Seed by seed, every method, so that an interrupted report has the same seeds of each.
        tasks = [(i, seed) for seed in args.seeds for i in range(len(methods))]
        with concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
            results = dict(zip(tasks, pool.map(lambda t: run(*t), tasks)))

    for index, (label, _, instance, time_key, radius_key, _) in enumerate(methods):
        errors = [[results[(index, seed)][0][i] for seed in args.seeds] for i in range(len(crops))]
        splat, trace, rmse, block, radius = [], [], [], [], []
        for seed in args.seeds:
            _, stats, e = results[(index, seed)]
            c = counters(stats, instance)
            splat.append(c[time_key] / 1e6)
            trace.append(c["trace_cpu_us"] / 1e6)
            radius.append(c.get(radius_key, 0))
            rmse.append(e[0])
            block.append(e[1])
        rows[label] = ([mean_and_error(e) for e in errors], splat, trace)
        quality[label] = (rmse, block, radius)
        per_seed[label] = errors
    for label in list(per_seed)[1:]:
        rows[f"{label} - pm-fg, seed by seed"] = (paired_errors(per_seed[label], per_seed["pm-fg"]), None, None)

    what = "of the indirect light against the reference less one-bounce pt" if args.indirect else ""
    eye = "the job's eye samples" if args.fixed_eye else "each seed's own eye samples"
    print(f"Mean signed error {what} in % of the reference's mean there, ± its standard error, over"
          f" {len(args.seeds)} seeds {args.seeds} ({eye}):\n")
    print("| pipeline | " + " | ".join(f"crop {','.join(map(str, c))}" for c in crops) +
          " | T_S (CPU s) | gather-ray trace (CPU s) |")
    print("|---|" + "---:|" * (len(crops) + 2))
    for label, (cells, splat, trace) in rows.items():
        times = f" | {sum(splat) / len(splat):.2f} | {sum(trace) / len(trace):.2f} |" if splat else " | | |"
        print(f"| {label} | " + " | ".join(f"{m:+.2f} % ± {e:.2f}" for m, e in cells) + times)
    what = "indirect light, against the reference less one-bounce pt" if args.indirect else "the full image"
    print(f"\n| pipeline ({what}) | RMSE | 8 x 8 block RMSE | mean radius (ppm of the diagonal) |")
    print("|---|---:|---:|---:|")
    for label, (rmse, block, radius) in quality.items():
        print(f"| {label} | {sum(rmse) / len(rmse):.5f} | {sum(block) / len(block):.5f} | {sum(radius) / len(radius):.0f} |")
    print()
    for label in list(quality)[1:]:
        ts_ratio = sum(rows[label][1]) / sum(rows["pm-fg"][1])
        print(f"T_S {label} / pm-fg = {ts_ratio:.2f} (the paper: 0.66)")


if __name__ == "__main__":
    main()
