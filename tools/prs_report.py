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
  T_S  density estimation (ray_splat, cache_select, radiance_cache, radiance_integrate; gather for PM;
       the splat / gather phase of fg_splat / final_gather, their gather-ray tracing counted in T_E)
  ΣT   their sum (composite and scene loading are left out)
and the RMSE and relMSE of each image against the scene's reference.

Beside them, for PM and RS, the mean bandwidth in millionths of the scene
diagonal (the paper chooses C so that RS's mean splat radius equals PM's
mean gather radius, §9 and Fig. 10): ray_splat's mean_hit_radius_ppm, R at
the hits of the splatted rays; for PM the distance to the k-th nearest
global photon, averaged over 3000 eye vertices drawn with a fixed seed from
the saved eye vertices and photon map (the gather pass reports no radius).
With --seeds the PM and RS rows are rendered again with those seeds
for the mean signed error in the concave corners (crops 20,20,16,16 and
92,20,16,16, and the whole image, percent of the reference's mean there, ± its
standard error). Each seed sets both the photon paths and the eye samples
(--fixed-eye keeps the job's eye samples): with one eye seed for every run
the eye samples' own error in a crop (about 0.4 % of the indirect light in
the first) would be one offset common to all rows, which no number of photon
seeds shows. PM and RS share each seed's photon paths and eye vertices, so
the photon set's error (about 1.3 % of the first crop's indirect light per seed
for PM) is largely common to both: the table adds RS - PM per seed, whose
standard error is the one that tells the two methods' biases apart. Four
seeds are too few for the bias itself: seeds 11-14 lie 1.3 points below the
mean of 20 for PM in the first crop;
with --corners-only nothing else is rendered and the corner table is only
printed; with --indirect those renders leave the direct light out (eye pass
direct_light = false) and are compared with the reference less a one-bounce
pt image of --direct-spp samples, so that the eye pass's direct-light noise,
common to both, does not enter the corner figures;
with --edge-split the same renders are split by each pixel's distance to the box's edges (its nearest eye
vertex's distance to another surface that rises in front of its own, a concave edge, or falls away behind it,
a convex edge; from the meshes of fragments/shapes.xml) in units of the mean splat radius at the hits: the
error of each band in % of its own light and its share of the whole image's error; with --photon-depth K the
photon paths end at K scattering events and the reference is pt with max_depth = K less one-bounce pt;
with --scaling RS's and PM's T_S at 1, 2 and 4 times the photons; with --bandwidth-spread (nothing else is
rendered; printed only; numpy) the spread of PM's and RS's bandwidths beyond their means, the samples a
vertex's estimate effectively averages, and Fig. 10's classes of the indirect light alone. Every row
also gets the shares of its pixels in Fig. 10's classes of relative error
against the reference (|image - reference| / reference of the channel mean:
below 5 %, below 15 %, 30 % and above).

