#!/usr/bin/env python3
"""Procedural meshes of the caustic test scenes in data/ (standard library only).

Writes Wavefront OBJ files with per-vertex normals ("v", "vn", "f a//a ..."),
which both the TOML and the Mitsuba XML scene loaders read, so the same mesh
serves both scene files. The output is deterministic: rerunning a command
reproduces the committed file byte for byte.

    tools/make_geometry.py wave  OUT.obj [--size S] [--grid N] [--height H] [--waves A,LAMBDA,DEG,PHASE ...]
    tools/make_geometry.py ring  OUT.obj [--inner R] [--outer R] [--height H] [--segments N]
                                 [--start DEG] [--sweep DEG]
    tools/make_geometry.py all [--root DIR]   (regenerates every mesh used by data/)

Conventions: y is up. A wave is a height field y = H + sum_i a_i sin(k_i (d_i . (x, z)) + phase_i)
over the square [-S/2, S/2]^2 with k_i = 2 pi / lambda_i and d_i the unit vector
at angle DEG from +x towards +z; its normals (analytic, per vertex) point up,
so with Mitsuba's convention the interior of a dielectric wave is below it.
A ring is a band around the y axis standing on y = 0: the inner and outer
cylinder walls carry smooth radial normals, the top and bottom rims (and the
end caps of a ring swept less than 360 degrees) are flat and do not share
vertices with the walls, so their edges stay sharp. Every face normal points
out of the metal.
"""

import argparse
import math
import os
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class Mesh:
    def __init__(self):
        self.positions = []
        self.normals = []
        self.triangles = []

    def vertex(self, p, n):
        length = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        self.positions.append(p)
        self.normals.append((n[0] / length, n[1] / length, n[2] / length))
        return len(self.positions) - 1

    def quad(self, a, b, c, d):
        """Two triangles a-b-c, a-c-d; counter-clockwise seen from the front."""
        self.triangles.append((a, b, c))
        self.triangles.append((a, c, d))

    def check_orientation(self):
        """Every triangle's winding must agree with its vertex normals."""
        for tri in self.triangles:
            p0, p1, p2 = (self.positions[i] for i in tri)
            e1 = [p1[k] - p0[k] for k in range(3)]
            e2 = [p2[k] - p0[k] for k in range(3)]
            ng = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
            ns = [sum(self.normals[i][k] for i in tri) for k in range(3)]
            if sum(ng[k] * ns[k] for k in range(3)) <= 0.0:
                raise SystemExit("internal error: a triangle's winding disagrees with its normals")


def fmt(x):
    text = "%.5g" % x
    return "0" if text == "-0" else text


def write_obj(mesh, path, header):
    mesh.check_orientation()
    lines = ["# " + line for line in header]
    lines += ["v %s %s %s" % tuple(fmt(c) for c in p) for p in mesh.positions]
    lines += ["vn %s %s %s" % tuple(fmt(c) for c in n) for n in mesh.normals]
    lines += ["f %d//%d %d//%d %d//%d" % (a + 1, a + 1, b + 1, b + 1, c + 1, c + 1) for a, b, c in mesh.triangles]
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w", newline="\n") as out:
        out.write("\n".join(lines) + "\n")
    size = os.path.getsize(path)
    print("%s: %d vertices, %d triangles, %d bytes" % (os.path.relpath(path), len(mesh.positions), len(mesh.triangles), size))


