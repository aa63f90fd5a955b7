#!/usr/bin/env python3
"""Table 2 of Herzog et al. 2007 for the rows fluxgraph has: one run each of
photon mapping (PM = spm), photon ray splatting (RS = prs), ray splatting
with the radiance cache (RC = prs-rc) and final gathering by photon maps and
by ray splatting (PM-FG = pm-fg, RS-FG = prs-fg, 128 x 128 x 1, 50k photons,
16 gather rays) on the Cornell box, written to results/prs/README.md.

Columns as the paper's, in CPU seconds of the passes (the wall clock of a
shared machine says more about its load than about the method):
  T_E  eye pass and the index over its vertices (eye, splat_index)
  T_L  photons, bandwidths and their order (photon, ray_bandwidth, photon_index)
  T_S  density estimation (ray_splat, radiance_cache, radiance_integrate; gather for PM;
       the splat / gather phase of fg_splat / final_gather, their gather-ray tracing counted in T_E)
  ΣT   their sum (composite and scene loading are left out)
and the RMSE and relMSE of each image against the scene's reference.

    python3 tools/prs_report.py [--threads 1] [--photons 200000] [--out results/prs]
"""
import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE_DIR = os.path.join(ROOT, "data", "cornell-box")
REFERENCE = os.path.join(SCENE_DIR, "reference", "reference.exr")
PHASES = {
    "T_E": {"eye", "splat_index", "eye_index"},
    "T_L": {"photon", "ray_bandwidth", "photon_index"},
    "T_S": {"ray_splat", "radiance_cache", "radiance_integrate", "gather"},
}

# Photon mapping on the same film, eye samples and photons as prs.toml; k as
# the README's comparison of spm with prs.
SPM_JOB = """scene = "{scene}"
pipeline = "spm"
seed = 1

[film]
width = 128
height = 128
filter = "gaussian"

[passes.eye]
spp = 4

[passes.photon]
photons = 200000

[passes.gather]
k_global = 100
"""


def render(binary, job, out_dir, threads, photons):
    stats = os.path.join(out_dir, "stats.json")
    command = [binary, "render", job, "--out", out_dir, "--threads", str(threads), "--stats", stats]
    if photons:
        command += ["--set", f"passes.photon.photons={photons}"]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    with open(stats) as f:
        passes = json.load(f)["passes"]
    times = {phase: sum(p["cpu_seconds"] for p in passes if p["pass"] in names) for phase, names in PHASES.items()}
    counters = {}
    for p in passes:
        counters.update(p.get("counters", {}))
        if p["pass"] in ("fg_splat", "final_gather"):
            c = p["counters"]
            times["T_E"] += c["trace_cpu_us"] / 1e6
            times["T_S"] += c.get("splat_cpu_us", c.get("gather_cpu_us", 0)) / 1e6
    images = [name for name in os.listdir(out_dir) if name.endswith(".exr")]
    return times, counters, os.path.join(out_dir, images[0])


def compare(binary, image):
    text = subprocess.run([binary, "compare", image, REFERENCE], check=True, capture_output=True, text=True).stdout
    values = dict(line.split()[:2] for line in text.splitlines() if len(line.split()) >= 2)
    return float(values["rmse"]), float(values["relmse"])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--photons", type=int, default=0, help="override the jobs' photon count")
    parser.add_argument("--out", default=os.path.join(ROOT, "results", "prs"))
    parser.add_argument("--binary", default=os.path.join(ROOT, "build", "fluxgraph"))
    args = parser.parse_args()

    os.makedirs(args.out, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        spm_job = os.path.join(scratch, "spm.toml")
        with open(spm_job, "w") as f:
            f.write(SPM_JOB.format(scene=os.path.join(SCENE_DIR, "cornell-box.xml")))
        methods = [
            ("PM (spm, k = 100)", spm_job),
            ("RS (prs, C = 1.0, S = 0.4)", os.path.join(SCENE_DIR, "prs.toml")),
            ("RC (prs-rc, C = 0.6, S = 0.4, ε = 0.7)", os.path.join(SCENE_DIR, "prs-rc.toml")),
            ("PM-FG (pm-fg, k = 100, 16 FGRs)", os.path.join(SCENE_DIR, "pm-fg.toml")),
            ("RS-FG (prs-fg, C = 0.6, S = 0.8, 16 FGRs, 1 tile)", os.path.join(SCENE_DIR, "prs-fg.toml")),
        ]
        for label, job in methods:
            out_dir = os.path.join(scratch, str(len(rows)))
            os.makedirs(out_dir)
            print(f"rendering {label} ...", file=sys.stderr)
            # --photons applies to the direct-visualisation rows; the FG jobs keep their own count.
            photons = 0 if "FG" in label else args.photons
            times, counters, image = render(args.binary, job, out_dir, args.threads, photons)
            rmse, relmse = compare(args.binary, image)
            rows.append((label, times, counters, rmse, relmse))

    load = os.getloadavg()[0]
    lines = [
        "# Photon ray splatting: Table 2 of Herzog et al. 2007 on the Cornell box",
        "",
        f"Written by `tools/prs_report.py --threads {args.threads}"
        + (f" --photons {args.photons}" if args.photons else "")
        + f"` on {datetime.date.today().isoformat()}; load average {load:.1f} on {os.cpu_count()} cores when it"
        " finished. Times are CPU seconds of the passes (see the script); on a loaded machine they vary by about"
        " 10 % between runs. 128 × 128 × 4, 200k emitted photon paths unless --photons says otherwise (FG rows:"
        " 128 × 128 × 1, 50k, as their jobs); RMSE and"
        " relMSE against `data/cornell-box/reference/reference.exr`.",
        "",
        "| Method | T_E | T_L | T_S | ΣT | RMSE | relMSE |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for label, times, counters, rmse, relmse in rows:
        total = sum(times.values())
        lines.append(
            f"| {label} | {times['T_E']:.2f} | {times['T_L']:.2f} | {times['T_S']:.2f} | {total:.2f} | {rmse:.4f} | {relmse:.4f} |"
        )
    rc_counters = rows[2][2]
    lines += [
        "",
        f"RC's T_S is {rows[2][1]['T_S'] / rows[1][1]['T_S']:.2f} × RS's (the paper: 11.9 / 58.3 = 0.20 on its"
        f" Cornell box I). RC placed {rc_counters.get('cache_records', 0)} records"
        f" ({rc_counters.get('records_pass_1', 0)}, {rc_counters.get('records_pass_2', 0)},"
        f" {rc_counters.get('records_pass_3', 0)} per pass); {rc_counters.get('undercovered_pixels', 0)} pixels"
        f" were covered by fewer than min_records, {rc_counters.get('uncached_vertices', 0)} vertices by none.",
        "",
        f"RS-FG's T_S is {rows[4][1]['T_S'] / rows[3][1]['T_S']:.2f} × PM-FG's (the paper: 2714 / 4114 = 0.66 on"
        " its conference room with 600 gather rays).",
        "",
    ]
    path = os.path.join(args.out, "README.md")
    with open(path, "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