With --footprint RS is rendered --repeats times alternating the frustum with
footprint = "sphere" (§9: frustum 1.5-2x the sphere's time), ray_splat's CPU
seconds, medians. With --memory prs.toml is rendered at 500 x 500 x 1 with
500k photon paths (and with as many paths as give 500k stored rays): the
bytes of the photon rays (ray_bandwidth's output), the splat index
(kd-tree, four-wide nodes and vertex columns) and the radiance film and
map (ray_splat's outputs), from --stats, and the process's peak RSS.

    python3 tools/prs_report.py [--threads 1] [--photons 200000] [--out results/prs]
                                [--seeds 11 12 13 14 [--indirect [--direct-spp 1024] [--photon-depth K]] [--fixed-eye]
                                 [--corners-only] [--edge-split]]
                                [--scaling] [--footprint] [--memory] [--bandwidth-spread]
                                [--repeats 3] [--set-pm KEY=VALUE ...] [--set-rs KEY=VALUE ...]
"""
import argparse
import collections
import datetime
import json
import math
import os
import random
import struct
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from caustics_report import read_exr_rgb  # noqa: E402
from prs_fg_report import (CROPS, WHOLE, crop_mean, indirect_reference, mean_and_error, paired_errors,  # noqa: E402
                           seed_settings)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE_DIR = os.path.join(ROOT, "data", "cornell-box")
REFERENCE = os.path.join(SCENE_DIR, "reference", "reference.exr")
PHASES = {
    "T_E": {"eye", "splat_index", "eye_index"},
    "T_L": {"photon", "ray_bandwidth", "photon_index"},
    "T_S": {"ray_splat", "cache_select", "radiance_cache", "radiance_integrate", "gather"},
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


def render(binary, job, out_dir, threads, photons, extra=(), peak=None):
    stats = os.path.join(out_dir, "stats.json")
    command = [binary, "render", job, "--out", out_dir, "--threads", str(threads), "--stats", stats] + list(extra)
    if photons:
        command += ["--set", f"passes.photon.photons={photons}"]
    if peak is not None:  # the peak resident set in kB, from GNU time
        command = ["/usr/bin/time", "-f", "%M", "-o", os.path.join(out_dir, "peak.txt")] + command
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    if peak is not None:
        with open(os.path.join(out_dir, "peak.txt")) as f:
            peak.append(int(f.read().split()[-1]))
    with open(stats) as f:
        passes = json.load(f)["passes"]
    output_bytes = {p["pass"]: p.get("output_bytes", 0) for p in passes}
    times = {phase: sum(p["cpu_seconds"] for p in passes if p["pass"] in names) for phase, names in PHASES.items()}
    counters = {}
    for p in passes:
        counters.update(p.get("counters", {}))
        if p["pass"] in ("fg_splat", "final_gather"):
            c = p["counters"]
            times["T_E"] += c["trace_cpu_us"] / 1e6
            times["T_S"] += c.get("splat_cpu_us", c.get("gather_cpu_us", 0)) / 1e6
    counters["output_bytes"] = output_bytes
    images = [name for name in os.listdir(out_dir) if name.endswith(".exr")]
    return times, counters, os.path.join(out_dir, images[0])


def error_classes(pixels, reference):
    """Shares of the pixels whose relative error against the reference (channel means) is below 5 %, below 15 %
    and 30 % or above (Fig. 10's classes); pixels the reference has black are left out."""
    errors = []
    for p, r in zip(pixels, reference):
        truth = sum(r) / 3.0
        if truth > 0.0:
            errors.append(abs(sum(p) / 3.0 - truth) / truth)
    n = max(1, len(errors))
    return (sum(e < 0.05 for e in errors) / n, sum(e < 0.15 for e in errors) / n, sum(e >= 0.30 for e in errors) / n)


def median(values):
    ordered = sorted(values)
    return ordered[len(ordered) // 2] if len(ordered) % 2 else 0.5 * (ordered[len(ordered) // 2 - 1] + ordered[len(ordered) // 2])


def buffer_columns(path):
    """The columns of a saved buffer (.fgbuf, engine/core/codec.h): name -> raw bytes. The columns are the
    file's last bytes, in the order its header lists them."""
    with open(path, "rb") as f:
        data = f.read()
    if data[:5] != b"FGBUF":
        raise SystemExit(f"{path}: not a buffer file")
    offset = 9  # magic, format version

    def take(fmt):
        nonlocal offset
        value = struct.unpack_from(fmt, data, offset)[0]
        offset += struct.calcsize(fmt)
        return value

    def string():
        nonlocal offset
        n = take("<I")
        offset += n
        return data[offset - n:offset].decode()

    string()  # type name
    header = [(string(), take("<I"), take("<Q")) for _ in range(take("<I"))]
    start = len(data) - sum(size * count for _, size, count in header)
    columns = {}
    for name, size, count in header:
        columns[name] = data[start:start + size * count]
        start += size * count
    return columns


def points(raw):
    return [struct.unpack_from("<3f", raw, 12 * i) for i in range(len(raw) // 12)]


def mean_gather_radius(eye_file, photon_file, k, sample=3000, among=None, radii_out=None):
    """Mean distance from an eye vertex to its k-th nearest global photon, over `sample` vertices (of `among`,
    if given), and the diagonal of the box around vertices and photons; the radii themselves are appended to
    `radii_out` if given."""
    photons = points(buffer_columns(photon_file)["photons.position"])
    vertices = points(buffer_columns(eye_file)["vertices.position"])
    lo = [min(p[a] for p in photons + vertices) for a in range(3)]
    hi = [max(p[a] for p in photons + vertices) for a in range(3)]
    diagonal = math.dist(lo, hi)
    cell = diagonal / 60
    grid = collections.defaultdict(list)
    for p in photons:
        grid[tuple(int((p[a] - lo[a]) // cell) for a in range(3))].append(p)
    radii = []
    candidates = vertices if among is None else among
    for v in random.Random(7).sample(candidates, min(sample, len(candidates))):
        c = tuple(int((v[a] - lo[a]) // cell) for a in range(3))
        ring = 0
        while True:  # grow the cube of cells until the k-th distance lies within it
            d2 = [(p[0] - v[0]) ** 2 + (p[1] - v[1]) ** 2 + (p[2] - v[2]) ** 2
                  for i in range(c[0] - ring, c[0] + ring + 1) for j in range(c[1] - ring, c[1] + ring + 1)
                  for l in range(c[2] - ring, c[2] + ring + 1) for p in grid.get((i, j, l), ())]
            if len(d2) >= k:
                r = math.sqrt(sorted(d2)[k - 1])
                if r <= ring * cell or len(d2) == len(photons):
                    break
            ring += 1
        radii.append(r)
    if radii_out is not None:
        radii_out.extend(radii)
    return sum(radii) / len(radii), diagonal


def crop_bandwidths(eye_file, photon_file, rays_file, k, sample=300):
    """Per corner crop: PM's mean k-nearest radius over (up to `sample` of) the crop's eye vertices, and RS's
    mean R(t_hit) over the indirect rays whose hit lies in the box of those vertices, both in millionths of
    the diagonal of the box around vertices and photons (as mean_gather_radius)."""
    eye = buffer_columns(eye_file)
    vertices = points(eye["vertices.position"])
    pixels = struct.unpack(f"<{len(eye['vertices.pixel']) // 4}I", eye["vertices.pixel"])
    rays = buffer_columns(rays_file)
    n = len(rays["rays.length"]) // 4
    origin, direction = points(rays["rays.origin"]), points(rays["rays.direction"])
    length, h0, dh = (struct.unpack(f"<{n}f", rays[f"rays.{c}"]) for c in ("length", "h0", "dh"))
    end_normal = points(rays["rays.end_normal"])
    hits = [(tuple(origin[i][a] + length[i] * direction[i][a] for a in range(3)), h0[i] + dh[i] * length[i])
            for i in range(n) if rays["rays.class"][i] != 0 and end_normal[i] != (0.0, 0.0, 0.0)]
    result = []
    for x0, y0, w, h in CROPS:
        inside = [v for v, p in zip(vertices, pixels) if x0 <= p % 128 < x0 + w and y0 <= p // 128 < y0 + h]
        lo = [min(v[a] for v in inside) for a in range(3)]
        hi = [max(v[a] for v in inside) for a in range(3)]
        radius, diagonal = mean_gather_radius(eye_file, photon_file, k, sample, inside)
        splat = [r for p, r in hits if all(lo[a] <= p[a] <= hi[a] for a in range(3))]
        result.append((round(1e6 * radius / diagonal), round(1e6 * sum(splat) / max(1, len(splat)) / diagonal)))
    return result


EDGE_BANDS = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0))


def quantile(values, q):
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def effective_samples(eye_file, photon_file, rays_file, ppm, sample=1000, k=100):
    """Per eye vertex (`sample` of them, drawn as mean_gather_radius draws), how many samples its estimate
    effectively averages, (sum w)^2 / sum w^2 of the kernel weights: PM's k nearest photons under Silverman's
    kernel (1 - d^2/r^2)^2 at the k-th distance r; RS's indirect rays whose hit lies within R(t_hit) of the
    vertex, weighed (1 - d^2/R^2) / R^2 (the Epanechnikov kernel of a sphere around the hit, not the frustum's;
    powers and BRDFs left out). Also the kernel-weighted mean R of those rays (the radius a vertex sees), and RS's
    mean taken as PM's is: the mean R(t_hit) of the vertex's k nearest hits, averaged over the vertices and over
    the pixels they lie in (each pixel's vertices averaged first), beside PM's k-nearest radius averaged alike."""
    import numpy as np
    eye = buffer_columns(eye_file)
    vertices = np.frombuffer(eye["vertices.position"], dtype="<f4").reshape(-1, 3).astype(np.float64)
    pixel = np.frombuffer(eye["vertices.pixel"], dtype="<u4")
    photons = np.frombuffer(buffer_columns(photon_file)["photons.position"], dtype="<f4").reshape(-1, 3).astype(np.float64)
    rays = buffer_columns(rays_file)
    column = lambda name: np.frombuffer(rays[f"rays.{name}"], dtype="<f4")  # noqa: E731
    origin, direction = column("origin").reshape(-1, 3), column("direction").reshape(-1, 3)
    length, h0, dh = column("length"), column("h0"), column("dh")
    hit = (np.frombuffer(rays["rays.class"], dtype="u1") != 0) & np.any(column("end_normal").reshape(-1, 3) != 0, axis=1)
    hits = (origin[hit] + length[hit, None] * direction[hit]).astype(np.float64)
    radius = (h0[hit] + dh[hit] * length[hit]).astype(np.float64)
    chosen = random.Random(7).sample(range(len(vertices)), min(sample, len(vertices)))
    pm, rs, seen, pm_radius, rs_nearest = [], [], [], [], []
    for v in vertices[chosen]:
        d2 = np.sort(np.partition(((photons - v) ** 2).sum(axis=1), k - 1)[:k])
        w = (1.0 - d2[:-1] / d2[-1]) ** 2
        pm.append(w.sum() ** 2 / (w ** 2).sum())
        pm_radius.append(np.sqrt(d2[-1]))
        d2 = ((hits - v) ** 2).sum(axis=1)
        rs_nearest.append(radius[np.argpartition(d2, k - 1)[:k]].mean())
        inside = d2 < radius ** 2
        if inside.any():
            r = radius[inside]
            w = (1.0 - d2[inside] / r ** 2) / r ** 2
            rs.append(w.sum() ** 2 / (w ** 2).sum())
            seen.append((w * r).sum() / w.sum())
    print(f"Effective samples per eye vertex ({len(chosen)} vertices; medians): PM {np.median(pm):.1f},"
          f" RS {np.median(rs):.1f} ({len(rs)} vertices with rays); the kernel-weighted mean R of the rays at a"
          f" vertex, averaged over the vertices: {np.mean(seen) * ppm:.0f} ppm.")

    def over_pixels(values):
        by_pixel = {}
        for p, value in zip(pixel[chosen], values):
            by_pixel.setdefault(int(p), []).append(value)
        return np.mean([np.mean(v) for v in by_pixel.values()]), len(by_pixel)

    (pm_pixels, count), (rs_pixels, _) = over_pixels(pm_radius), over_pixels(rs_nearest)
    print(f"Mean bandwidth over the same vertices: PM's k-nearest radius {np.mean(pm_radius) * ppm:.0f} ppm, RS's"
          f" mean R(t_hit) of the {k} nearest hits {np.mean(rs_nearest) * ppm:.0f}; over the {count} pixels they lie"
          f" in: PM {pm_pixels * ppm:.0f}, RS {rs_pixels * ppm:.0f}.\n")


def bandwidth_spread(args, reference, scratch, spm_job):
    """How PM's and RS's bandwidths are spread, not only their means (§9 matches C by the mean): PM's k-nearest
    radius over the 3000 eye vertices of mean_gather_radius, RS's R(t_hit) over the indirect rays that meet a
    surface (ray_splat's mean_hit_radius_ppm is their mean), in millionths of the same diagonal; the share of
    those rays at the clamps R h and h / R of Eq. 8; and the C that would match PM's mean, geometric mean and
    median (every R is proportional to C). Then Fig. 10's classes on the indirect light alone (the figure's
    quantity; eye pass direct_light = false against the reference less one-bounce pt), the job's eye samples."""

    pm_dir, rs_dir = os.path.join(scratch, "spread-pm"), os.path.join(scratch, "spread-rs")
    os.makedirs(pm_dir)
    os.makedirs(rs_dir)
    rs_set = [a for setting in args.set_rs for a in ("--set", setting)]
    render(args.binary, spm_job, pm_dir, args.threads, args.photons,
           ["--save", f"eye_vertices={pm_dir}/eye.fgbuf", "--save", f"global_photons={pm_dir}/global.fgbuf"])
    _, counters, _ = render(args.binary, os.path.join(SCENE_DIR, "prs.toml"), rs_dir, args.threads, args.photons,
                            ["--save", f"splat_rays={rs_dir}/rays.fgbuf"] + rs_set)
    pm = []
    _, diagonal = mean_gather_radius(f"{pm_dir}/eye.fgbuf", f"{pm_dir}/global.fgbuf", 100, radii_out=pm)
    rays = buffer_columns(f"{rs_dir}/rays.fgbuf")
    n = len(rays["rays.length"]) // 4
    length, h0, dh = (struct.unpack(f"<{n}f", rays[f"rays.{c}"]) for c in ("length", "h0", "dh"))
    end_normal = points(rays["rays.end_normal"])
    rs = [h0[i] + dh[i] * length[i] for i in range(n)
          if rays["rays.class"][i] != 0 and end_normal[i] != (0.0, 0.0, 0.0)]
    ppm = 1e6 / diagonal
    lo, hi = min(rs), max(rs)
    smoothness = next((float(a.split("=")[1]) for a in args.set_rs if a.startswith("passes.ray_bandwidth.smoothness=")),
                      None)
    c = f"C = {smoothness:g}" if smoothness else "the job's C"
    geometric = [math.exp(sum(math.log(r) for r in v) / len(v)) for v in (pm, rs)]
    print(f"Bandwidths in ppm of the diagonal (RS: {c}, {len(rs)} indirect rays that meet a surface; PM: k = 100,"
          f" {len(pm)} eye vertices): {100 * sum(r <= lo * 1.0001 for r in rs) / len(rs):.1f} % of RS's rays at the"
          f" lower clamp ({lo * ppm:.0f}), {100 * sum(r >= hi * 0.9999 for r in rs) / len(rs):.1f} % at the upper"
          f" ({hi * ppm:.0f}); R_hit of the mean_hit_radius_ppm counter {counters['mean_hit_radius_ppm']}.\n")
    print("| | mean | geometric mean | 10 % | 25 % | median | 75 % | 90 % |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for label, v, g in (("PM, k-nearest radius", pm, geometric[0]), ("RS, R(t_hit)", rs, geometric[1])):
        print(f"| {label} | {sum(v) / len(v) * ppm:.0f} | {g * ppm:.0f} | "
              + " | ".join(f"{quantile(v, q) * ppm:.0f}" for q in (0.1, 0.25, 0.5, 0.75, 0.9)) + " |")
    base = smoothness or 0.29
    print(f"\nC matching PM's (from C = {base:g}): mean {base * (sum(pm) / len(pm)) / (sum(rs) / len(rs)):.3f},"
          f" geometric mean {base * geometric[0] / geometric[1]:.3f}, median"
          f" {base * quantile(pm, 0.5) / quantile(rs, 0.5):.3f}\n")
    effective_samples(f"{pm_dir}/eye.fgbuf", f"{pm_dir}/global.fgbuf", f"{rs_dir}/rays.fgbuf", ppm)
    from pathlib import Path
    target = indirect_reference(args.binary, Path(scratch), reference, args.direct_spp)
    for label, job, extra in (("PM (spm, k = 100)", spm_job, []), (f"RS (prs, {c})", os.path.join(SCENE_DIR, "prs.toml"), rs_set)):
        out_dir = os.path.join(scratch, "spread-indirect-" + label[:2])
        os.makedirs(out_dir)
        _, _, image = render(args.binary, job, out_dir, args.threads, args.photons,
                             ["--set", "passes.eye.direct_light=false"] + extra)
        classes = error_classes(read_exr_rgb(image), target)
        print(f"{label}, indirect light: < 5 % {100 * classes[0]:.1f} %, < 15 % {100 * classes[1]:.1f} %,"
              f" ≥ 30 % {100 * classes[2]:.1f} %")


def scene_triangles():
    """The Cornell box's surfaces as triangles (a fan over each OBJ face), in world space: the shapes of
    fragments/shapes.xml with their translations (only the luminaire moves)."""
    import re
    import numpy as np
    with open(os.path.join(SCENE_DIR, "fragments", "shapes.xml")) as f:
        shapes = re.findall(r'value="(meshes/[^"]+)"/>\s*(?:<transform name="to_world">\s*<translate'
                            r' x="([^"]+)" y="([^"]+)" z="([^"]+)"/>)?', f.read())
    triangles = []
    for name, *shift in shapes:
        offset = [float(s) if s else 0.0 for s in shift]
        with open(os.path.join(SCENE_DIR, name)) as f:
            lines = [line.split() for line in f]
        vertices = [[float(v) + o for v, o in zip(line[1:4], offset)] for line in lines if line and line[0] == "v"]
        for line in lines:
            if line and line[0] == "f":
                corners = [vertices[int(c.split("/")[0]) - 1] for c in line[1:]]
                triangles += [(corners[0], corners[k], corners[k + 1]) for k in range(1, len(corners) - 1)]
    return np.array(triangles, dtype=np.float64)


def point_triangle_distance(p, a, b, c):
    """Distance from each point of p (N x 3) to the triangle abc: to its plane where the projection falls
    inside, else to the nearest of its edges."""
    import numpy as np
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n)
    height = (p - a) @ n
    q = p - np.outer(height, n)
    inside = np.ones(len(p), dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= (np.cross(v - u, q - u) @ n) >= 0.0
    best = np.where(inside, np.abs(height), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        t = np.clip(((p - u) @ e) / (e @ e), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - (u + np.outer(t, e)), axis=1))
    return best


def edge_distances(eye_file, width=128):
    """Per pixel, the distance from its nearest eye vertex to another surface that rises in front of the
    vertex's own (a concave edge: the adjacent wall, a box on the floor) and to one that falls away behind it
    (a convex edge: a box's top and sides). Surfaces parallel to the vertex's (its own wall, the luminaire
    0.5 below the ceiling) are no edge."""
    import numpy as np
    eye = buffer_columns(eye_file)
    x = np.frombuffer(eye["vertices.position"], dtype="<f4").reshape(-1, 3).astype(np.float64)
    n = np.frombuffer(eye["vertices.ng"], dtype="<f4").reshape(-1, 3).astype(np.float64)
    pixel = np.frombuffer(eye["vertices.pixel"], dtype="<u4")
    concave = np.full(len(x), np.inf)
    convex = np.full(len(x), np.inf)
    for a, b, c in scene_triangles():
        normal = np.cross(b - a, c - a)
        normal /= np.linalg.norm(normal)
        crossing = np.abs(n @ normal) < 0.99
        rises = np.max(np.stack([(corner - x) * n for corner in (a, b, c)]).sum(axis=2), axis=0) > 1e-2
        d = point_triangle_distance(x, a, b, c)
        concave = np.where(crossing & rises, np.minimum(concave, d), concave)
        convex = np.where(crossing & ~rises, np.minimum(convex, d), convex)
    per_pixel = np.full((2, width * width), np.inf)
    np.minimum.at(per_pixel[0], pixel, concave)
    np.minimum.at(per_pixel[1], pixel, convex)
    return per_pixel


def edge_bands(distances, radius):
    """Pixel index lists: within EDGE_BANDS (in units of `radius`) of a concave edge, then those 4 R or more from
    any concave edge but within 4 R of a convex one, then the rest (the interior)."""
    concave, convex = distances[0] / radius, distances[1] / radius
    bands = [[i for i in range(len(concave)) if lo <= concave[i] < hi] for lo, hi in EDGE_BANDS]
    far = [i for i in range(len(concave)) if concave[i] >= EDGE_BANDS[-1][1]]
    bands.append([i for i in far if convex[i] < EDGE_BANDS[-1][1]])
    bands.append([i for i in far if convex[i] >= EDGE_BANDS[-1][1]])
    return bands


def band_errors(pixels, target, band, whole):
    """A band's signed error in % of its own indirect light and in % of the whole image's (the bands' shares
    add up to the whole image's error)."""
    diff = sum(sum(pixels[i]) - sum(target[i]) for i in band) / 3.0
    own = sum(sum(target[i]) for i in band) / 3.0
    return 100.0 * diff / own, 100.0 * diff / whole


def bounce_reference(binary, work, depth, spp):
    """The light of paths with 2 to `depth` scattering events: pt with max_depth = depth less pt with
    max_depth = 1, both of `spp` samples (the photon pass with max_depth = depth stores photons up to that
    event, and the eye pass adds the first)."""
    images = []
    for d in (depth, 1):
        out = work / f"pt-depth-{d}"
        subprocess.run([binary, "render", os.path.join(SCENE_DIR, "pt.toml"), "-q", "--out", str(out),
                        "--set", f"passes.pt.max_depth={d}", "--set", f"passes.pt.spp={spp}"], check=True)
        images.append(read_exr_rgb(next(out.glob("*.exr"))))
    return [tuple(a - b for a, b in zip(p, q)) for p, q in zip(*images)]


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
    parser.add_argument("--seeds", type=int, nargs="*", default=[],
                        help="photon seeds for the corner-crop error of PM and RS (e.g. 11 12 13 14)")
    parser.add_argument("--indirect", action="store_true", help="corner crops of the indirect light alone")
    parser.add_argument("--fixed-eye", action="store_true",
                        help="keep the job's eye samples for every seed (only the photon paths change)")
    parser.add_argument("--corners-only", action="store_true",
                        help="render only the corner seeds of PM and RS and print their table (writes nothing)")
    parser.add_argument("--direct-spp", type=int, default=1024, help="samples of --indirect's one-bounce pt image")
    parser.add_argument("--photon-depth", type=int, default=0,
                        help="with --indirect: photon paths cut at this many scattering events (passes.photon."
                             "max_depth), against pt of that max_depth less one-bounce pt")
    parser.add_argument("--edge-split", action="store_true",
                        help="with --seeds: the error split by the eye vertices' distance to the box's edges")
    parser.add_argument("--crop-bandwidth", action="store_true",
                        help="PM's and RS's mean bandwidth in the corner crops (from the saved buffers)")
    parser.add_argument("--bandwidth-spread", action="store_true",
                        help="PM's and RS's bandwidths spread, and Fig. 10's classes of the indirect light (prints only)")
    parser.add_argument("--scaling", action="store_true", help="PM's and RS's T_S at 1, 2 and 4 times the photons")
    parser.add_argument("--footprint", action="store_true", help="RS's T_S with the frustum against the sphere")
    parser.add_argument("--memory", action="store_true", help="memory of RS at 500 x 500 with 500k photons")
    parser.add_argument("--repeats", type=int, default=3, help="alternating runs of --footprint")
    parser.add_argument("--set-pm", nargs="*", default=[], help="extra --set for the PM row (e.g. passes.gather.k_global=25)")
    parser.add_argument("--set-rs", nargs="*", default=[],
                        help="extra --set for the RS row (e.g. passes.ray_bandwidth.smoothness=1.0)")
    args = parser.parse_args()
    reference = read_exr_rgb(REFERENCE)
    # The corner crops, then the whole image for comparison.
    corner_crops = list(CROPS) + [WHOLE]
    ref_means = [crop_mean(reference, 128, c) for c in corner_crops]

    def rs_settings(label):
        chosen = args.set_rs if label.startswith("RS ") else args.set_pm if label.startswith("PM ") else []
        return [a for setting in chosen for a in ("--set", setting)]

    os.makedirs(args.out, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        spm_job = os.path.join(scratch, "spm.toml")
        with open(spm_job, "w") as f:
            f.write(SPM_JOB.format(scene=os.path.join(SCENE_DIR, "cornell-box.xml")))
        if args.bandwidth_spread:
            bandwidth_spread(args, reference, scratch, spm_job)
            return
        methods = [
            ("PM (spm, " + (", ".join(args.set_pm) or "k = 100") + ")", spm_job),
            ("RS (prs, " + (", ".join(args.set_rs) or "C = 0.29, S = 0.4") + ")", os.path.join(SCENE_DIR, "prs.toml")),
            ("RC (prs-rc, C = 0.29, S = 0.4, ε = 0.7, 7 records)", os.path.join(SCENE_DIR, "prs-rc.toml")),
            ("PM-FG (pm-fg, k = 100, 16 FGRs)", os.path.join(SCENE_DIR, "pm-fg.toml")),
            ("RS-FG (prs-fg, C = 0.6, S = 0.8, 16 FGRs, 1 tile)", os.path.join(SCENE_DIR, "prs-fg.toml")),
        ]
        for label, job in methods if not args.corners_only else ():
            out_dir = os.path.join(scratch, str(len(rows)))
            os.makedirs(out_dir)
            print(f"rendering {label} ...", file=sys.stderr)
            # --photons applies to the direct-visualisation rows; the FG jobs keep their own count.
            photons = 0 if "FG" in label else args.photons
            saves = []
            if label.startswith("PM "):
                saves = ["--save", f"eye_vertices={out_dir}/eye.fgbuf", "--save", f"global_photons={out_dir}/global.fgbuf"]
                pm_buffers = (f"{out_dir}/eye.fgbuf", f"{out_dir}/global.fgbuf")
            if label.startswith("RS ") and args.crop_bandwidth:
                saves = ["--save", f"splat_rays={out_dir}/rays.fgbuf"]
            times, counters, image = render(args.binary, job, out_dir, args.threads, photons, saves + rs_settings(label))
            if label.startswith("PM "):
                radius, diagonal = mean_gather_radius(f"{out_dir}/eye.fgbuf", f"{out_dir}/global.fgbuf", 100)
                counters["mean_gather_radius_ppm"] = round(1e6 * radius / diagonal)
            if label.startswith("RS ") and args.crop_bandwidth:
                counters["crop_bandwidths"] = crop_bandwidths(*pm_buffers, f"{out_dir}/rays.fgbuf", 100)
            rmse, relmse = compare(args.binary, image)
            counters["error_classes"] = error_classes(read_exr_rgb(image), reference)
            rows.append((label, times, counters, rmse, relmse))

        corners = {}
        corner_settings = []
        if args.seeds and args.indirect:
            from pathlib import Path
            if args.photon_depth:
                target = bounce_reference(args.binary, Path(scratch), args.photon_depth, args.direct_spp)
            else:
                target = indirect_reference(args.binary, Path(scratch), reference, args.direct_spp)
            target_pixels = target
            ref_means = [crop_mean(target, 128, c) for c in corner_crops]
            corner_settings = ["--set", "passes.eye.direct_light=false"]
            if args.photon_depth:
                corner_settings += ["--set", f"passes.photon.max_depth={args.photon_depth}"]
        per_seed = {}
        seed_images, seed_distances, hit_radii = {}, [], []
        for label, job in methods[:2] if args.seeds else ():
            errors = [[] for _ in corner_crops]
            for seed in args.seeds:
                out_dir = os.path.join(scratch, f"seed-{len(rows)}-{seed}-{len(corners)}")
                os.makedirs(out_dir)
                print(f"rendering {label}, seed {seed} ...", file=sys.stderr)
                saves = []
                if args.edge_split and label.startswith("PM "):
                    saves = ["--save", f"eye_vertices={out_dir}/eye.fgbuf"]
                _, seed_counters, image = render(args.binary, job, out_dir, args.threads, args.photons,
                                                 seed_settings(seed, args.fixed_eye) + corner_settings
                                                 + rs_settings(label) + saves)
                pixels = read_exr_rgb(image)
                if args.edge_split:
                    seed_images.setdefault(label, []).append(pixels)
                    if saves:
                        seed_distances.append(edge_distances(f"{out_dir}/eye.fgbuf"))
                    if label.startswith("RS "):
                        hit_radii.append(seed_counters["mean_hit_radius_ppm"])
                for i, crop in enumerate(corner_crops):
                    errors[i].append(100.0 * (crop_mean(pixels, 128, crop) - ref_means[i]) / ref_means[i])
            corners[label] = [mean_and_error(e) for e in errors]
            per_seed[label] = errors
        if len(per_seed) == 2:
            pm, rs = per_seed.values()
            corners["RS - PM, seed by seed"] = paired_errors(rs, pm)

        edge_rows, edge_shares = {}, []
        if args.edge_split and seed_images:
            import numpy as np
            triangles = scene_triangles().reshape(-1, 3)
            diagonal = float(np.linalg.norm(triangles.max(axis=0) - triangles.min(axis=0)))
            radius = 1e-6 * sum(hit_radii) / len(hit_radii) * diagonal
            target = [sum(p) / 3.0 for p in (target_pixels if args.indirect else reference)]
            target = [(t, t, t) for t in target]
            whole = sum(t[0] for t in target)
            by_label = {}
            for label, images in seed_images.items():
                cells = []  # per band: (own errors, contributions) over the seeds
                for pixels, distances in zip(images, seed_distances):
                    bands = edge_bands(distances, radius)
                    if label == next(iter(seed_images)):
                        edge_shares.append([(len(b) / len(target), sum(target[i][0] for i in b) / whole)
                                            for b in bands])
                    cells.append([band_errors(pixels, target, b, whole) for b in bands] + [band_errors(pixels, target, range(len(target)), whole)])
                by_label[label] = cells
            for label, cells in by_label.items():
                edge_rows[label] = [(mean_and_error([c[b][0] for c in cells]), mean_and_error([c[b][1] for c in cells]))
                                    for b in range(len(cells[0]))]
            if len(by_label) == 2:
                pm, rs = by_label.values()
                edge_rows["RS - PM, seed by seed"] = [
                    (mean_and_error([r[b][0] - p[b][0] for r, p in zip(rs, pm)]),
                     mean_and_error([r[b][1] - p[b][1] for r, p in zip(rs, pm)])) for b in range(len(pm[0]))]
            edge_radius = radius

        scaling = {}
        base_photons = args.photons or 200000
        for label, job in methods[:2] if args.scaling else ():
            for factor in (1, 2, 4):
                out_dir = os.path.join(scratch, f"scale-{len(scaling)}-{factor}")
                os.makedirs(out_dir)
                print(f"rendering {label} with {factor * base_photons} photons ...", file=sys.stderr)
                times, counters, _ = render(args.binary, job, out_dir, args.threads, factor * base_photons,
                                            rs_settings(label))
                scaling.setdefault(label, []).append((factor * base_photons, times["T_S"], counters))

        footprints = {}
        for run in range(args.repeats if args.footprint else 0):
            for footprint in ("frustum", "sphere"):
                out_dir = os.path.join(scratch, f"footprint-{footprint}-{run}")
                os.makedirs(out_dir)
                print(f"rendering RS with the {footprint} footprint, run {run + 1} ...", file=sys.stderr)
                _, counters, _ = render(args.binary, methods[1][1], out_dir, args.threads, args.photons,
                                        ["--set", f"passes.ray_splat.footprint={footprint}"] + rs_settings("RS "))
                with open(os.path.join(out_dir, "stats.json")) as f:
                    splat = [p for p in json.load(f)["passes"] if p["pass"] == "ray_splat"][0]
                footprints.setdefault(footprint, []).append((splat["cpu_seconds"], counters))

        memory = []
        for paths in (500000, 136000) if args.memory else ():
            out_dir = os.path.join(scratch, f"memory-{paths}")
            os.makedirs(out_dir)
            print(f"rendering RS at 500 x 500 x 1 with {paths} photon paths ...", file=sys.stderr)
            peak = []
            _, counters, _ = render(args.binary, methods[1][1], out_dir, args.threads, paths,
                                    ["--set", "film.width=500", "--set", "film.height=500", "--set",
                                     "passes.eye.spp=1"] + rs_settings("RS "), peak=peak)
            memory.append((paths, counters, peak[0]))

    edge_lines = []
    if edge_rows:
        shares = [[sum(s[b][k] for s in edge_shares) / len(edge_shares) for k in (0, 1)]
                  for b in range(len(edge_shares[0]))]
        names = [f"concave edge {lo:g}–{hi:g} R" for lo, hi in EDGE_BANDS] + ["convex edge < 4 R", "interior", "whole image"]
        edge_lines = [
            f"Error by distance to the box's edges (R = {edge_radius:.2f}, the mean splat radius at the hits;"
            f" a pixel's distance is its nearest eye vertex's, per seed), over seeds {args.seeds}: the band's mean"
            " signed error in % of its own reference light, then its share of the whole image's error"
            " (the shares add up to the last column), ± standard errors. Pixels / light of the band:"
            + "; ".join(f" {n} {100 * a:.1f} % / {100 * b:.1f} %" for n, (a, b) in zip(names, shares)) + ".", "",
            "| Method | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
        for label, cells in edge_rows.items():
            edge_lines.append(f"| {label} | " + " | ".join(f"{m:+.2f} ± {e:.2f} ({c:+.2f} ± {ce:.2f})"
                                                          for (m, e), (c, ce) in cells) + " |")
        edge_lines.append("")

    if args.corners_only:
        print("\n".join(edge_lines))
        what = "of the indirect light against the reference less one-bounce pt" if args.indirect else ""
        eye = "the job's eye samples" if args.fixed_eye else "each seed's own eye samples"
        print(f"Corner crops, mean signed error {what} over seeds {args.seeds} ({eye}):\n")
        print("| Method | " + " | ".join(f"crop {','.join(map(str, c))}" for c in corner_crops) + " |")
        print("|---|" + "---:|" * len(corner_crops))
        for label, cells in corners.items():
            print(f"| {label} | " + " | ".join(f"{m:+.2f} % ± {e:.2f}" for m, e in cells) + " |")
        return

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
        "| Method | T_E | T_L | T_S | ΣT | RMSE | relMSE | < 5 % | < 15 % | ≥ 30 % |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, times, counters, rmse, relmse in rows:
        total = sum(times.values())
        classes = " | ".join(f"{100 * share:.1f} %" for share in counters["error_classes"])
        lines.append(
            f"| {label} | {times['T_E']:.2f} | {times['T_L']:.2f} | {times['T_S']:.2f} | {total:.2f} | {rmse:.4f} |"
            f" {relmse:.4f} | {classes} |"
        )
    pm_counters, rs_counters = rows[0][2], rows[1][2]
    pm_radius, rs_radius = pm_counters["mean_gather_radius_ppm"], rs_counters["mean_hit_radius_ppm"]
    rs_rays = max(1, rs_counters["splatted_rays"])
    lines += [
        "",
        f"RS's T_S is {rows[1][1]['T_S'] / rows[0][1]['T_S']:.2f} × PM's (the paper: 0.54–1.00). Mean bandwidth"
        f" (millionths of the scene diagonal): PM's k-nearest radius {pm_radius}, RS's R at the hits {rs_radius}"
        f" ({rs_radius / pm_radius:.2f} × PM's). RS made {rs_counters['vertex_deposits'] / rs_rays:.0f} deposits per"
        f" splatted ray ({rs_counters['vertex_deposits']} in all) from {rs_counters['vertex_candidates']} candidates"
        f" ({rs_counters['leaf_vertices']} leaf vertices tested against the cones); PM used"
        f" {pm_counters.get('photon_contributions', 0)} photons.",
    ]
    if "crop_bandwidths" in rs_counters:
        lines += ["", "Mean bandwidth in the corner crops (ppm of the diagonal; PM: k-nearest radius at the crop's eye"
                  " vertices, RS: R at the hits of the rays ending in the box of those vertices): "
                  + "; ".join(f"crop {','.join(map(str, c))}: PM {pm}, RS {rs} ({rs / pm:.2f} ×)"
                              for c, (pm, rs) in zip(CROPS, rs_counters["crop_bandwidths"])) + "."]
    if corners:
        what = "of the indirect light against the reference less one-bounce pt" if args.indirect else ""
        eye = "the job's eye samples" if args.fixed_eye else "each seed's own eye samples"
        lines += ["", f"Corner crops, mean signed error {what} over seeds {args.seeds} ({eye}):", "",
                  "| Method | " + " | ".join(f"crop {','.join(map(str, c))}" for c in corner_crops) + " |",
                  "|---|" + "---:|" * len(corner_crops)]
        for label, cells in corners.items():
            lines.append(f"| {label} | " + " | ".join(f"{m:+.1f} % ± {e:.1f}" for m, e in cells) + " |")
    if edge_lines:
        lines += [""] + edge_lines
    if scaling:
        lines += ["", "T_S (CPU s) against the emitted photon paths:", "",
                  "| Method | " + " | ".join(f"{m // 1000}k" for m, _, _ in next(iter(scaling.values()))) + " |",
                  "|---|" + "---:|" * 3]
        for label, runs in scaling.items():
            lines.append(f"| {label} | " + " | ".join(f"{t:.2f}" for _, t, _ in runs) + " |")
    if footprints:
        frustum = [t for t, _ in footprints["frustum"]]
        sphere = [t for t, _ in footprints["sphere"]]
        sphere_counters = footprints["sphere"][0][1]
        lines += ["", f"ray_splat's CPU seconds, {args.repeats} alternating runs: frustum "
                  + ", ".join(f"{t:.2f}" for t in frustum) + f" (median {median(frustum):.2f}), sphere "
                  + ", ".join(f"{t:.2f}" for t in sphere) + f" (median {median(sphere):.2f}): the frustum takes"
                  f" {median(frustum) / median(sphere):.2f} × the sphere's time (the paper: 1.5–2). The sphere made"
                  f" {sphere_counters['vertex_deposits']} deposits from {sphere_counters['leaf_vertices']} leaf"
                  f" vertices, the frustum {footprints['frustum'][0][1]['vertex_deposits']} from"
                  f" {footprints['frustum'][0][1]['leaf_vertices']}."]
    for paths, counters, peak in memory:
        b = counters["output_bytes"]
        rays, index, film = b.get("ray_bandwidth", 0), b.get("splat_index", 0), b.get("ray_splat", 0)
        lines += ["", f"Memory at 500 × 500 × 1, {paths} photon paths ({counters['global_rays'] + counters['caustic_rays']}"
                  f" indirect and {counters['direct_rays']} direct rays stored): photon rays {rays / 1e6:.1f} MB, splat"
                  f" index {index / 1e6:.1f} MB, radiance film and map {film / 1e6:.1f} MB, together"
                  f" {(rays + index + film) / 1e6:.1f} MB (the paper: 100–160 MB at 500k photons); peak RSS"
                  f" {peak / 1e3:.0f} MB."]
    rc_counters = rows[2][2]
    lines += [
        "",
        f"RC's T_S is {rows[2][1]['T_S'] / rows[1][1]['T_S']:.2f} × RS's (the paper: 11.9 / 58.3 = 0.20 on its"
        f" Cornell box I). RC placed {rc_counters.get('cache_records', 0)} records before splatting ("
        + ", ".join(str(rc_counters[f"records_pass_{p}"]) for p in range(1, 13) if f"records_pass_{p}" in rc_counters)
        + f" per pass); {rc_counters.get('undercovered_pixels', 0)} pixels"
        f" were covered by fewer than min_records, {rc_counters.get('uncached_vertices', 0)} vertices by none"
        f" (splatted directly); the rays made {rc_counters.get('vertex_deposits', 0)} deposits.",
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
