#!/usr/bin/env python3
"""Throughput and equal-time error of bidirectional path tracing (`bdpt`)
against the path tracer (`pt`).

For each scene (default: cornell-box and volumetric-caustic):
  - samples/s: camera samples per second of each pass (for bdpt, one sample
    is a camera and a light subpath and all their connections), and
    paths/s: subpath vertices per second for bdpt (camera + light
    vertices, its counters) and path segments per second for pt;
  - equal-time RMSE: pt is rendered with as many samples per pixel as fit in
    the wall time of the bdpt render, and both are compared with a reference
    (--reference DIR/<scene>/reference.exr, e.g. from
    tools/render_bdpt_references.sh; without one only throughput is reported).

Usage:
  tools/bdpt_report.py [--build build] [--threads 2] [--spp 16] [--seed 3]
                       [--scenes cornell-box,volumetric-caustic]
                       [--reference out/bdpt-references] [--crop volumetric-caustic=0,16,128,112]
                       [--out out/bdpt-report] [--clock wall|cpu]

The jobs are data/<scene>/bdpt.toml and data/<scene>/pt.toml with the
sample count set on the command line.
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def fail(message):
    print(f"bdpt_report.py: {message}", file=sys.stderr)
    sys.exit(2)


def render(binary, job, out, name, threads, sets, seed):
    stats = out / f"{name}.json"
    cmd = [str(binary), "render", str(job), "--out", str(out), "--threads", str(threads), "-q", "--seed", str(seed),
           "--stats", str(stats), "--set", f"output.name={name}", "--set", "output.png=false"]
    for s in sets:
        cmd += ["--set", s]
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode != 0:
        fail(f"{' '.join(cmd)} failed:\n{result.stderr}")
    data = json.loads(stats.read_text())
    return data["passes"][0], out / f"{name}.exr"


def rmse(binary, image, reference, crop=None):
    cmd = [str(binary), "compare", str(image), str(reference), "--metric", "rmse"]
    if crop:
        cmd += ["--crop", crop]
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode != 0:
        fail(f"{' '.join(cmd)} failed:\n{result.stderr}")
    return float(result.stdout.split()[1])


def mean_rgb(image, crop=None):
    """Mean RGB over the crop (x,y,w,h) or the whole image, by oiiotool."""
    single = Path(str(image) + ".cut.exr")
    cmd = ["oiiotool", str(image), "--ch", "R,G,B"]
    if crop:
        x, y, w, h = (int(v) for v in crop.split(","))
        cmd += ["--cut", f"{w}x{h}+{x}+{y}"]
    subprocess.run(cmd + ["-o", str(single)], check=True, capture_output=True)
    stats = subprocess.run(["oiiotool", "--stats", str(single)], check=True, capture_output=True, text=True).stdout
    single.unlink()
    line = next(l for l in stats.splitlines() if "Stats Avg" in l)
    return [float(v) for v in line.split(":")[1].split()[:3]]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--spp", type=int, default=16, help="bdpt samples per pixel")
    ap.add_argument("--seed", type=int, default=3,
                    help="seed of the renders (tools/render_bdpt_references.sh uses 1 and 2: keep them apart, "
                         "or the light subpaths repeat the reference's)")
    ap.add_argument("--scenes", default="cornell-box,volumetric-caustic")
    ap.add_argument("--reference", default=None, help="folder with <scene>/reference.exr")
    ap.add_argument("--crop", action="append", default=["volumetric-caustic=0,16,128,112"],
                    help="scene=x,y,w,h also compared over that rectangle")
    ap.add_argument("--out", default="out/bdpt-report")
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="time that sets pt's equal-time budget and the rates: wall seconds, or CPU seconds of the "
                         "pass (the fair choice on a shared machine; pair it with --threads 1)")
    args = ap.parse_args()
    seconds = f"{args.clock}_seconds"

    binary = Path(args.build) / "fluxgraph"
    if not binary.exists():
        fail(f"no {binary}; build first")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    crops = dict(c.split("=", 1) for c in args.crop)

    rows = []
    for scene in args.scenes.split(","):
        data = ROOT / "data" / scene
        bdpt_job, pt_job = data / "bdpt.toml", data / "pt.toml"
        if not bdpt_job.exists() or not pt_job.exists():
            fail(f"{scene} needs data/{scene}/bdpt.toml and pt.toml")
        b, b_image = render(binary, bdpt_job, out, f"{scene}-bdpt", args.threads, [f"passes.bdpt.spp={args.spp}"], args.seed)
        # A short pt run measures its rate, from which the equal-time sample count follows.
        p, _ = render(binary, pt_job, out, f"{scene}-pt-probe", args.threads, [f"passes.pt.spp={args.spp}"], args.seed)
        pt_spp = max(1, round(args.spp * b[seconds] / p[seconds]))
        p_eq, p_image = render(binary, pt_job, out, f"{scene}-pt", args.threads, [f"passes.pt.spp={pt_spp}"], args.seed)
        bdpt_vertices = b["counters"].get("camera_vertices", 0) + b["counters"].get("light_vertices", 0)
        row = {
            "scene": scene,
            "clock": args.clock,
            "bdpt_spp": args.spp,
            "bdpt_seconds": b[seconds],
            "bdpt_samples_per_s": b["items"] / b[seconds],
            "bdpt_vertices_per_s": bdpt_vertices / b[seconds],
            "pt_samples_per_s": p["items"] / p[seconds],
            "pt_segments_per_s": p["counters"].get("path_segments", 0) / p[seconds],
            "pt_equal_time_spp": pt_spp,
            "pt_seconds": p_eq[seconds],
        }
        reference = Path(args.reference) / scene / "reference.exr" if args.reference else None
        if reference and reference.exists():
            row["bdpt_rmse"] = rmse(binary, b_image, reference)
            row["pt_rmse"] = rmse(binary, p_image, reference)
            if scene in crops:
                row["bdpt_rmse_crop"] = rmse(binary, b_image, reference, crops[scene])
                row["pt_rmse_crop"] = rmse(binary, p_image, reference, crops[scene])
            crop = crops.get(scene)
            row["mean_rgb_reference"] = mean_rgb(reference, crop)
            row["mean_rgb_bdpt"] = mean_rgb(b_image, crop)
            row["mean_rgb_pt"] = mean_rgb(p_image, crop)
        rows.append(row)

    (out / "report.json").write_text(json.dumps(rows, indent=2))
    print(f"{'scene':<20} {'bdpt smp/s':>11} {'bdpt vtx/s':>11} {'pt smp/s':>10} {'pt seg/s':>10} "
          f"{'pt spp@eq':>9} {'bdpt RMSE':>10} {'pt RMSE':>10} {'ratio':>6}")
    for r in rows:
        b_err, p_err = r.get("bdpt_rmse_crop", r.get("bdpt_rmse")), r.get("pt_rmse_crop", r.get("pt_rmse"))
        errors = (f"{b_err:>10.4f} {p_err:>10.4f} {b_err / p_err:>6.2f}" if b_err is not None and p_err
                  else f"{'-':>10} {'-':>10} {'-':>6}")
        print(f"{r['scene']:<20} {r['bdpt_samples_per_s']:>11.0f} {r['bdpt_vertices_per_s']:>11.0f} "
              f"{r['pt_samples_per_s']:>10.0f} {r['pt_segments_per_s']:>10.0f} {r['pt_equal_time_spp']:>9} {errors}")
    for r in rows:
        if "mean_rgb_reference" in r:
            ref, b, p = r["mean_rgb_reference"], r["mean_rgb_bdpt"], r["mean_rgb_pt"]
            print(f"{r['scene']}: mean RGB over the crop: reference {ref[0]:.4f} {ref[1]:.4f} {ref[2]:.4f}, "
                  f"bdpt {b[0]:.4f} {b[1]:.4f} {b[2]:.4f} ({100 * (sum(b) / sum(ref) - 1):+.2f} %), "
                  f"pt {p[0]:.4f} {p[1]:.4f} {p[2]:.4f} ({100 * (sum(p) / sum(ref) - 1):+.2f} %)")
    print(f"(RMSE over the crop where one is given; details in {out / 'report.json'})")


if __name__ == "__main__":
    main()
