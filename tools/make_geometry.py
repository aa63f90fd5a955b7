#!/usr/bin/env python3
"""Procedural meshes of the caustic test scenes in data/ (standard library only).

Writes Wavefront OBJ files with per-vertex normals ("v", "vn", "f a//a ..."),
which both the TOML and the Mitsuba XML scene loaders read, so the same mesh
serves both scene files. The output is deterministic: rerunning a command
reproduces the committed file byte for byte.

    tools/make_geometry.py wave  OUT.obj [--size S] [--grid N] [--height H] [--waves A,LAMBDA,DEG,PHASE ...]
    tools/make_geometry.py ring  OUT.obj [--inner R] [--outer R] [--height H] [--segments N]
                                 [--start DEG] [--sweep DEG]
    tools/make_geometry.py teapot BODY.obj LID.obj [--steps N]
    tools/make_geometry.py window-room ROOM.xml SKY.exr
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
A teapot is Newell's Utah teapot (1975; public-domain data as published by
Crow 1987, "The origins of the teapot", IEEE CG&A 7(1)), with the bottom
patches many later copies add: 32 bicubic Bezier patches over 306 control
points, z up in the data, written y up (x, z, -y) with the base on y = 0.
Each patch becomes an N x N grid with analytic normals (dP/du x dP/dv, the
partials taken slightly inside the patch where a patch collapses to a point);
each patch's side is chosen so that its normals point out of the pot (a ray
from the patch centre along the normal crosses the surface an even number of
times). BODY gets rim, body, handle, spout and bottom, LID the lid.
The window room is a whole Mitsuba 3 scene (closed boxes, a thin glass pane,
a sky environment map) rather than a mesh; its sky is a half-float OpenEXR
file written by a small standard-library writer (ZIP compression through
zlib), so that regenerating it needs no Python imaging package beyond the
project's dependencies (Debian's python3-openimageio would do, but is not one).
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


# Newell's teapot control points (1-based in the patch table below).
TEAPOT_POINTS = [float(v) for v in """
1.4 0 2.4  1.4 -0.784 2.4  0.784 -1.4 2.4  0 -1.4 2.4  1.3375 0 2.53125  1.3375 -0.749 2.53125
0.749 -1.3375 2.53125  0 -1.3375 2.53125  1.4375 0 2.53125  1.4375 -0.805 2.53125  0.805 -1.4375 2.53125
0 -1.4375 2.53125  1.5 0 2.4  1.5 -0.84 2.4  0.84 -1.5 2.4  0 -1.5 2.4  -0.784 -1.4 2.4  -1.4 -0.784 2.4
-1.4 0 2.4  -0.749 -1.3375 2.53125  -1.3375 -0.749 2.53125  -1.3375 0 2.53125  -0.805 -1.4375 2.53125
-1.4375 -0.805 2.53125  -1.4375 0 2.53125  -0.84 -1.5 2.4  -1.5 -0.84 2.4  -1.5 0 2.4  -1.4 0.784 2.4
-0.784 1.4 2.4  0 1.4 2.4  -1.3375 0.749 2.53125  -0.749 1.3375 2.53125  0 1.3375 2.53125
-1.4375 0.805 2.53125  -0.805 1.4375 2.53125  0 1.4375 2.53125  -1.5 0.84 2.4  -0.84 1.5 2.4  0 1.5 2.4
0.784 1.4 2.4  1.4 0.784 2.4  0.749 1.3375 2.53125  1.3375 0.749 2.53125  0.805 1.4375 2.53125
1.4375 0.805 2.53125  0.84 1.5 2.4  1.5 0.84 2.4  1.75 0 1.875  1.75 -0.98 1.875  0.98 -1.75 1.875
0 -1.75 1.875  2 0 1.35  2 -1.12 1.35  1.12 -2 1.35  0 -2 1.35  2 0 0.9  2 -1.12 0.9  1.12 -2 0.9  0 -2 0.9
-0.98 -1.75 1.875  -1.75 -0.98 1.875  -1.75 0 1.875  -1.12 -2 1.35  -2 -1.12 1.35  -2 0 1.35  -1.12 -2 0.9
-2 -1.12 0.9  -2 0 0.9  -1.75 0.98 1.875  -0.98 1.75 1.875  0 1.75 1.875  -2 1.12 1.35  -1.12 2 1.35
0 2 1.35  -2 1.12 0.9  -1.12 2 0.9  0 2 0.9  0.98 1.75 1.875  1.75 0.98 1.875  1.12 2 1.35  2 1.12 1.35
1.12 2 0.9  2 1.12 0.9  2 0 0.45  2 -1.12 0.45  1.12 -2 0.45  0 -2 0.45  1.5 0 0.225  1.5 -0.84 0.225
0.84 -1.5 0.225  0 -1.5 0.225  1.5 0 0.15  1.5 -0.84 0.15  0.84 -1.5 0.15  0 -1.5 0.15  -1.12 -2 0.45
-2 -1.12 0.45  -2 0 0.45  -0.84 -1.5 0.225  -1.5 -0.84 0.225  -1.5 0 0.225  -0.84 -1.5 0.15  -1.5 -0.84 0.15
-1.5 0 0.15  -2 1.12 0.45  -1.12 2 0.45  0 2 0.45  -1.5 0.84 0.225  -0.84 1.5 0.225  0 1.5 0.225
-1.5 0.84 0.15  -0.84 1.5 0.15  0 1.5 0.15  1.12 2 0.45  2 1.12 0.45  0.84 1.5 0.225  1.5 0.84 0.225
0.84 1.5 0.15  1.5 0.84 0.15  -1.6 0 2.025  -1.6 -0.3 2.025  -1.5 -0.3 2.25  -1.5 0 2.25  -2.3 0 2.025
-2.3 -0.3 2.025  -2.5 -0.3 2.25  -2.5 0 2.25  -2.7 0 2.025  -2.7 -0.3 2.025  -3 -0.3 2.25  -3 0 2.25
-2.7 0 1.8  -2.7 -0.3 1.8  -3 -0.3 1.8  -3 0 1.8  -1.5 0.3 2.25  -1.6 0.3 2.025  -2.5 0.3 2.25  -2.3 0.3 2.025
-3 0.3 2.25  -2.7 0.3 2.025  -3 0.3 1.8  -2.7 0.3 1.8  -2.7 0 1.575  -2.7 -0.3 1.575  -3 -0.3 1.35  -3 0 1.35
-2.5 0 1.125  -2.5 -0.3 1.125  -2.65 -0.3 0.9375  -2.65 0 0.9375  -2 -0.3 0.9  -1.9 -0.3 0.6  -1.9 0 0.6
-3 0.3 1.35  -2.7 0.3 1.575  -2.65 0.3 0.9375  -2.5 0.3 1.125  -1.9 0.3 0.6  -2 0.3 0.9  1.7 0 1.425
1.7 -0.66 1.425  1.7 -0.66 0.6  1.7 0 0.6  2.6 0 1.425  2.6 -0.66 1.425  3.1 -0.66 0.825  3.1 0 0.825
2.3 0 2.1  2.3 -0.25 2.1  2.4 -0.25 2.025  2.4 0 2.025  2.7 0 2.4  2.7 -0.25 2.4  3.3 -0.25 2.4  3.3 0 2.4
1.7 0.66 0.6  1.7 0.66 1.425  3.1 0.66 0.825  2.6 0.66 1.425  2.4 0.25 2.025  2.3 0.25 2.1  3.3 0.25 2.4
2.7 0.25 2.4  2.8 0 2.475  2.8 -0.25 2.475  3.525 -0.25 2.49375  3.525 0 2.49375  2.9 0 2.475
2.9 -0.15 2.475  3.45 -0.15 2.5125  3.45 0 2.5125  2.8 0 2.4  2.8 -0.15 2.4  3.2 -0.15 2.4  3.2 0 2.4
3.525 0.25 2.49375  2.8 0.25 2.475  3.45 0.15 2.5125  2.9 0.15 2.475  3.2 0.15 2.4  2.8 0.15 2.4  0 0 3.15
0 -0.002 3.15  0.002 0 3.15  0.8 0 3.15  0.8 -0.45 3.15  0.45 -0.8 3.15  0 -0.8 3.15  0 0 2.85  0.2 0 2.7
0.2 -0.112 2.7  0.112 -0.2 2.7  0 -0.2 2.7  -0.002 0 3.15  -0.45 -0.8 3.15  -0.8 -0.45 3.15  -0.8 0 3.15
-0.112 -0.2 2.7  -0.2 -0.112 2.7  -0.2 0 2.7  0 0.002 3.15  -0.8 0.45 3.15  -0.45 0.8 3.15  0 0.8 3.15
-0.2 0.112 2.7  -0.112 0.2 2.7  0 0.2 2.7  0.45 0.8 3.15  0.8 0.45 3.15  0.112 0.2 2.7  0.2 0.112 2.7
0.4 0 2.55  0.4 -0.224 2.55  0.224 -0.4 2.55  0 -0.4 2.55  1.3 0 2.55  1.3 -0.728 2.55  0.728 -1.3 2.55
0 -1.3 2.55  1.3 0 2.4  1.3 -0.728 2.4  0.728 -1.3 2.4  0 -1.3 2.4  -0.224 -0.4 2.55  -0.4 -0.224 2.55
-0.4 0 2.55  -0.728 -1.3 2.55  -1.3 -0.728 2.55  -1.3 0 2.55  -0.728 -1.3 2.4  -1.3 -0.728 2.4  -1.3 0 2.4
-0.4 0.224 2.55  -0.224 0.4 2.55  0 0.4 2.55  -1.3 0.728 2.55  -0.728 1.3 2.55  0 1.3 2.55  -1.3 0.728 2.4
-0.728 1.3 2.4  0 1.3 2.4  0.224 0.4 2.55  0.4 0.224 2.55  0.728 1.3 2.55  1.3 0.728 2.55  0.728 1.3 2.4
1.3 0.728 2.4  0 0 0  1.5 0 0.15  1.5 0.84 0.15  0.84 1.5 0.15  0 1.5 0.15  1.5 0 0.075  1.5 0.84 0.075
0.84 1.5 0.075  0 1.5 0.075  1.425 0 0  1.425 0.798 0  0.798 1.425 0  0 1.425 0  -0.84 1.5 0.15
-1.5 0.84 0.15  -1.5 0 0.15  -0.84 1.5 0.075  -1.5 0.84 0.075  -1.5 0 0.075  -0.798 1.425 0
-1.425 0.798 0  -1.425 0 0  -1.5 -0.84 0.15  -0.84 -1.5 0.15  0 -1.5 0.15  -1.5 -0.84 0.075
-0.84 -1.5 0.075  0 -1.5 0.075  -1.425 -0.798 0  -0.798 -1.425 0  0 -1.425 0  0.84 -1.5 0.15
1.5 -0.84 0.15  0.84 -1.5 0.075  1.5 -0.84 0.075  0.798 -1.425 0  1.425 -0.798 0
""".split()]

# (part, 16 one-based control point indices, row by row).
TEAPOT_PATCHES = [(part, [int(v) for v in row.split()]) for part, row in [
    ("body", "1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16"),
    ("body", "4 17 18 19 8 20 21 22 12 23 24 25 16 26 27 28"),
    ("body", "19 29 30 31 22 32 33 34 25 35 36 37 28 38 39 40"),
    ("body", "31 41 42 1 34 43 44 5 37 45 46 9 40 47 48 13"),
    ("body", "13 14 15 16 49 50 51 52 53 54 55 56 57 58 59 60"),
    ("body", "16 26 27 28 52 61 62 63 56 64 65 66 60 67 68 69"),
    ("body", "28 38 39 40 63 70 71 72 66 73 74 75 69 76 77 78"),
    ("body", "40 47 48 13 72 79 80 49 75 81 82 53 78 83 84 57"),
    ("body", "57 58 59 60 85 86 87 88 89 90 91 92 93 94 95 96"),
    ("body", "60 67 68 69 88 97 98 99 92 100 101 102 96 103 104 105"),
    ("body", "69 76 77 78 99 106 107 108 102 109 110 111 105 112 113 114"),
    ("body", "78 83 84 57 108 115 116 85 111 117 118 89 114 119 120 93"),
    ("body", "121 122 123 124 125 126 127 128 129 130 131 132 133 134 135 136"),
    ("body", "124 137 138 121 128 139 140 125 132 141 142 129 136 143 144 133"),
    ("body", "133 134 135 136 145 146 147 148 149 150 151 152 69 153 154 155"),
    ("body", "136 143 144 133 148 156 157 145 152 158 159 149 155 160 161 69"),
    ("body", "162 163 164 165 166 167 168 169 170 171 172 173 174 175 176 177"),
    ("body", "165 178 179 162 169 180 181 166 173 182 183 170 177 184 185 174"),
    ("body", "174 175 176 177 186 187 188 189 190 191 192 193 194 195 196 197"),
    ("body", "177 184 185 174 189 198 199 186 193 200 201 190 197 202 203 194"),
    ("lid", "204 204 204 204 207 208 209 210 211 211 211 211 212 213 214 215"),
    ("lid", "204 204 204 204 210 217 218 219 211 211 211 211 215 220 221 222"),
    ("lid", "204 204 204 204 219 224 225 226 211 211 211 211 222 227 228 229"),
    ("lid", "204 204 204 204 226 230 231 207 211 211 211 211 229 232 233 212"),
    ("lid", "212 213 214 215 234 235 236 237 238 239 240 241 242 243 244 245"),
    ("lid", "215 220 221 222 237 246 247 248 241 249 250 251 245 252 253 254"),
    ("lid", "222 227 228 229 248 255 256 257 251 258 259 260 254 261 262 263"),
    ("lid", "229 232 233 212 257 264 265 234 260 266 267 238 263 268 269 242"),
    ("body", "270 270 270 270 279 280 281 282 275 276 277 278 271 272 273 274"),
    ("body", "270 270 270 270 282 289 290 291 278 286 287 288 274 283 284 285"),
    ("body", "270 270 270 270 291 298 299 300 288 295 296 297 285 292 293 294"),
    ("body", "270 270 270 270 300 305 306 279 297 303 304 275 294 301 302 271"),
]]


def bezier_patch(points, u, v):
    """Point and partial derivatives of a bicubic Bezier patch (rows along v, columns along u)."""
    def basis(t):
        s = 1.0 - t
        return (s * s * s, 3.0 * t * s * s, 3.0 * t * t * s, t * t * t), \
               (-3.0 * s * s, 3.0 * s * s - 6.0 * t * s, 6.0 * t * s - 3.0 * t * t, 3.0 * t * t)
    bu, du = basis(u)
    bv, dv = basis(v)
    p, pu, pv = [0.0] * 3, [0.0] * 3, [0.0] * 3
    for i in range(4):
        for j in range(4):
            c = points[4 * i + j]
            for k in range(3):
                p[k] += bv[i] * bu[j] * c[k]
                pu[k] += bv[i] * du[j] * c[k]
                pv[k] += dv[i] * bu[j] * c[k]
    return p, pu, pv


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def patch_normal(points, u, v):
    """Unnormalised dP/du x dP/dv; at a collapsed edge, taken a little inside the patch."""
    for inset in (0.0, 1e-3, 1e-2):
        uu = min(max(u, inset), 1.0 - inset)
        vv = min(max(v, inset), 1.0 - inset)
        _, pu, pv = bezier_patch(points, uu, vv)
        n = cross(pu, pv)
        if sum(c * c for c in n) > 1e-16:
            return n
    return (0.0, 0.0, 1.0)


def ray_crossings(origin, direction, triangles):
    """How many triangles the ray origin + t direction (t > 0) crosses (Moller-Trumbore)."""
    count = 0
    for a, b, c in triangles:
        e1 = [b[k] - a[k] for k in range(3)]
        e2 = [c[k] - a[k] for k in range(3)]
        pv = cross(direction, e2)
        det = sum(e1[k] * pv[k] for k in range(3))
        if abs(det) < 1e-12:
            continue
        tv = [origin[k] - a[k] for k in range(3)]
        u = sum(tv[k] * pv[k] for k in range(3)) / det
        if u < 0.0 or u > 1.0:
            continue
        qv = cross(tv, e1)
        v = sum(direction[k] * qv[k] for k in range(3)) / det
        if v < 0.0 or u + v > 1.0:
            continue
        if sum(e2[k] * qv[k] for k in range(3)) / det > 1e-6:
            count += 1
    return count


def make_teapot(steps):
    """Two meshes (body, lid) of Newell's teapot, y up, base on y = 0."""
    control = [tuple(TEAPOT_POINTS[3 * i:3 * i + 3]) for i in range(len(TEAPOT_POINTS) // 3)]
    grids = []
    for part, indices in TEAPOT_PATCHES:
        points = [control[i - 1] for i in indices]
        grid = []
        for j in range(steps + 1):
            row = []
            for i in range(steps + 1):
                u, v = i / steps, j / steps
                p, _, _ = bezier_patch(points, u, v)
                row.append((p, patch_normal(points, u, v)))
            grid.append(row)
        grids.append((part, grid))
    # Coarse triangles of the whole pot, for choosing each patch's outer side.
    coarse = []
    for _, grid in grids:
        for j in range(steps):
            for i in range(steps):
                a, b, c, d = grid[j][i][0], grid[j][i + 1][0], grid[j + 1][i + 1][0], grid[j + 1][i][0]
                coarse += [(a, b, c), (a, c, d)]
    meshes = {"body": Mesh(), "lid": Mesh()}
    for part, grid in grids:
        centre, normal = grid[steps // 2][steps // 2]
        length = math.sqrt(sum(c * c for c in normal))
        direction = [c / length for c in normal]
        start = [centre[k] + 1e-4 * direction[k] for k in range(3)]
        sign = -1.0 if ray_crossings(start, direction, coarse) % 2 == 1 else 1.0
        mesh = meshes[part]
        index = []
        for row in grid:
            index_row = []
            for p, n in row:
                if sum(c * c for c in n) <= 0.0:
                    n = (0.0, 0.0, 1.0)
                # z up in the data, y up in the file.
                index_row.append(mesh.vertex((p[0], p[2], -p[1]), (sign * n[0], sign * n[2], -sign * n[1])))
            index.append(index_row)
        for j in range(steps):
            for i in range(steps):
                a, b, c, d = index[j][i], index[j][i + 1], index[j + 1][i + 1], index[j + 1][i]
                for tri in ((a, b, c), (a, c, d)):
                    p0, p1, p2 = (mesh.positions[t] for t in tri)
                    ng = cross([p1[k] - p0[k] for k in range(3)], [p2[k] - p0[k] for k in range(3)])
                    if sum(c * c for c in ng) < 1e-20:
                        continue  # collapsed corner of a patch
                    ns = [sum(mesh.normals[t][k] for t in tri) for k in range(3)]
                    mesh.triangles.append(tri if sum(ng[k] * ns[k] for k in range(3)) > 0.0 else (tri[0], tri[2], tri[1]))
    return meshes["body"], meshes["lid"]


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


# Veach's "ajar" scene (../shared/scenes/bitterli-veach-ajar) names its teapots
# models/Mesh000.obj and Mesh009.obj, which its copy lacks; data/veach-ajar/
# includes that scene and supplies these two.
TEAPOT_BODY = "data/veach-ajar/models/Mesh000.obj"
TEAPOT_LID = "data/veach-ajar/models/Mesh009.obj"


def write_teapot(body_path, lid_path, steps, names):
    body, lid = make_teapot(steps)
    command = "tools/make_geometry.py teapot %s %s --steps %d" % (names[0], names[1], steps)
    write_obj(body, body_path, [command, "Newell's Utah teapot (public-domain data): rim, body, handle, spout, bottom"])
    write_obj(lid, lid_path, [command, "Newell's Utah teapot (public-domain data): lid"])


# ---------------------------------------------------------------- window room

# The window room (data/window-room/): a closed 6 x 3 x 4 room lit only through
# a narrow gap between two curtains behind a glass pane, by a generated sky with
# a small sun, after the living-room and classroom scenes of Vorba et al. 2014
# (Fig. 1, Sec. 6). Lengths in metres; the room's inside is x in [-3, 3],
# y in [0, 3], z in [-2, 2]; the window is in the wall x = -3.
WINDOW_ROOM = dict(
    wall=0.1,                       # thickness of floor, ceiling and walls (closed boxes: no light leaks at edges)
    opening=(-0.9, 0.9, 0.8, 2.4),  # window opening in the wall x = -3: z0, z1, y0, y1
    gap=0.12,                       # width of the vertical gap between the curtains, centred on z = 0
    sun_elevation=30.0,             # degrees above the horizon
    sun_azimuth=15.0,               # degrees from -x (straight through the window) towards -z
    sun_radius=2.0,                 # angular radius, degrees
    sun_radiance=(6000.0, 5600.0, 5000.0),
    sky_size=(256, 128),
)


def window_room_sun_direction(params):
    """Unit vector towards the sun (world space; the envmap is not rotated)."""
    e, a = math.radians(params["sun_elevation"]), math.radians(params["sun_azimuth"])
    return (-math.cos(e) * math.cos(a), math.sin(e), -math.cos(e) * math.sin(a))


def sky_radiance(d, sun, params):
    """A clear-sky gradient (bluish zenith, bright horizon, dim ground) plus a sun disk of uniform radiance."""
    y = d[1]
    if y >= 0.0:
        t = 1.0 - y  # 1 at the horizon, 0 at the zenith
        base = [0.25 + 0.55 * t ** 3, 0.40 + 0.45 * t ** 3, 0.80 + 0.15 * t ** 3]
        # Brighter around the sun (a crude circumsolar glow, wide and smooth).
        cos_sun = sum(d[k] * sun[k] for k in range(3))
        glow = 1.5 * math.exp(-(1.0 - cos_sun) * 12.0)
        base = [b + glow * c for b, c in zip(base, (1.0, 0.9, 0.7))]
    else:
        base = [0.25, 0.22, 0.20]
    cos_sun = sum(d[k] * sun[k] for k in range(3))
    if cos_sun >= math.cos(math.radians(params["sun_radius"])):
        base = [b + s for b, s in zip(base, params["sun_radiance"])]
    return base


def make_sky(params):
    """Equirectangular sky in the envmap's convention (engine/shading/light.cpp): column x is
    phi = 2 pi (x + 0.5) / W with phi = atan2(d.x, -d.z), row y is theta = pi y / (H - 1) from +y.
    Each pixel averages 8 x 8 directions over its footprint, so the sun's edge is spread over
    the pixels it partly covers. Returns rows of RGB tuples and the sun's and the whole map's
    radiant integrals (sum of radiance x solid angle over pixels)."""
    width, height = params["sky_size"]
    sun = window_room_sun_direction(params)
    n = 8
    rows = []
    sun_integral = 0.0
    total = [0.0, 0.0, 0.0]
    for y in range(height):
        row = []
        theta0 = math.pi * max(0.0, (y - 0.5)) / (height - 1)
        theta1 = math.pi * min(height - 1.0, (y + 0.5)) / (height - 1)
        solid = 2.0 * math.pi / width * (math.cos(theta0) - math.cos(theta1))
        for x in range(width):
            acc = [0.0, 0.0, 0.0]
            sun_part = 0.0
            for j in range(n):
                theta = theta0 + (theta1 - theta0) * (j + 0.5) / n
                for i in range(n):
                    phi = 2.0 * math.pi * (x + (i + 0.5) / n) / width
                    d = (math.sin(phi) * math.sin(theta), math.cos(theta), -math.cos(phi) * math.sin(theta))
                    value = sky_radiance(d, sun, params)
                    for k in range(3):
                        acc[k] += value[k]
                    if sum(d[k] * sun[k] for k in range(3)) >= math.cos(math.radians(params["sun_radius"])):
                        sun_part += 1.0
            pixel = tuple(v / (n * n) for v in acc)
            row.append(pixel)
            sun_integral += sun_part / (n * n) * solid
            for k in range(3):
                total[k] += pixel[k] * solid
        rows.append(row)
    return rows, sun_integral, total


def write_exr(rows, path):
    """Half-float RGB OpenEXR, scanlines, ZIP compression (16 lines per chunk), standard library only.
    The layout is that of the OpenEXR file format specification ("The OpenEXR File Layout"):
    magic and version, header attributes, a line offset table, then chunks of (y, size, data);
    ZIP data are the chunk's bytes split into even and odd halves, delta-coded, then zlib."""
    import struct
    import zlib
    height, width = len(rows), len(rows[0])

    def attribute(name, kind, value):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    channels = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 1, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = b"\x76\x2f\x31\x01" + struct.pack("<i", 2)
    header += attribute("channels", "chlist", channels)
    header += attribute("compression", "compression", b"\x03")
    header += attribute("dataWindow", "box2i", box)
    header += attribute("displayWindow", "box2i", box)
    header += attribute("lineOrder", "lineOrder", b"\x00")
    header += attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0))
    header += attribute("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0))
    header += attribute("screenWindowWidth", "float", struct.pack("<f", 1.0))
    header += b"\0"
    chunks = []
    for first in range(0, height, 16):
        raw = bytearray()
        for y in range(first, min(first + 16, height)):
            for c in (2, 1, 0):  # channels in name order: B, G, R
                raw += struct.pack("<%de" % width, *(p[c] for p in rows[y]))
        half = (len(raw) + 1) // 2
        split = bytearray(len(raw))
        split[:half] = raw[0::2]
        split[half:] = raw[1::2]
        coded = bytearray(split)
        for i in range(1, len(split)):
            coded[i] = (split[i] - split[i - 1] + 128 + 256) & 0xFF
        packed = zlib.compress(bytes(coded), 9)
        data = packed if len(packed) < len(raw) else bytes(raw)
        chunks.append(struct.pack("<ii", first, len(data)) + data)
    offset = len(header) + 8 * len(chunks)
    table = b""
    for chunk in chunks:
        table += struct.pack("<Q", offset)
        offset += len(chunk)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "wb") as out:
        out.write(header + table + b"".join(chunks))


def window_room_boxes(params):
    """(name, material, (x0, x1), (y0, y1), (z0, z1)) of every box of the room."""
    t = params["wall"]
    z0, z1, y0, y1 = params["opening"]
    g = 0.5 * params["gap"]
    return [
        ("floor", "floor", (-3 - t, 3 + t), (-t, 0), (-2 - t, 2 + t)),
        ("ceiling", "ceiling", (-3 - t, 3 + t), (3, 3 + t), (-2 - t, 2 + t)),
        ("wall-east", "wall", (3, 3 + t), (0, 3), (-2, 2)),
        ("wall-north", "wall", (-3, 3), (0, 3), (-2 - t, -2)),
        ("wall-south", "wall", (-3, 3), (0, 3), (2, 2 + t)),
        # The window wall x = -3 around its opening.
        ("wall-west-sill", "wall", (-3 - t, -3), (0, y0), (-2, 2)),
        ("wall-west-lintel", "wall", (-3 - t, -3), (y1, 3), (-2, 2)),
        ("wall-west-left", "wall", (-3 - t, -3), (y0, y1), (-2, z0)),
        ("wall-west-right", "wall", (-3 - t, -3), (y0, y1), (z1, 2)),
        # Curtains: opaque panels against the wall (no slot behind them for light to leak through around
        # their edges), wider and taller than the opening, leaving the gap.
        ("curtain-left", "curtain", (-3.0, -2.96), (y0 - 0.1, y1 + 0.2), (z0 - 0.1, -g)),
        ("curtain-right", "curtain", (-3.0, -2.96), (y0 - 0.1, y1 + 0.2), (g, z1 + 0.1)),
        # Furniture: a table, a low chest at the far end of the sunlit streak, a cupboard and a sofa block.
        ("table", "wood", (-0.6, 0.6), (0, 0.75), (-1.5, -0.7)),
        ("chest", "fabric", (0.3, 1.0), (0, 0.45), (0.7, 1.4)),
        ("cupboard", "wood", (-2.2, -1.0), (0, 1.8), (1.55, 2.0)),
        ("sofa", "fabric", (2.1, 2.9), (0, 0.8), (-0.4, 1.6)),
    ]


WINDOW_ROOM_MATERIALS = [
    ("wall", (0.7, 0.68, 0.62)),
    ("floor", (0.45, 0.33, 0.22)),
    ("ceiling", (0.8, 0.8, 0.8)),
    ("curtain", (0.55, 0.2, 0.15)),
    ("wood", (0.35, 0.25, 0.15)),
    ("fabric", (0.25, 0.35, 0.5)),
]


def window_room_xml(params, command, sky_file, sun_integral, total):
    z0, z1, y0, y1 = params["opening"]
    sun = window_room_sun_direction(params)
    width, height = params["sky_size"]
    zenith = sky_radiance((0.0, 1.0, 0.0), sun, params)
    solid = 2.0 * math.pi * (1.0 - math.cos(math.radians(params["sun_radius"])))
    sun_power = sun_integral * sum(params["sun_radiance"]) / 3.0
    lines = [
        '<?xml version="1.0" encoding="utf-8"?>',
        "<!--",
        "    Written by: %s" % command,
        "    Window room: a closed 6 x 3 x 4 room (inside x in [-3, 3], y in [0, 3], z in [-2, 2])",
        "    lit only through a %.2f m wide vertical gap between two curtains behind a thin glass" % params["gap"],
        "    pane in the window opening (z in [%g, %g], y in [%g, %g] of the wall x = -3), by a" % (z0, z1, y0, y1),
        "    generated %d x %d sky (%s) with a sun of angular radius %g degrees" % (width, height, sky_file, params["sun_radius"]),
        "    (solid angle %.3g sr; radiance %g, %.0f x the zenith sky's luminance; %.0f %% of the" % (
            solid, params["sun_radiance"][1], luminance3(params["sun_radiance"]) / luminance3(zenith),
            100.0 * sun_power / (sum(total) / 3.0)),
        "    map's radiant integral) at %g degrees elevation, %g degrees azimuth from the window's" % (
            params["sun_elevation"], params["sun_azimuth"]),
        "    normal. Sunlight through the gap lands as a streak on the floor; the camera sees the",
        "    streak, the curtains and the room, lit mostly indirectly. After the living room and",
        "    classroom of Vorba et al. 2014. Every surface but the pane is diffuse; every solid is",
        "    a closed box, so no light leaks through edges.",
        "-->",
        '<scene version="3.0.0">',
        '    <default name="spp" value="64"/>',
        '    <default name="width" value="64"/>',
        '    <default name="height" value="48"/>',
        '    <default name="max_depth" value="16"/>',
        "",
        '    <integrator type="path">',
        '        <integer name="max_depth" value="$max_depth"/>',
        "    </integrator>",
        "",
        '    <sensor type="perspective">',
        '        <string name="fov_axis" value="x"/>',
        '        <float name="fov" value="75"/>',
        '        <transform name="to_world">',
        '            <lookat origin="2.75, 1.6, -1.85" target="-1.2, 0.5, 0.6" up="0, 1, 0"/>',
        "        </transform>",
        '        <sampler type="independent">',
        '            <integer name="sample_count" value="$spp"/>',
        "        </sampler>",
        '        <film type="hdrfilm">',
        '            <integer name="width" value="$width"/>',
        '            <integer name="height" value="$height"/>',
        '            <rfilter type="box"/>',
        "        </film>",
        "    </sensor>",
        "",
    ]
    for name, rgb in WINDOW_ROOM_MATERIALS:
        lines += ['    <bsdf type="diffuse" id="mat-%s">' % name,
                  '        <rgb name="reflectance" value="%s, %s, %s"/>' % tuple(fmt(v) for v in rgb),
                  "    </bsdf>"]
    lines += ['    <bsdf type="thindielectric" id="mat-glass">',
              '        <float name="int_ior" value="1.5"/>',
              '        <float name="ext_ior" value="1"/>',
              "    </bsdf>", ""]
    for name, material, (xa, xb), (ya, yb), (za, zb) in window_room_boxes(params):
        lines += ['    <shape type="cube" id="%s">' % name,
                  '        <transform name="to_world">',
                  '            <scale x="%s" y="%s" z="%s"/>' % tuple(fmt(0.5 * (b - a)) for a, b in ((xa, xb), (ya, yb), (za, zb))),
                  '            <translate x="%s" y="%s" z="%s"/>' % tuple(fmt(0.5 * (a + b)) for a, b in ((xa, xb), (ya, yb), (za, zb))),
                  "        </transform>",
                  '        <ref id="mat-%s"/>' % material,
                  "    </shape>"]
    # The pane: a rectangle (Mitsuba's [-1, 1]^2 in z = 0) turned to face x, in the middle of the wall.
    lines += ['    <shape type="rectangle" id="glass">',
              '        <transform name="to_world">',
              '            <scale x="%s" y="%s"/>' % (fmt(0.5 * (z1 - z0)), fmt(0.5 * (y1 - y0))),
              '            <rotate y="1" angle="90"/>',
              '            <translate x="%s" y="%s" z="%s"/>' % (fmt(-3 - 0.5 * params["wall"]), fmt(0.5 * (y0 + y1)), fmt(0.5 * (z0 + z1))),
              "        </transform>",
              '        <ref id="mat-glass"/>',
              "    </shape>", "",
              '    <emitter type="envmap">',
              '        <string name="filename" value="%s"/>' % sky_file,
              "    </emitter>",
              "</scene>"]
    return "\n".join(lines) + "\n"


def luminance3(rgb):
    return 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]


