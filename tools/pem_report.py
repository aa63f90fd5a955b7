#!/usr/bin/env python3
"""Table 2 of Jakob et al. 2011 for our `pem` and `bre` pipelines: for each
scene and number of Gaussians k, the progressive EM fit (n0 = 128 k volume
photons, then maps of 32 k while a component asks for them) and the beam
radiance estimate over as many volume photons as the fit used.

Columns: k, n (photons the fit used), |P| (cells of the final cut), EM
iterations (inner / outer), preprocess / render / total for bre and pem and
pem's speed-ups, RMSE of each image against data/<scene>/reference/reference.exr.

  bre preprocess = photon + photon_radius + photon_bvh, render = beam_query;
  pem preprocess = photon + pem_fit + gmm_pyramid + gmm_bbh, render = gmm_render.

The surface part (gather) is the same in both and left out. Times are CPU
seconds of each pass (`--stats`), which a loaded machine distorts less than
wall time; the photon pass streams while pem_fit runs, so their wall times
overlap anyway.

Usage:
  tools/pem_report.py [--build build] [--scenes volumetric-caustic,spot-fog]
                      [--ks 1024,4096] [--threads N] [--out results/pem]

Writes <out>/README.md; runs, stats and images go to <out>/runs.
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

BRE_PREPROCESS = ("photon", "photon_radius", "photon_bvh")
PEM_PREPROCESS = ("photon", "pem_fit", "gmm_pyramid", "gmm_bbh")


def fail(message):
    print(message, file=sys.stderr)
    sys.exit(2)


def render(binary, job, out_dir, stats, sets, threads):
    cmd = [str(binary), "render", str(job), "--out", str(out_dir), "-q", "--stats", str(stats)]
    for s in sets:
        cmd += ["--set", s]
    if threads is not None:
        cmd += ["--threads", str(threads)]
    subprocess.run(cmd, check=True)
    return {p["instance"]: p for p in json.loads(stats.read_text())["passes"]}


def cpu(passes, names):
    return sum(passes[n]["cpu_seconds"] for n in names if n in passes)


def rmse(binary, image, reference):
    out = subprocess.run([str(binary), "compare", str(image), str(reference), "--metric", "rmse"],
                         check=True, capture_output=True, text=True).stdout
    return float(out.split()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default="build")
    parser.add_argument("--scenes", default="volumetric-caustic,spot-fog")
    parser.add_argument("--ks", default="1024,4096")
    parser.add_argument("--threads", type=int)
    parser.add_argument("--out", default="results/pem")
    args = parser.parse_args()
    binary = (ROOT / args.build / "fluxgraph").resolve()
    if not binary.exists():
        fail(f"pem_report: no {binary}; build first")
    out = Path(args.out)
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    rows = []
    for scene in args.scenes.split(","):
        reference = ROOT / "data" / scene / "reference" / "reference.exr"
        if not reference.exists():
            fail(f"pem_report: no reference {reference}")
        for k in (int(v) for v in args.ks.split(",")):
            tag = f"{scene}-k{k}"
            pem = render(binary, ROOT / "data" / scene / "pem.toml", runs / f"{tag}-pem", runs / f"{tag}-pem.json",
                         [f"passes.pem_fit.k={k}", f"passes.photon.volume_photons={128 * k}",
                          f"passes.photon.volume_batch={32 * k}"], args.threads)
            fit = pem["pem_fit"]["counters"]
            n = fit["photons"]
            bre = render(binary, ROOT / "data" / scene / "bre.toml", runs / f"{tag}-bre", runs / f"{tag}-bre.json",
                         [f"passes.photon.volume_photons={n}"], args.threads)
            bre_pre, bre_render = cpu(bre, BRE_PREPROCESS), cpu(bre, ("beam_query",))
            pem_pre, pem_render = cpu(pem, PEM_PREPROCESS), cpu(pem, ("gmm_render",))
            rows.append({
                "scene": scene, "k": k, "n": n, "cells": fit["cells"],
                "iterations": f"{fit['inner_iterations']} / {fit['outer_iterations']}",
                "batches": fit["batches"], "sparse": fit.get("sparse_components", 0),
                "bre": (bre_pre, bre_render), "pem": (pem_pre, pem_render),
                "rmse_bre": rmse(binary, runs / f"{tag}-bre" / f"{scene}-bre.exr", reference),
                "rmse_pem": rmse(binary, runs / f"{tag}-pem" / f"{scene}-pem.exr", reference),
            })
            print(f"{tag}: n {n}, pem {pem_pre:.2f} + {pem_render:.2f} s, bre {bre_pre:.2f} + {bre_render:.2f} s",
                  file=sys.stderr)
    lines = [
        "# Progressive EM against the beam radiance estimate (Jakob et al. 2011, Table 2)",
        "",
        "Written by `tools/pem_report.py`. CPU seconds per pass (`--stats`); bre uses as many volume photons",
        "as the fit did. RMSE against `data/<scene>/reference/reference.exr`.",
        "",
        "| scene | k | n | batches | \\|P\\| | EM iter. (inner / outer) | sparse | bre pre | bre render | bre total "
        "| pem pre | pem render | pem total | RMSE bre | RMSE pem |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        (bp, br), (pp, pr) = r["bre"], r["pem"]
        lines.append(
            f"| {r['scene']} | {r['k']} | {r['n']:,} | {r['batches']} | {r['cells']:,} | {r['iterations']} | "
            f"{r['sparse']} | {bp:.2f} s | {br:.2f} s | {bp + br:.2f} s | {pp:.2f} s | "
            f"{pr:.2f} s ({br / pr:.2f}×) | {pp + pr:.2f} s ({(bp + br) / (pp + pr):.2f}×) | "
            f"{r['rmse_bre']:.4f} | {r['rmse_pem']:.4f} |")
    (out / "README.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'README.md'}", file=sys.stderr)


if __name__ == "__main__":
    main()
