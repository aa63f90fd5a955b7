#!/usr/bin/env python3
"""Temporal coherence of the Gaussian-mixture fit (Jakob et al. 2011 §5.4):
an animation whose lamp moves a little each frame, rendered with `pem` fitted
independently per frame and coherently (each frame's pem_fit seeded with the
previous frame's mixture, `--save gmm=...` then `--import previous_gmm=...`),
and with `bre` at as many volume photons as the independent fit used.

The scene is data/<scene>/<scene>.xml with the lamp's position made a define
(`$lamp_x`, written to a temporary copy); frame t moves the lamp by
t * --step along x. Every frame draws its own photons (`--seed` 1 + t), as
separately rendered frames of an animation do, or with --same-seed the
same random numbers (seed 1), which correlates the photons of all frames.

Per frame: pem_fit CPU seconds (`--stats`), EM iterations, photons, the
CPU seconds of all of pem's media passes and of bre's; per method the
flicker: the RMSE between consecutive
frames over a crop of the lit fog (against the black background, so that the
photon-mapped floor, common to all methods, stays out), and the same for a
converged reference sequence (bre with --reference-factor times the photons,
one seed for all frames, so that its frame-to-frame change is the lamp's
motion). The excess sqrt(d^2 - d_ref^2) over the reference is the flicker:
independent noise of standard deviation s per pixel adds 2 s^2 to the mean
squared frame difference. Also per method the mean RMSE against the
reference frame over the same crop (the reference's own noise and bre's
blur included).

Usage:
  tools/pem_animation.py [--build build] [--scene spot-fog] [--frames 24] [--k 1024] [--res 64]
                         [--step 0.01] [--crop X,Y,W,H] [--same-seed] [--threads 1] [--out results/pem]

Writes <out>/animation.md and prints the same table.
"""
import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAMP_ORIGIN = 'origin="-1, 3.2, 0.3"'
BRE_PASSES = ("photon", "photon_radius", "photon_bvh", "beam_query")
PEM_PASSES = ("photon", "pem_fit", "gmm_pyramid", "gmm_bbh", "gmm_render")


def fail(message):
    print(message, file=sys.stderr)
    sys.exit(2)


def animated_scene(scene, work):
    """A copy of the scene whose lamp (disk and shade) is placed by $lamp_x."""
    source = ROOT / "data" / scene / f"{scene}.xml"
    text = source.read_text()
    if text.count(LAMP_ORIGIN) != 2:
        fail(f"pem_animation: {source} does not place its lamp at {LAMP_ORIGIN}")
    text = text.replace(LAMP_ORIGIN, 'origin="$lamp_x, 3.2, 0.3"')
    text = text.replace('<default name="spp"', '<default name="lamp_x" value="-1"/>\n    <default name="spp"', 1)
    text = text.replace('value="meshes/', f'value="{source.parent / "meshes"}/')
    path = work / f"{scene}-animated.xml"
    path.write_text(text)
    return path


def job_for(scene, method, scene_file, work):
    text = (ROOT / "data" / scene / f"{method}.toml").read_text()
    original = f'scene = "{scene}.xml"'
    if original not in text:
        fail(f"pem_animation: data/{scene}/{method}.toml does not name {scene}.xml")
    path = work / f"{method}.toml"
    path.write_text(text.replace(original, f'scene = "{scene_file}"'))
    return path


def render(binary, job, out_dir, args, extra):
    stats = out_dir / "stats.json"
    cmd = [str(binary), "render", str(job), "--out", str(out_dir), "-q", "--stats", str(stats),
           "--threads", str(args.threads), "--set", f"film.width={args.res}", "--set", f"film.height={args.res}"]
    cmd += extra
    subprocess.run(cmd, check=True)
    return {p["instance"]: p for p in json.loads(stats.read_text())["passes"]}


def crop_rmse(binary, a, b, crop):
    out = subprocess.run([str(binary), "compare", str(a), str(b), "--metric", "rmse", "--crop", crop],
                         check=True, capture_output=True, text=True).stdout
    return float(out.split()[-1])


