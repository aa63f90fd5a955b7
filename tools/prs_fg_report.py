#!/usr/bin/env python3
"""Final gathering in the Cornell box's corners: photon maps against photon ray splatting.

Herzog et al. 2007, §8.4 and Fig. 7(a): with final gathering, photon mapping
overestimates the light near concave features, where many gather rays land
within the photon search radius of where they left; photon ray splatting,
which estimates density in ray space, should come closer. This renders
data/cornell-box/pm-fg.toml and prs-fg.toml (or the jobs given) with several
photon seeds and reports, per crop (default: the two ceiling, back-wall and
side-wall corners, 20,20,16,16 and 92,20,16,16 of the 128 x 128 image), the
mean signed error against data/cornell-box/reference/reference.exr in percent
of the reference's mean there, averaged over the seeds, with its standard
error; and the splat / gather time T_S (fg_splat's splat_us against
final_gather's gather_cpu_us, process CPU time; the paper's 0.66x) and the
gather rays' trace time. Renders run on one thread (--threads 1); on a
shared machine CPU times are still noisy.

Usage: tools/prs_fg_report.py [--build DIR] [--seeds 1 2 3 4] [--photons N] [--fg-rays N]
"""
import argparse
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


def render(binary, job, work, seed, photons, fg_rays):
    out = work / f"{job.stem}-{seed}"
    stats = out / "stats.json"
    command = [str(binary), "render", str(job), "-q", "--threads", "1", "--out", str(out), "--stats", str(stats),
               "--set", f"passes.photon.seed={seed}"]
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


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default=str(ROOT / "build"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[11, 12, 13, 14])
    parser.add_argument("--photons", type=int, default=0, help="override the jobs' photon count")
    parser.add_argument("--fg-rays", type=int, default=0, help="override the jobs' final-gather rays")
    args = parser.parse_args()
    binary = Path(args.build) / "fluxgraph"
    scene_dir = ROOT / "data" / "cornell-box"
    reference = read_exr_rgb(scene_dir / "reference" / "reference.exr")
    width = 128
    if len(reference) != width * width:
        raise SystemExit("the reference is not 128 x 128")
    ref_means = [crop_mean(reference, width, c) for c in CROPS]

    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for job, instance, time_key in (("pm-fg", "final_gather", "gather_cpu_us"), ("prs-fg", "fg_splat", "splat_cpu_us")):
            errors = [[] for _ in CROPS]
            splat, trace = [], []
            for seed in args.seeds:
                pixels, stats = render(binary, scene_dir / f"{job}.toml", work, seed, args.photons, args.fg_rays)
                for i, crop in enumerate(CROPS):
                    errors[i].append(100.0 * (crop_mean(pixels, width, crop) - ref_means[i]) / ref_means[i])
                c = counters(stats, instance)
                splat.append(c[time_key] / 1e6)
                trace.append(c["trace_cpu_us"] / 1e6)
            rows[job] = (errors, splat, trace)

    print("| pipeline | " + " | ".join(f"crop {','.join(map(str, c))}" for c in CROPS) +
          " | T_S (CPU s) | gather-ray trace (CPU s) |")
    print("|---|" + "---:|" * (len(CROPS) + 2))
    for job, (errors, splat, trace) in rows.items():
        cells = []
        for e in errors:
            mean, err = mean_and_error(e)
            cells.append(f"{mean:+.1f} % ± {err:.1f}")
        print(f"| {job} | " + " | ".join(cells) + f" | {sum(splat) / len(splat):.2f} | {sum(trace) / len(trace):.2f} |")
    ts_ratio = sum(rows["prs-fg"][1]) / sum(rows["pm-fg"][1])
    print(f"\nT_S prs-fg / pm-fg = {ts_ratio:.2f} (the paper: 0.66); seeds {args.seeds}")


if __name__ == "__main__":
    main()