WINDOW_ROOM_XML = "data/window-room/window-room.xml"
WINDOW_ROOM_SKY = "data/window-room/sky.exr"


def write_window_room(xml_path, sky_path, names):
    params = WINDOW_ROOM
    rows, sun_integral, total = make_sky(params)
    write_exr(rows, sky_path)
    command = "tools/make_geometry.py window-room %s %s" % names
    text = window_room_xml(params, command, os.path.relpath(sky_path, os.path.dirname(os.path.abspath(xml_path))),
                           sun_integral, total)
    with open(xml_path, "w", newline="\n") as out:
        out.write(text)
    print("%s, %s: %d bytes, %d bytes" % (os.path.relpath(xml_path), os.path.relpath(sky_path),
                                          os.path.getsize(xml_path), os.path.getsize(sky_path)))


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
    teapot = sub.add_parser("teapot", help="Newell's Utah teapot as two meshes (body, lid)")
    teapot.add_argument("body")
    teapot.add_argument("lid")
    teapot.add_argument("--steps", type=int, default=12, help="grid steps per patch side")
    room = sub.add_parser("window-room", help="the window room's Mitsuba XML and its generated sky (EXR)")
    room.add_argument("xml")
    room.add_argument("sky")
    everything = sub.add_parser("all", help="regenerate every mesh used by the scenes in data/")
    everything.add_argument("--root", default=REPO, help="write below this directory instead of the repository")
    args = parser.parse_args(argv)

    if args.command == "all":
        for out, kind, params in SCENE_MESHES:
            write_obj(build(kind, params), os.path.join(args.root, out), [describe(kind, out, params)])
        write_teapot(os.path.join(args.root, TEAPOT_BODY), os.path.join(args.root, TEAPOT_LID), 12,
                     (TEAPOT_BODY, TEAPOT_LID))
        write_window_room(os.path.join(args.root, WINDOW_ROOM_XML), os.path.join(args.root, WINDOW_ROOM_SKY),
                          (WINDOW_ROOM_XML, WINDOW_ROOM_SKY))
        return
    if args.command == "window-room":
        write_window_room(args.xml, args.sky, (args.xml, args.sky))
        return
    if args.command == "teapot":
        if args.steps < 1:
            raise SystemExit("teapot: need steps >= 1")
        write_teapot(args.body, args.lid, args.steps, (args.body, args.lid))
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