def flicker(binary, images, crop):
    """Mean RMSE between consecutive frames over the crop."""
    return statistics.mean(crop_rmse(binary, images[t - 1], images[t], crop) for t in range(1, len(images)))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default="build")
    parser.add_argument("--scene", default="spot-fog")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--k", type=int, default=1024)
    parser.add_argument("--res", type=int, default=64)
    parser.add_argument("--step", type=float, default=0.01, help="lamp movement per frame (scene units, along x)")
    parser.add_argument("--crop", help="X,Y,W,H of the flicker crop (default: the beam above the sphere)")
    parser.add_argument("--reference-factor", type=int, default=2,
                        help="the reference's volume photons, times the first frame's independent fit's")
    parser.add_argument("--same-seed", action="store_true",
                        help="every frame with seed 1 (correlated photons) instead of 1 + frame")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="results/pem")
    args = parser.parse_args()
    binary = (ROOT / args.build / "fluxgraph").resolve()
    if not binary.exists():
        fail(f"pem_animation: no {binary}; build first")
    crop = args.crop or ",".join(str(round(v * args.res / 64)) for v in (14, 6, 12, 14))
    k = args.k
    fit_sets = ["--set", f"passes.pem_fit.k={k}", "--set", f"passes.photon.volume_photons={128 * k}",
                "--set", f"passes.photon.volume_batch={32 * k}"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="pem-animation-") as tmp:
        work = Path(tmp)
        scene_file = animated_scene(args.scene, work)
        pem_job, bre_job = job_for(args.scene, "pem", scene_file, work), job_for(args.scene, "bre", scene_file, work)
        frames = []
        images = {"independent": [], "coherent": [], "bre": [], "reference": []}
        reference_photons = None
        for t in range(args.frames):
            lamp = ["--define", f"lamp_x={-1.0 + args.step * t:.6f}"]
            seed = ["--seed", str(1 if args.same_seed else 1 + t)]
            row = {"frame": t}
            d = work / f"independent-{t}"
            p = render(binary, pem_job, d, args, lamp + seed + fit_sets)
            images["independent"].append(d / f"{args.scene}-pem.exr")
            row["independent"] = p["pem_fit"]
            row["independent_total"] = sum(p[name]["cpu_seconds"] for name in PEM_PASSES if name in p)
            d = work / f"coherent-{t}"
            saved = work / f"gmm-{t}.fgbuf"
            seeded = ["--import", f"previous_gmm={work / f'gmm-{t - 1}.fgbuf'}"] if t > 0 else []
            p = render(binary, pem_job, d, args, lamp + seed + fit_sets + ["--save", f"gmm={saved}"] + seeded)
            images["coherent"].append(d / f"{args.scene}-pem.exr")
            row["coherent"] = p["pem_fit"]
            row["coherent_total"] = sum(p[name]["cpu_seconds"] for name in PEM_PASSES if name in p)
            n = row["independent"]["counters"]["photons"]
            d = work / f"bre-{t}"
            p = render(binary, bre_job, d, args, lamp + seed + ["--set", f"passes.photon.volume_photons={n}"])
            images["bre"].append(d / f"{args.scene}-bre.exr")
            row["bre"] = sum(p[name]["cpu_seconds"] for name in BRE_PASSES if name in p)
            row["bre_n"] = n
            if reference_photons is None:
                reference_photons = args.reference_factor * n
            d = work / f"reference-{t}"
            render(binary, bre_job, d, args, lamp + ["--seed", "1", "--set", f"passes.photon.volume_photons={reference_photons}"])
            images["reference"].append(d / f"{args.scene}-bre.exr")
            frames.append(row)
            i, c = row["independent"], row["coherent"]
            print(f"frame {t}: pem_fit independent {i['cpu_seconds']:.3f} s ({i['counters']['inner_iterations']} it.), "
                  f"coherent {c['cpu_seconds']:.3f} s ({c['counters']['inner_iterations']} it.), bre {row['bre']:.3f} s",
                  file=sys.stderr)
        reference = flicker(binary, images["reference"], crop)
        change = {m: flicker(binary, images[m], crop) for m in ("independent", "coherent", "bre")}
        error = {m: statistics.mean(crop_rmse(binary, images[m][t], images["reference"][t], crop)
                                    for t in range(1, args.frames))
                 for m in ("independent", "coherent", "bre")}
        # The first coherent frame has nothing to be seeded with: it is an independent fit.
        later = frames[1:]

        def median(method, key):
            return statistics.median(r[method][key] if key != "iterations" else r[method]["counters"]["inner_iterations"]
                                     for r in later)

        def median_counter(method, key):
            return statistics.median(r[method]["counters"][key] for r in later)

    lines = [
        "# Temporal coherence of the mixture fit (Jakob et al. 2011 §5.4)",
        "",
        f"Written by `tools/pem_animation.py --scene {args.scene} --frames {args.frames} --k {k} --res {args.res} "
        f"--step {args.step} --threads {args.threads}{' --same-seed' if args.same_seed else ''}`: the lamp moves "
        f"{args.step} along x per frame, "
        f"{'every frame with seed 1' if args.same_seed else 'every frame draws its own photons (seed 1 + frame)'}; k = {k}, n0 = {128 * k}, maps of {32 * k}; "
        f"{args.res}x{args.res} pixels. CPU seconds per pass (`--stats`).",
        "",
        "| frame | independent pem_fit | iterations (inner / outer) | photons | coherent pem_fit | iterations "
        "(inner / outer) | photons | components indep. / coh. (restored) | \\|P\\| indep. / coh. | pem total indep. / coh. "
        "| bre total |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in frames:
        i, c = r["independent"], r["coherent"]
        ic, cc = i["counters"], c["counters"]
        lines.append(
            f"| {r['frame']} | {i['cpu_seconds']:.3f} s | {ic['inner_iterations']} / {ic['outer_iterations']} | "
            f"{ic['photons']:,} | {c['cpu_seconds']:.3f} s{'' if cc.get('seeded') else ' (not seeded)'} | "
            f"{cc['inner_iterations']} / {cc['outer_iterations']} | {cc['photons']:,} | "
            f"{ic['components']} / {cc['components']} ({cc.get('restored_components', 0)}) | "
            f"{ic['cells']:,} / {cc['cells']:,} | {r['independent_total']:.3f} / {r['coherent_total']:.3f} s | "
            f"{r['bre']:.3f} s |")
    total_i = sum(r["independent"]["cpu_seconds"] for r in later)
    total_c = sum(r["coherent"]["cpu_seconds"] for r in later)
    total_b = sum(r["bre"] for r in later)
    all_i = sum(r["independent_total"] for r in later)
    all_c = sum(r["coherent_total"] for r in later)

    def excess(d):
        return math.sqrt(max(0.0, d * d - reference * reference))

    lines += [
        "",
        f"Frames 1 to {args.frames - 1} (frame 0 has no previous mixture): pem_fit {total_i:.2f} s independent, "
        f"{total_c:.2f} s coherent ({total_i / total_c:.2f}× faster; per-frame medians "
        f"{median('independent', 'cpu_seconds'):.3f} and {median('coherent', 'cpu_seconds'):.3f} s); "
        f"median EM iterations {median('independent', 'iterations'):g} and {median('coherent', 'iterations'):g}, "
        f"photons {median_counter('independent', 'photons'):,.0f} and {median_counter('coherent', 'photons'):,.0f}; "
        f"all of pem's media passes (photon, pem_fit, gmm_pyramid, gmm_bbh, gmm_render) {all_i:.2f} s independent, "
        f"{all_c:.2f} s coherent ({all_i / all_c:.2f}×); bre's (photon, photon_radius, photon_bvh, beam_query, "
        f"at the independent fit's photons) {total_b:.2f} s. Components of the coherent fits: "
        f"{min(r['coherent']['counters']['components'] for r in later)} to "
        f"{max(r['coherent']['counters']['components'] for r in later)}, "
        f"{frames[-1]['coherent']['counters']['components']} in the last frame (k = {k}).",
        "",
        f"Flicker over the crop {crop} (x, y, w, h): mean RMSE between consecutive frames; the reference "
        f"(bre, {reference_photons:,} volume photons, one seed) changes by {reference:.5f} from frame to frame.",
        "",
        "| method | frame-to-frame RMSE | excess over the reference | RMSE against the reference |",
        "|---|---|---|---|",
    ]
    for method in ("independent", "coherent", "bre"):
        label = {"independent": "pem, independent fits", "coherent": "pem, coherent fits", "bre": "bre"}[method]
        lines.append(f"| {label} | {change[method]:.5f} | {excess(change[method]):.5f} | {error[method]:.5f} |")
    text = "\n".join(lines) + "\n"
    (out / "animation.md").write_text(text)
    print(text)
    print(f"wrote {out / 'animation.md'}", file=sys.stderr)


if __name__ == "__main__":
    main()