def make_wave(size, grid, height, waves):
    """Height field y = height + sum a sin(k d.(x,z) + phase) on a grid x grid lattice."""
    mesh = Mesh()
    components = []
    for amplitude, wavelength, degrees, phase in waves:
        angle = math.radians(degrees)
        k = 2.0 * math.pi / wavelength
        components.append((amplitude, k * math.cos(angle), k * math.sin(angle), phase))
    for j in range(grid + 1):
        z = -0.5 * size + size * j / grid
        for i in range(grid + 1):
            x = -0.5 * size + size * i / grid
            y, dydx, dydz = height, 0.0, 0.0
            for a, kx, kz, phase in components:
                y += a * math.sin(kx * x + kz * z + phase)
                c = a * math.cos(kx * x + kz * z + phase)
                dydx += c * kx
                dydz += c * kz
            mesh.vertex((x, y, z), (-dydx, 1.0, -dydz))
    row = grid + 1
    for j in range(grid):
        for i in range(grid):
            a = j * row + i
            # Seen from above (+y) with x right and z down the page, a -> a+row -> a+row+1 is counter-clockwise.
            mesh.quad(a, a + row, a + row + 1, a + 1)
    return mesh


def make_ring(inner, outer, height, segments, start_deg, sweep_deg):
    """A band between radii inner and outer, 0 <= y <= height, over the given angular sweep."""
    if not (0.0 < inner < outer) or height <= 0.0 or segments < 3 or not (0.0 < sweep_deg <= 360.0):
        raise SystemExit("ring: need 0 < inner < outer, height > 0, segments >= 3, 0 < sweep <= 360")
    mesh = Mesh()
    closed = sweep_deg >= 360.0
    count = segments if closed else segments + 1
    angles = [math.radians(start_deg + sweep_deg * s / segments) for s in range(count)]

    def point(r, phi, y):
        # phi increases from +x towards -z: counter-clockwise seen from above.
        return (r * math.cos(phi), y, -r * math.sin(phi))

    def strip(first_ring, second_ring, reverse):
        for s in range(segments):
            t = (s + 1) % count
            a, b, c, d = first_ring[s], first_ring[t], second_ring[t], second_ring[s]
            if reverse:
                mesh.quad(a, d, c, b)
            else:
                mesh.quad(a, b, c, d)

    # Walls: radial normals, outwards on the outer wall and towards the axis on the inner one.
    for radius, sign in ((outer, 1.0), (inner, -1.0)):
        bottom = [mesh.vertex(point(radius, phi, 0.0), (sign * math.cos(phi), 0.0, -sign * math.sin(phi))) for phi in angles]
        top = [mesh.vertex(point(radius, phi, height), (sign * math.cos(phi), 0.0, -sign * math.sin(phi))) for phi in angles]
        strip(bottom, top, reverse=sign < 0.0)
    # Rims: flat annuli facing up (top) and down (bottom).
    for y, up in ((height, 1.0), (0.0, -1.0)):
        inner_ring = [mesh.vertex(point(inner, phi, y), (0.0, up, 0.0)) for phi in angles]
        outer_ring = [mesh.vertex(point(outer, phi, y), (0.0, up, 0.0)) for phi in angles]
        strip(outer_ring, inner_ring, reverse=up < 0.0)
    # End caps of a clipped ring: flat rectangles across the band.
    if not closed:
        for phi, sign in ((angles[0], -1.0), (angles[-1], 1.0)):
            tangent = (-math.sin(phi) * sign, 0.0, -math.cos(phi) * sign)
            corners = [mesh.vertex(point(r, phi, y), tangent) for r, y in ((inner, 0.0), (outer, 0.0), (outer, height), (inner, height))]
            if sign < 0.0:
                mesh.quad(*corners)
            else:
                mesh.quad(corners[3], corners[2], corners[1], corners[0])
    return mesh


def parse_wave(text):
    parts = [float(v) for v in text.split(",")]
    if len(parts) != 4 or parts[1] <= 0.0:
        raise argparse.ArgumentTypeError("a wave is AMPLITUDE,WAVELENGTH,DIRECTION_DEG,PHASE_RAD")
    return tuple(parts)


