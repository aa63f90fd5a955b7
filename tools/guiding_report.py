#!/usr/bin/env python3
"""Equal-time relMSE of guided vs unguided path tracing (issue #20, Vorba et al. 2014).

For each scene: renders guided-pt (training included in its time), then pt with
its spp scaled so that pt takes the same CPU time (the passes' CPU seconds at
the same thread count; wall time on a shared machine is mostly other load),
and compares both with a reference by `fluxgraph compare --metric relmse`. Prints a Markdown table with
the time shares of guided-pt (training passes vs the guided pt pass).

References: data/<scene>/reference/reference.exr is used only if it has the
size rendered here; otherwise a pt reference at --reference-spp is rendered
once into the output folder, with a seed of its own (with the judged images'
seed its first samples would be pt's, and pt's error would look smaller than
it is). Its own noise adds to both relMSE figures and pulls their ratio
towards 1, so a second reference of the same spp and another seed is rendered
as well: relMSE(reference, second) / 2 estimates the reference's share of
every relMSE ("ref noise"), and the ratio with that share taken out of both
figures is printed beside the raw one. Where the share is not well below pt's
relMSE, the reference cannot judge that budget.

Each budget of --spp (the guided pt pass's samples per pixel; the guided run's
CPU time, training included, is the budget pt gets) is one row.

    tools/guiding_report.py --out results/guiding   # the defaults: 64x48, 512/1024/2048 guided spp, 4096-spp reference

Time shares of the guided pt pass (cache query, GMM sampling and density,
BSDF, Embree) from a profile:

    perf record -e cpu-clock -F 1000 --call-graph dwarf -o p.data -- build/fluxgraph render JOB.toml --threads 1
    perf script -i p.data -F comm,tid,time,ip,sym,dso --inline > p.txt
    tools/guiding_report.py --perf-shares p.txt
"""
import argparse
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SCENES = {
    "veach-ajar": os.path.join(ROOT, "data/veach-ajar/fragments/veach-ajar.xml"),
    "cornell-box": os.path.join(ROOT, "data/cornell-box/cornell-box.xml"),
}


def pipeline_text(training_passes, path):
    text = open(path).read()
    text = text[text.index("[pipeline]"):]
    text = text.replace('name = "guided-pt"', 'name = "guided-pt-report"').replace("count = 30", f"count = {training_passes}")
    return "\n".join(line for line in text.splitlines() if not line.startswith("doc =")) + "\n"


def job(scene, width, height, body, pipeline=None, seed=1):
    top = f'pipeline = "{pipeline}"\n' if pipeline else ""
    return f'scene = "{scene}"\nseed = {seed}\n{top}[film]\nwidth = {width}\nheight = {height}\n' + body


def run(binary, job_text, path, out_dir, threads):
    with open(path, "w") as f:
        f.write(job_text)
    result = subprocess.run([binary, "render", path, "--out", out_dir, "--threads", str(threads)],
                            capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"render {path} failed:\n{result.stderr}")
    # CPU seconds per pass instance: on a shared machine wall time follows the
    # other users' load (2-thread passes measured between 0.13 and 0.3 CPU s
    # per wall s), CPU time far less so.
    rows = {}
    for line in (result.stdout + result.stderr).splitlines():
        m = re.match(r"^(\S+)\s+([0-9.]+)\s+([0-9.]+)\s", line)
        if m and "[*]" not in m.group(1):
            rows[m.group(1)] = float(m.group(3))
    name = os.path.splitext(os.path.basename(path))[0]
    return os.path.join(out_dir, name + ".exr"), sum(rows.values()), rows


def relmse(binary, image, reference):
    """relMSE and the largest per-pixel relative squared error (a few outliers can carry relMSE)."""
    out = subprocess.run([binary, "compare", image, reference, "--metric", "all"], capture_output=True, text=True)
    m = re.search(r"^relmse\s+([0-9.eE+-]+)", out.stdout, re.M)
    w = re.search(r"^worst_relse\s+([0-9.eE+-]+)", out.stdout, re.M)
    if not m or not w:
        sys.exit(f"compare failed: {out.stdout}{out.stderr}")
    return float(m.group(1)), float(w.group(1))


