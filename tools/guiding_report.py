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
CPU time, training included, is the budget pt gets) is one row per seed.

pt's spp for a budget comes from its CPU time per sample, the median of
--probe-runs runs of --probe-spp samples (a single 32-spp run gave pt 495-553
spp for the same 512-spp budget on a loaded machine, and pt's relMSE on a
small image jumps between nearby spp).
The efficiency column does not depend on that probe at all: (guided relMSE x
guided CPU s) / (pt relMSE x pt CPU s), each relMSE less the reference noise,
is the equal-time ratio wherever relMSE falls as 1 / time.

Seeds: the guided run of seed S uses S, the unguided pt run S + 1000 (see
PT_SEED_OFFSET), the references 2 and 3. With --seeds S1 S2 ... every seed
runs every budget, and a second table gives, per scene and budget, the mean
relMSE of each method over the seeds, the ratios of those means with their
standard error and a bootstrap interval, and the median training share.

    tools/guiding_report.py --out results/guiding   # the defaults: 64x48, 512/1024/2048 guided spp, 4096-spp reference, seed 1
    tools/guiding_report.py --out results/guiding --scenes cornell-box --seeds 1 4 5 6 7 8

Time shares of the guided pt pass (cache query, GMM sampling and density,
BSDF, Embree) from a profile:

    perf record -e cpu-clock -F 1000 --call-graph dwarf -o p.data -- build/fluxgraph render JOB.toml --threads 1
    perf script -i p.data -F comm,tid,time,ip,sym,dso --inline > p.txt
    tools/guiding_report.py --perf-shares p.txt