# The meshes used by the scenes in data/, with the exact parameters (kept in
# sync with the scene READMEs).
WATER_WAVES = [(0.014, 0.35, 10.0, 0.0), (0.011, 0.31, 70.0, 1.0), (0.0086, 0.27, 130.0, 2.0)]
SCENE_MESHES = [
    ("data/water-wave/meshes/wave.obj", "wave", dict(size=1.4, grid=80, height=1.0, waves=WATER_WAVES)),
    # The first of water-wave's wave trains alone: a single sinusoid, fold lines without point foci.
    ("data/water-wave-sine/meshes/wave.obj", "wave", dict(size=1.4, grid=80, height=1.0, waves=WATER_WAVES[:1])),
    ("data/gold-ring/meshes/ring.obj", "ring",
     dict(inner=1.0, outer=1.08, height=0.5, segments=360, start=0.0, sweep=360.0)),
    ("data/metal-ring/meshes/half-ring.obj", "ring",
     dict(inner=1.0, outer=1.05, height=0.3, segments=240, start=0.0, sweep=180.0)),
    ("data/spot-fog/meshes/lamp-shade.obj", "ring",
     dict(inner=0.205, outer=0.22, height=0.8, segments=96, start=0.0, sweep=360.0)),
]


def build(kind, params):
    if kind == "wave":
        return make_wave(params["size"], params["grid"], params["height"], params["waves"])
    return make_ring(params["inner"], params["outer"], params["height"], params["segments"], params["start"],
                     params["sweep"])


def describe(kind, out, params):
    if kind == "wave":
        args = ["wave", out, "--size", fmt(params["size"]), "--grid", str(params["grid"]), "--height",
                fmt(params["height"])]
        for w in params["waves"]:
            args += ["--waves", ",".join(fmt(v) for v in w)]
    else:
        args = ["ring", out] + sum((["--" + k, fmt(params[k])] for k in ("inner", "outer", "height")), [])
        args += ["--segments", str(params["segments"]), "--start", fmt(params["start"]), "--sweep",
                 fmt(params["sweep"])]
    return "tools/make_geometry.py " + " ".join(args)


def main(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    wave = sub.add_parser("wave", help="sinusoidal height field (water surface)")
    wave.add_argument("out")
    wave.add_argument("--size", type=float, default=3.0, help="side of the square patch")
    wave.add_argument("--grid", type=int, default=80, help="quads per side")
    wave.add_argument("--height", type=float, default=1.5, help="mean height (y)")
    wave.add_argument("--waves", type=parse_wave, action="append",
                      help="AMPLITUDE,WAVELENGTH,DIRECTION_DEG,PHASE_RAD (repeatable)")
    ring = sub.add_parser("ring", help="band around the y axis (full or clipped ring)")
    ring.add_argument("out")
    ring.add_argument("--inner", type=float, default=1.0)
    ring.add_argument("--outer", type=float, default=1.08)
    ring.add_argument("--height", type=float, default=0.4)
    ring.add_argument("--segments", type=int, default=360)
    ring.add_argument("--start", type=float, default=0.0, help="start angle, degrees from +x towards -z")
    ring.add_argument("--sweep", type=float, default=360.0, help="angular extent in degrees (360 = closed ring)")
    everything = sub.add_parser("all", help="regenerate every mesh used by the scenes in data/")
    everything.add_argument("--root", default=REPO, help="write below this directory instead of the repository")
    args = parser.parse_args(argv)

    if args.command == "all":
        for out, kind, params in SCENE_MESHES:
            write_obj(build(kind, params), os.path.join(args.root, out), [describe(kind, out, params)])
        return
    if args.command == "wave":
        if args.grid < 1 or args.size <= 0.0:
            raise SystemExit("wave: need grid >= 1 and size > 0")
        params = dict(size=args.size, grid=args.grid, height=args.height, waves=args.waves or WATER_WAVES)
    else:
        params = dict(inner=args.inner, outer=args.outer, height=args.height, segments=args.segments,
                      start=args.start, sweep=args.sweep)
    write_obj(build(args.command, params), args.out, [describe(args.command, args.out, params)])


if __name__ == "__main__":
    main(sys.argv[1:])