# Time shares of a guided pt pass from `perf script -F comm,tid,time,ip,sym,dso
# --inline` of a `perf record --call-graph dwarf` run: each sample whose stack
# holds PathTracerPass::run goes to the innermost frame that belongs to one of
# the categories. Embree's frames do not unwind to the pass (no unwind tables
# deep enough), so Embree samples within the pass's time span are added to it.
SHARE_CATEGORIES = [
    ("GMM density", re.compile(r"DirectionalGmm::pdfSquare|DirectionalGmm::pdfLocal|hemisphereToSquare")),
    ("GMM sampling", re.compile(r"DirectionalGmm::samplePlane|squareToHemisphere")),
    ("cache query", re.compile(r"GuidingCache::lookupCovering|GuidingCache::lookup\b")),
    ("BSDF and textures", re.compile(r"Bsdf[A-Za-z<>:]*::(eval|sample|pdf)|fresnel|Ggx|Beckmann|Texture")),
]


def perf_shares(path):
    samples, current = [], None
    for line in open(path, errors="replace"):
        if not line.strip() or line[0] not in " \t":
            if current:
                samples.append(current)
            current = None
            if line.strip():
                m = re.search(r"\s([0-9]+\.[0-9]+):", line)
                current = [float(m.group(1)) if m else 0.0, []]
            continue
        if current is not None:
            current[1].append(line.strip())
    if current:
        samples.append(current)
    in_pass = [s for s in samples if any("PathTracerPass::run" in f for f in s[1])]
    if not in_pass:
        sys.exit("no sample of PathTracerPass::run")
    start, end = min(s[0] for s in in_pass), max(s[0] for s in in_pass)
    counts = {name: 0 for name, _ in SHARE_CATEGORIES}
    counts["Embree"] = sum(1 for s in samples if s[1] and "libembree" in s[1][0] and start <= s[0] <= end
                           and not any("PathTracerPass::run" in f for f in s[1]))
    counts["other"] = 0
    for s in in_pass:
        name = next((n for f in s[1] for n, rx in SHARE_CATEGORIES if rx.search(f)), None)
        if name is None:
            name = "Embree" if "libembree" in s[1][0] else "other"
        counts[name] += 1
    total = len(in_pass) + counts["Embree"]
    print(f"pt pass: {total} samples")
    for name, n in counts.items():
        print(f"{name:18s} {n:6d} {100.0 * n / total:5.1f} %")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--binary", default=os.path.join(ROOT, "build/fluxgraph"))
    parser.add_argument("--out", default=os.path.join(ROOT, "results/guiding"))
    parser.add_argument("--scenes", default="veach-ajar,cornell-box")
    parser.add_argument("--size", default="64x48")
    parser.add_argument("--training-passes", type=int, default=3)
    parser.add_argument("--photons", type=int, default=10000)
    parser.add_argument("--training-particles", type=int, default=256)
    parser.add_argument("--max-sweeps", type=int, default=12, help="cache_update max_sweeps")
    parser.add_argument("--spacing", type=float, default=1.0, help="cache_update new_record_spacing")
    parser.add_argument("--candidates", type=int, default=2, help="pt and importon guiding_candidates (M of Eq. 11)")
    parser.add_argument("--importon-spp", type=int, default=1, help="importon paths per pixel per training pass")
    parser.add_argument("--guide-decision", default="variance", choices=["variance", "always"],
                        help="cache_update guide_decision (always: every record's mixture is sampled, as before it existed)")
    parser.add_argument("--guide-moment-ratio", type=float, default=0.3, help="cache_update guide_moment_ratio")
    parser.add_argument("--spp", type=int, nargs="+", default=[512, 1024, 2048],
                        help="guided pt samples per pixel, one budget each")
    parser.add_argument("--rr-threshold", type=float, default=1.0,
                        help="rr_threshold of the guided job's importon, photon and pt passes (1e-5: Vorba et al. §4.5)")
    parser.add_argument("--pt-rr-threshold", type=float, default=1.0, help="rr_threshold of the unguided pt runs")
    parser.add_argument("--reference-spp", type=int, default=4096)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1, help="seed of the guided run (the reference uses 2, pt 1)")
    parser.add_argument("--pipeline", default=os.path.join(ROOT, "passes/pipelines/guided-pt.toml"),
                        help="the guided-pt pipeline file (another build's, to compare builds)")
    parser.add_argument("--perf-shares", metavar="PERF_SCRIPT_OUTPUT",
                        help="only print the guided pt pass's time shares from this perf script output")
    args = parser.parse_args()
    if args.perf_shares:
        perf_shares(args.perf_shares)
        return
    width, height = (int(v) for v in args.size.split("x"))
    os.makedirs(args.out, exist_ok=True)
    lines = ["| scene | guided spp | guided CPU s | training share | guided pt share | guided relMSE (worst pixel) | pt spp | "
             "pt CPU s | pt relMSE (worst pixel) | ref noise | guided/pt relMSE | less ref noise |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in args.scenes.split(","):
        scene = SCENES[name]
        work = os.path.join(args.out, name)
        os.makedirs(work, exist_ok=True)
        reference = os.path.join(work, "reference.exr")
        second = os.path.join(work, "reference-second.exr")
        for path, seed in ((reference, 2), (second, 3)):
            if not os.path.exists(path):
                body = f"[passes.pt]\nspp = {args.reference_spp}\nmax_depth = 16\n"
                toml = os.path.splitext(path)[0] + ".toml"
                run(args.binary, job(scene, width, height, body, "pt", seed=seed), toml, work, args.threads)
        # Two independent references of equal spp differ by twice the noise of one.
        reference_noise = relmse(args.binary, second, reference)[0] / 2.0
        decision = (f"guide_decision = \"{args.guide_decision}\"\nguide_moment_ratio = {args.guide_moment_ratio}\n"
                    if args.guide_decision != "variance" or args.guide_moment_ratio != 0.3 else "")
        rr = f"rr_threshold = {args.rr_threshold!r}\n" if args.rr_threshold != 1.0 else ""
        plain_rr = f"rr_threshold = {args.pt_rr_threshold!r}\n" if args.pt_rr_threshold != 1.0 else ""
        # pt's time per sample from a short run, then the spp that fills each guided budget.
        probe_spp = 32
        _, probe_time, probe_rows = run(args.binary, job(scene, width, height, f"[passes.pt]\nspp = {probe_spp}\nmax_depth = 16\n{plain_rr}", "pt"),
                                        os.path.join(work, "probe.toml"), work, args.threads)
        per_spp = probe_rows.get("pt", probe_time) / probe_spp
        for guided_spp in args.spp:
            guided_body = (f"[passes.importon]\nspp = {args.importon_spp}\nmax_depth = 16\nguiding_candidates = {args.candidates}\n{rr}"
                           f"[passes.photon]\nphotons = {args.photons}\nstore = \"global\"\ndifferentials = false\n{rr}"
                           f"guiding_candidates = {args.candidates}\n"
                           f"[passes.radiance_update]\ntraining_particles = {args.training_particles}\n"
                           f"max_sweeps = {args.max_sweeps}\nnew_record_spacing = {args.spacing}\n{decision}"
                           f"[passes.importance_update]\ntraining_particles = {args.training_particles}\n"
                           f"max_sweeps = {args.max_sweeps}\nnew_record_spacing = {args.spacing}\n{decision}"
                           f"[passes.pt]\nspp = {guided_spp}\nmax_depth = 16\nguiding_candidates = {args.candidates}\n{rr}\n"
                           + pipeline_text(args.training_passes, args.pipeline))
            guided, guided_time, rows = run(args.binary, job(scene, width, height, guided_body, seed=args.seed),
                                            os.path.join(work, f"guided-pt-{guided_spp}.toml"), work, args.threads)
            training = sum(v for k, v in rows.items() if k.startswith("train["))
            pt_share = rows.get("pt", 0.0)
            spp = max(1, int(round(guided_time / per_spp)))
            plain, plain_time, _ = run(args.binary, job(scene, width, height, f"[passes.pt]\nspp = {spp}\nmax_depth = 16\n{plain_rr}", "pt"),
                                       os.path.join(work, f"pt-{guided_spp}.toml"), work, args.threads)
            (g, gw), (p, pw) = relmse(args.binary, guided, reference), relmse(args.binary, plain, reference)
            corrected = (g - reference_noise) / (p - reference_noise) if p > 2.0 * reference_noise else float("nan")
            lines.append(f"| {name} | {guided_spp} | {guided_time:.1f} | {training / guided_time:.0%} | {pt_share / guided_time:.0%} | "
                         f"{g:.4g} ({gw:.3g}) | {spp} | {plain_time:.1f} | {p:.4g} ({pw:.3g}) | {reference_noise:.3g} | "
                         f"{g / p:.3f} | {corrected:.3f} |")
            print(lines[-1], flush=True)
    report = "\n".join(lines) + "\n"
    with open(os.path.join(args.out, "README.md"), "w") as f:
        f.write("# Guided vs unguided pt at equal time\n\n" + " ".join(sys.argv) + "\n\n" + report)
    print(report)


if __name__ == "__main__":
    main()