"""
import argparse
import math
import os
import random
import re
import statistics
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The references' seeds. Only their own noise should enter a relMSE: an image
# judged against a reference of its own seed shares its first pixel's samples
# with it (pt's streams are keyed by seed, pass instance and p * spp + s).
REFERENCE_SEEDS = (2, 3)
# The unguided pt run's seed is the guided run's plus this. With equal seeds
# the guided job's pt pass (instance "pt", like plain pt's) draws plain pt's
# streams: where no record guides (the Cornell box after its first training
# pass) the two images are the same at equal spp, and at pt's slightly larger
# spp the first pixels still share samples, so the two errors would be
# partly the same draw rather than independent ones.
PT_SEED_OFFSET = 1000

SCENES = {
    "veach-ajar": os.path.join(ROOT, "data/veach-ajar/fragments/veach-ajar.xml"),
    "cornell-box": os.path.join(ROOT, "data/cornell-box/cornell-box.xml"),
    # A closed room lit by a sky with a small sun through a curtain gap and a
    # thin glass pane (tools/make_geometry.py window-room): the paper's living
    # room / classroom case, where nearly all light arrives indirectly.
    "window-room": os.path.join(ROOT, "data/window-room/window-room.xml"),
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


def ratio_of_means(xs, ys):
    """mean(xs) / mean(ys) over paired runs, its standard error (ratio
    estimator: from the residuals x - R y) and a 95 % percentile bootstrap
    interval over the runs (fixed generator, so a report repeats)."""
    n = len(xs)
    r = statistics.fmean(xs) / statistics.fmean(ys)
    if n < 2:
        return r, float("nan"), (float("nan"), float("nan"))
    residuals = [x - r * y for x, y in zip(xs, ys)]
    se = math.sqrt(sum(d * d for d in residuals) / (n * (n - 1))) / statistics.fmean(ys)
    rng = random.Random(0)
    boot = []
    for _ in range(4000):
        idx = [rng.randrange(n) for _ in range(n)]
        den = sum(ys[i] for i in idx)
        if den != 0.0:
            boot.append(sum(xs[i] for i in idx) / den)
    boot.sort()
    return r, se, (boot[int(0.025 * len(boot))], boot[min(len(boot) - 1, int(0.975 * len(boot)))])


def format_ratio(value):
    r, se, (lo, hi) = value
    return f"{r:.3f} ± {se:.3f} [{lo:.3f}, {hi:.3f}]" if not math.isnan(se) else f"{r:.3f}"


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
    parser.add_argument("--seeds", "--seed", type=int, nargs="+", default=[1],
                        help=f"seeds of the guided runs, one run of each budget per seed (pt: seed + {PT_SEED_OFFSET}, "
                             f"the references {REFERENCE_SEEDS[0]} and {REFERENCE_SEEDS[1]})")
    parser.add_argument("--probe-spp", type=int, default=128, help="spp of each run that times pt's CPU seconds per sample")
    parser.add_argument("--probe-runs", type=int, default=3, help="probe runs; pt's cost per sample is their median")
    parser.add_argument("--pipeline", default=os.path.join(ROOT, "passes/pipelines/guided-pt.toml"),
                        help="the guided-pt pipeline file (another build's, to compare builds)")
    parser.add_argument("--perf-shares", metavar="PERF_SCRIPT_OUTPUT",
                        help="only print the guided pt pass's time shares from this perf script output")
    args = parser.parse_args()
    if args.perf_shares:
        perf_shares(args.perf_shares)
        return
    pt_seeds = [seed + PT_SEED_OFFSET for seed in args.seeds]
    taken = set(REFERENCE_SEEDS)
    for seed in args.seeds + pt_seeds:
        if seed in taken:
            sys.exit(f"seed {seed} is taken (references {REFERENCE_SEEDS}, pt runs use guided seed + {PT_SEED_OFFSET}): "
                     "give the guided runs other seeds")
        taken.add(seed)
    width, height = (int(v) for v in args.size.split("x"))
    os.makedirs(args.out, exist_ok=True)
    lines = ["| scene | guided spp | seed (pt seed) | guided CPU s | training share | guided pt share | guided relMSE (worst pixel) | "
             "pt spp | pt CPU s | pt relMSE (worst pixel) | ref noise | guided/pt relMSE | less ref noise | "
             "relMSE x CPU s ratio, less ref noise |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    summary = ["| scene | guided spp | seeds | training share (median) | pt spp (range) | ref noise | guided relMSE (mean) | "
               "pt relMSE (mean) | ratio of means ± SE [95 % bootstrap] | less ref noise | relMSE x CPU s, less ref noise |",
               "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in args.scenes.split(","):
        scene = SCENES[name]
        work = os.path.join(args.out, name)
        os.makedirs(work, exist_ok=True)
        reference = os.path.join(work, "reference.exr")
        second = os.path.join(work, "reference-second.exr")
        for path, seed in zip((reference, second), REFERENCE_SEEDS):
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
        # pt's CPU time per sample, the median of a few probe runs, then the spp that fills each guided budget.
        probes = []
        for i in range(args.probe_runs):
            _, probe_time, probe_rows = run(args.binary, job(scene, width, height, f"[passes.pt]\nspp = {args.probe_spp}\nmax_depth = 16\n{plain_rr}",
                                                             "pt", seed=pt_seeds[0]),
                                            os.path.join(work, f"probe-{i}.toml"), work, args.threads)
            probes.append(probe_rows.get("pt", probe_time) / args.probe_spp)
        per_spp = statistics.median(probes)
        print(f"{name}: pt CPU s per spp {per_spp:.5f} (median of {', '.join(f'{v:.5f}' for v in probes)})", flush=True)
        runs = {guided_spp: [] for guided_spp in args.spp}
        for seed, pt_seed in zip(args.seeds, pt_seeds):
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
                guided, guided_time, rows = run(args.binary, job(scene, width, height, guided_body, seed=seed),
                                                os.path.join(work, f"guided-pt-{guided_spp}-seed{seed}.toml"), work, args.threads)
                training = sum(v for k, v in rows.items() if k.startswith("train["))
                pt_share = rows.get("pt", 0.0)
                spp = max(1, int(round(guided_time / per_spp)))
                plain, plain_time, _ = run(args.binary, job(scene, width, height, f"[passes.pt]\nspp = {spp}\nmax_depth = 16\n{plain_rr}",
                                                            "pt", seed=pt_seed),
                                           os.path.join(work, f"pt-{guided_spp}-seed{seed}.toml"), work, args.threads)
                (g, gw), (p, pw) = relmse(args.binary, guided, reference), relmse(args.binary, plain, reference)
                judged = p > 2.0 * reference_noise
                corrected = (g - reference_noise) / (p - reference_noise) if judged else float("nan")
                efficiency = corrected * guided_time / plain_time if judged else float("nan")
                runs[guided_spp].append(dict(g=g, p=p, guided_time=guided_time, plain_time=plain_time, spp=spp,
                                             share=training / guided_time))
                lines.append(f"| {name} | {guided_spp} | {seed} ({pt_seed}) | {guided_time:.2f} | {training / guided_time:.1%} | "
                             f"{pt_share / guided_time:.0%} | {g:.4g} ({gw:.3g}) | {spp} | {plain_time:.2f} | {p:.4g} ({pw:.3g}) | "
                             f"{reference_noise:.3g} | {g / p:.3f} | {corrected:.3f} | {efficiency:.3f} |")
                print(lines[-1], flush=True)
        for guided_spp, rs in runs.items():
            gs, ps = [r["g"] for r in rs], [r["p"] for r in rs]
            gc, pc = [g - reference_noise for g in gs], [p - reference_noise for p in ps]
            ge = [(r["g"] - reference_noise) * r["guided_time"] for r in rs]
            pe = [(r["p"] - reference_noise) * r["plain_time"] for r in rs]
            spps = [r["spp"] for r in rs]
            summary.append(f"| {name} | {guided_spp} | {len(rs)} | {statistics.median(r['share'] for r in rs):.1%} | "
                           f"{statistics.fmean(spps):.0f} ({min(spps)}–{max(spps)}) | {reference_noise:.3g} | "
                           f"{statistics.fmean(gs):.4g} | {statistics.fmean(ps):.4g} | {format_ratio(ratio_of_means(gs, ps))} | "
                           f"{format_ratio(ratio_of_means(gc, pc))} | {format_ratio(ratio_of_means(ge, pe))} |")
    report = "\n".join(lines) + "\n\nOver seeds:\n\n" + "\n".join(summary) + "\n"
    with open(os.path.join(args.out, "README.md"), "w") as f:
        f.write("# Guided vs unguided pt at equal time\n\n" + " ".join(sys.argv) + "\n\n" + report)
    print(report)


if __name__ == "__main__":
    main()
