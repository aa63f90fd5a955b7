#!/usr/bin/env python3
"""Converts a Radiance scene into Wavefront OBJ meshes and a Mitsuba 3 XML scene.

    tools/rad2mitsuba.py [-o DIR] [--name NAME] [--view FILE.vf] [--unit METRES]
                         [--max-edge LEN] [--light-scale S] [--allow-missing] FILE.rad ...

Reads the Radiance files in order, as oconv would, expanding the in-line
commands it knows (`!xform`, `!genbox`, `!genprism`, `!genworm`, and pipes of
them into `xform`), and writes DIR/NAME.xml with one OBJ per material in
DIR/meshes/. Bad input (a malformed primitive, an undefined modifier, an
unknown primitive type or command, a missing file) is one line naming the
file and line, exit code 2. With --allow-missing a missing file is skipped
with a warning instead; every file, pattern and texture left out is listed at
the end of the run (standard output), as are the triangle counts.

Geometry
  Radiance scenes are z up; the output is y up: (x, y, z) -> (x, z, -y), a
  rotation, so surface orientations are kept. Lengths are multiplied by
  --unit (default 0.3048: Radiance feet to metres).
  polygon            triangulated by ear clipping in its plane (non-convex
                     polygons and Radiance's "keyhole" polygons with holes
                     joined by a doubled edge are fine); the triangles keep
                     the polygon's orientation (right-hand rule).
  sphere, bubble     a latitude-longitude mesh; cone, cup, cylinder, tube:
  cone, cylinder,    the open side of a frustum; ring: a flat annulus (a disk
  ring, cup, tube    when the inner radius is 0). A full circle has
                     2 pi r / --max-edge segments (default edge 0.1 input
                     units), rounded up to a multiple of 4, at least 8 and at
                     most 32 (a 32-gon has 99.4 % of the disk's area).
  genbox             6 faces; -r R rounds the edges and corners (the visible
                     surface of genbox's cylinders and spheres: flat faces
                     inset by R, quarter-cylinder edges, sphere octants);
                     -b B bevels them (the same construction with one segment
                     per quarter circle: 45-degree edge strips and corner
                     triangles, as genbox -b); -i turns the faces inward.
                     The rounding's segment count follows --max-edge in
                     genbox's own units, before any xform scales it.
  genprism           N vertices, -l extrusion vector, -c (no closing side),
                     -e (no end caps); -r is refused.
  genworm            spheres and cones along (x(t), y(t), z(t)) of radius
                     r(t) as genworm makes them; the functions may use + - * /
                     ^, PI, sin cos tan asin acos atan atan2 sqrt exp log
                     log10 abs floor ceil min max select if hermite, and -e
                     definitions ("f(t)=..." or "a=..."); -f is refused.
  xform              -t, -rx, -ry, -rz, -s, -mx, -my, -mz in command-line
                     order; -i N repeats the transforms that follow (up to
                     the next -i or -a) N times; -a N makes N copies, copy k
                     with those transforms applied k times (several -a make a
                     grid); -n, -e, -c accepted; -m MOD replaces the surfaces'
                     modifier; -I and an odd number of mirrors turn surfaces
                     as xform does. Files named by nested commands are looked
                     up next to the file that names them, then next to the
                     first input file.

Materials (Radiance RGB values are linear reflectances; roughness is the RMS
surface slope alpha of Ward's Gaussian lobe exp(-tan^2 d / alpha^2), which is
Beckmann's alpha, so it maps one to one)
  plastic R G B S A  diffuse (reflectance R G B) when S = 0; otherwise plastic
                     (A = 0) or roughplastic (Beckmann, alpha = A) with
                     diffuse_reflectance R G B and the coating's index chosen
                     so that its normal-incidence Fresnel reflectance is S:
                     int_ior = (1 + sqrt S) / (1 - sqrt S) (S = 0.05 -> 1.58).
                     Radiance scales the diffuse part by (1 - S); Mitsuba's
                     coating takes a similar share through its Fresnel
                     transmission, so R G B is passed on unscaled.
  metal R G B S A    conductor (A = 0) or roughconductor (Beckmann, alpha = A),
                     material "none", specular_reflectance R G B: Radiance's
                     diffuse fraction (1 - S) of the metal is folded into the
                     specular lobe, keeping the total reflectance R G B.
  mirror R G B       conductor, material "none", specular_reflectance R G B.
  glass R G B        thindielectric, int_ior 1.52 (Radiance's glass index);
                     the transmissivity R G B is not represented (fluxgraph's
                     thindielectric transmits fully).
  dielectric R G B N H  dielectric with int_ior N (R G B, H not represented).
  light R G B        an area emitter of radiance (R G B) * --light-scale on
  glow R G B M       a black diffuse surface; one-sided (it emits along the
                     surface normal), as Radiance's sources are.
  Every other BSDF is wrapped in "twosided": Radiance shades both sides of a
  surface alike.
  Patterns and textures (brightfunc, colorfunc, brightdata, colordata,
  brighttext, colorpict, colortext, texfunc, texdata) are dropped: the
  material keeps its own colour, and the run lists every dropped modifier
  that a surface used. Other material types are refused.
"""

import argparse
import math
import os
import re
import shlex
import sys

EXIT_BAD_INPUT = 2

PATTERN_TYPES = {"brightfunc", "colorfunc", "brightdata", "colordata", "brighttext", "colortext",
                 "colorpict", "texfunc", "texdata"}
MATERIAL_TYPES = {"plastic", "metal", "mirror", "glass", "dielectric", "light", "glow"}
SURFACE_TYPES = {"polygon", "sphere", "bubble", "cone", "cup", "cylinder", "tube", "ring"}
REAL_COUNTS = {"polygon": None, "sphere": 4, "bubble": 4, "cone": 8, "cup": 8, "cylinder": 7, "tube": 7,
               "ring": 8, "plastic": 5, "metal": 5, "mirror": 3, "glass": 3, "light": 3, "glow": 4,
               "dielectric": 5}


class RadError(Exception):
    """Bad input: reported as 'file:line: message' with exit code 2."""

    def __init__(self, where, message):
        super().__init__("%s:%d: %s" % (where[0], where[1], message))


# ---------------------------------------------------------------- vectors and transforms

def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def mul(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def length(a):
    return math.sqrt(dot(a, a))


def normalize(a):
    n = length(a)
    return (a[0] / n, a[1] / n, a[2] / n)


def orthonormal_basis(axis):
    """Two unit vectors perpendicular to the unit vector `axis` and to each other."""
    other_axis = (1.0, 0.0, 0.0) if abs(axis[0]) < 0.9 else (0.0, 1.0, 0.0)
    u = normalize(cross(axis, other_axis))
    return u, cross(axis, u)


IDENTITY = ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def matmul(a, b):
    return tuple(tuple(sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)) for i in range(4))


def translation(t):
    return ((1.0, 0.0, 0.0, t[0]), (0.0, 1.0, 0.0, t[1]), (0.0, 0.0, 1.0, t[2]), (0.0, 0.0, 0.0, 1.0))


def scaling(s):
    return ((s[0], 0.0, 0.0, 0.0), (0.0, s[1], 0.0, 0.0), (0.0, 0.0, s[2], 0.0), (0.0, 0.0, 0.0, 1.0))


def rotation(axis, degrees):
    """Right-handed rotation about coordinate axis 0, 1 or 2 (xform's -rx, -ry, -rz)."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    i, j = (axis + 1) % 3, (axis + 2) % 3
    m = [list(row) for row in IDENTITY]
    m[i][i], m[i][j], m[j][i], m[j][j] = c, -s, s, c
    return tuple(tuple(row) for row in m)


def apply_point(m, p):
    return tuple(m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3] for i in range(3))


def apply_vector(m, v):
    return tuple(m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2] for i in range(3))


def determinant(m):
    return (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))


def uniform_scale(m):
    return abs(determinant(m)) ** (1.0 / 3.0)


# ---------------------------------------------------------------- expressions (genworm)

class Expression:
    """A small evaluator for Radiance's calc expressions as genworm uses them."""

    TOKEN = re.compile(r"\s*(?:(\d+\.?\d*(?:[eE][-+]?\d+)?|\.\d+(?:[eE][-+]?\d+)?)|([A-Za-z_][A-Za-z0-9_.]*)|(.))")

    @staticmethod
    def hermite(p0, p1, r0, r1, t):
        return (p0 * ((2.0 * t - 3.0) * t * t + 1.0) + p1 * (-2.0 * t + 3.0) * t * t
                + r0 * (((t - 2.0) * t + 1.0) * t) + r1 * ((t - 1.0) * t * t))

    @staticmethod
    def select(n, *values):
        index = int(n)
        if index == 0:
            return float(len(values))
        if not 1 <= index <= len(values):
            raise ValueError("select index %g out of range" % n)
        return values[index - 1]

    FUNCTIONS = {
        "sin": math.sin, "cos": math.cos, "tan": math.tan, "asin": math.asin, "acos": math.acos,
        "atan": math.atan, "atan2": math.atan2, "sqrt": math.sqrt, "exp": math.exp, "log": math.log,
        "log10": math.log10, "abs": abs, "floor": math.floor, "ceil": math.ceil, "min": min, "max": max,
        "if": lambda c, a, b: a if c > 0 else b,
    }

    def __init__(self, text, definitions):
        self.text = text
        self.definitions = definitions
        self.tokens = []
        pos = 0
        while pos < len(text):
            m = self.TOKEN.match(text, pos)
            if m.group(0).strip() == "":
                break
            self.tokens.append((float(m.group(1)), "num") if m.group(1) else
                               (m.group(2), "name") if m.group(2) else (m.group(3), "op"))
            pos = m.end()
        self.pos = 0
        self.tree = self.parse_sum()
        if self.pos != len(self.tokens):
            raise ValueError("unexpected '%s' in '%s'" % (self.tokens[self.pos][0], text))

    def peek(self):
        return self.tokens[self.pos][0] if self.pos < len(self.tokens) else None

    def take(self, expected=None):
        if self.pos >= len(self.tokens):
            raise ValueError("'%s' ends early" % self.text)
        token = self.tokens[self.pos]
        if expected is not None and token[0] != expected:
            raise ValueError("expected '%s' in '%s'" % (expected, self.text))
        self.pos += 1
        return token

    def parse_sum(self):
        node = self.parse_product()
        while self.peek() in ("+", "-"):
            op = self.take()[0]
            node = ("bin", op, node, self.parse_product())
        return node

    def parse_product(self):
        node = self.parse_unary()
        while self.peek() in ("*", "/"):
            op = self.take()[0]
            node = ("bin", op, node, self.parse_unary())
        return node

    def parse_unary(self):
        if self.peek() in ("-", "+"):
            op = self.take()[0]
            operand = self.parse_unary()
            return ("neg", operand) if op == "-" else operand
        node = self.parse_primary()
        if self.peek() == "^":
            self.take()
            node = ("bin", "^", node, self.parse_unary())
        return node

    def parse_primary(self):
        value, kind = self.take()
        if kind == "num":
            return ("num", value)
        if kind == "name":
            if self.peek() == "(":
                self.take()
                args = [] if self.peek() == ")" else [self.parse_sum()]
                while self.peek() == ",":
                    self.take()
                    args.append(self.parse_sum())
                self.take(")")
                return ("call", value, args)
            return ("var", value)
        if value == "(":
            node = self.parse_sum()
            self.take(")")
            return node
        raise ValueError("unexpected '%s' in '%s'" % (value, self.text))

    def evaluate(self, variables, node=None, depth=0):
        if depth > 64:
            raise ValueError("definitions nest too deep in '%s'" % self.text)
        node = self.tree if node is None else node
        kind = node[0]
        if kind == "num":
            return node[1]
        if kind == "neg":
            return -self.evaluate(variables, node[1], depth)
        if kind == "bin":
            a, b = self.evaluate(variables, node[2], depth), self.evaluate(variables, node[3], depth)
            op = node[1]
            return a + b if op == "+" else a - b if op == "-" else a * b if op == "*" else \
                a / b if op == "/" else a ** b
        if kind == "var":
            name = node[1]
            if name in variables:
                return variables[name]
            if name == "PI":
                return math.pi
            if name in self.definitions and not self.definitions[name][0]:
                return self.definitions[name][1].evaluate(variables, None, depth + 1)
            raise ValueError("undefined variable '%s'" % name)
        name, args = node[1], [self.evaluate(variables, a, depth) for a in node[2]]
        if name in self.definitions and self.definitions[name][0]:
            params, body = self.definitions[name]
            if len(params) != len(args):
                raise ValueError("%s takes %d arguments" % (name, len(params)))
            return body.evaluate(dict(variables, **dict(zip(params, args))), None, depth + 1)
        if name == "hermite":
            return self.hermite(*args)
        if name == "select":
            return self.select(*args)
        if name in self.FUNCTIONS:
            return float(self.FUNCTIONS[name](*args))
        raise ValueError("unknown function '%s'" % name)


def parse_definitions(texts):
    """genworm -e arguments: 'f(a,b)=expr' and 'v=expr', several per argument separated by ';'."""
    definitions = {}
    for text in texts:
        for statement in text.split(";"):
            statement = statement.strip()
            if not statement:
                continue
            m = re.match(r"^([A-Za-z_][A-Za-z0-9_.]*)\s*(?:\(([^)]*)\))?\s*:?=(.*)$", statement)
            if not m:
                raise ValueError("cannot read definition '%s'" % statement)
            params = [p.strip() for p in m.group(2).split(",")] if m.group(2) is not None else []
            definitions[m.group(1)] = (params, None)
            definitions[m.group(1)] = (params, Expression(m.group(3), definitions))
    return definitions


# ---------------------------------------------------------------- primitives

class Primitive:
    """One Radiance object: modifier, type, identifier, string and real arguments, where it came from."""

    __slots__ = ("modifier", "type", "name", "strings", "reals", "where", "inverted")

    def __init__(self, modifier, type_, name, strings, reals, where, inverted=False):
        self.modifier = modifier
        self.type = type_
        self.name = name
        self.strings = strings
        self.reals = reals
        self.where = where
        self.inverted = inverted

    def transformed(self, m, invert, prefix, new_modifier):
        """The primitive after xform's matrix `m` (-I given: `invert`), -n `prefix`, -m `new_modifier`."""
        if self.type not in SURFACE_TYPES:
            return self
        flip = (determinant(m) < 0.0) != invert
        r = self.reals
        s = uniform_scale(m)
        if self.type == "polygon":
            points = [apply_point(m, r[i:i + 3]) for i in range(0, len(r), 3)]
            if flip:
                points.reverse()
            reals = [c for p in points for c in p]
        elif self.type in ("sphere", "bubble"):
            reals = list(apply_point(m, r[0:3])) + [r[3] * s]
        elif self.type in ("cone", "cup"):
            reals = list(apply_point(m, r[0:3])) + list(apply_point(m, r[3:6])) + [r[6] * s, r[7] * s]
        elif self.type in ("cylinder", "tube"):
            reals = list(apply_point(m, r[0:3])) + list(apply_point(m, r[3:6])) + [r[6] * s]
        else:  # ring: the normal follows the geometry; only -I turns it
            direction = apply_vector(m, r[3:6])
            if invert:
                direction = mul(direction, -1.0)
            reals = list(apply_point(m, r[0:3])) + list(direction) + [r[6] * s, r[7] * s]
        name = prefix + "." + self.name if prefix else self.name
        modifier = new_modifier if new_modifier else self.modifier
        inverted = self.inverted != (invert and self.type != "polygon" and self.type != "ring")
        return Primitive(modifier, self.type, name, self.strings, reals, self.where, inverted)


class Reader:
    """Radiance scene text: primitives, comments ('#' where a primitive may start) and '!' commands."""

    def __init__(self, text, path):
        self.text = text
        self.path = path
        self.pos = 0
        self.line = 1

    def skip_space(self):
        text = self.text
        while self.pos < len(text) and text[self.pos].isspace():
            if text[self.pos] == "\n":
                self.line += 1
            self.pos += 1

    def word(self, what):
        self.skip_space()
        if self.pos >= len(self.text):
            raise RadError((self.path, self.line), "file ends where %s was expected" % what)
        start = self.pos
        while self.pos < len(self.text) and not self.text[self.pos].isspace():
            self.pos += 1
        return self.text[start:self.pos]

    def count(self, what):
        line = self.line
        token = self.word(what)
        if not re.fullmatch(r"[0-9]+", token):
            raise RadError((self.path, line), "expected the number of %s, found '%s'" % (what, token))
        return int(token)

    def real(self, what):
        self.skip_space()
        line = self.line
        token = self.word(what)
        try:
            value = float(token)
        except ValueError:
            raise RadError((self.path, line), "expected a number (%s), found '%s'" % (what, token)) from None
        if not math.isfinite(value) or abs(value) > 1e10:
            raise RadError((self.path, line), "number out of range (%s): '%s'" % (what, token))
        return value

    def items(self):
        """Yields ('command', text, where) and ('primitive', Primitive)."""
        text = self.text
        while True:
            self.skip_space()
            if self.pos >= len(text):
                return
            where = (self.path, self.line)
            c = text[self.pos]
            if c == "#":
                end = text.find("\n", self.pos)
                self.pos = len(text) if end < 0 else end
                continue
            if c == "!":
                command = []
                while True:
                    end = text.find("\n", self.pos)
                    end = len(text) if end < 0 else end
                    chunk = text[self.pos:end]
                    self.pos = end
                    if chunk.endswith("\\") and self.pos < len(text):
                        command.append(chunk[:-1])
                        self.pos += 1
                        self.line += 1
                        continue
                    command.append(chunk)
                    break
                yield ("command", " ".join(command)[1:], where)
                continue
            modifier = self.word("a modifier")
            type_ = self.word("a primitive type")
            name = self.word("an identifier")
            if type_ == "alias":
                target = self.word("the aliased modifier")
                yield ("primitive", Primitive(modifier, type_, name, [target], [], where))
                continue
            strings = [self.word("a string argument") for _ in range(self.count("string arguments"))]
            ints = self.count("integer arguments")
            if ints != 0:
                raise RadError(where, "%s '%s': integer arguments are not supported" % (type_, name))
            reals = [self.real("real argument") for _ in range(self.count("real arguments"))]
            expected = REAL_COUNTS.get(type_)
            if type_ == "polygon":
                if len(reals) < 9 or len(reals) % 3:
                    raise RadError(where, "polygon '%s' needs 3 or more vertices (3 reals each), has %d reals"
                                   % (name, len(reals)))
            elif expected is not None and len(reals) != expected:
                raise RadError(where, "%s '%s' needs %d real arguments, has %d" % (type_, name, expected, len(reals)))
            yield ("primitive", Primitive(modifier, type_, name, strings, reals, where))


# ---------------------------------------------------------------- generators

def box_polygons(size, inward):
    """genbox's six faces of [0, x] x [0, y] x [0, z], outward unless `inward`."""
    x, y, z = size
    faces = [
        [(0, 0, 0), (0, y, 0), (x, y, 0), (x, 0, 0)],      # z = 0, normal -z
        [(0, 0, z), (x, 0, z), (x, y, z), (0, y, z)],      # z = z, normal +z
        [(0, 0, 0), (x, 0, 0), (x, 0, z), (0, 0, z)],      # y = 0, normal -y
        [(0, y, 0), (0, y, z), (x, y, z), (x, y, 0)],      # y = y, normal +y
        [(0, 0, 0), (0, 0, z), (0, y, z), (0, y, 0)],      # x = 0, normal -x
        [(x, 0, 0), (x, y, 0), (x, y, z), (x, 0, z)],      # x = x, normal +x
    ]
    return [list(reversed(f)) if inward else f for f in faces]


def rounded_box_polygons(size, radius, segments, inward):
    """A box with rounded (segments per quarter circle > 1) or bevelled (1) edges and corners."""
    lo = (radius, radius, radius)
    hi = (size[0] - radius, size[1] - radius, size[2] - radius)
    polygons = []

    def corner(signs):
        return tuple(hi[a] if signs[a] > 0 else lo[a] for a in range(3))

    def oriented(points, outward):
        normal = newell_normal(points)
        if (dot(normal, outward) < 0.0) != inward:
            points = list(reversed(points))
        return points

    # Faces, inset by the radius.
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for sign in (-1, 1):
            points = []
            for pb, pc in ((lo[b], lo[c]), (hi[b], lo[c]), (hi[b], hi[c]), (lo[b], hi[c])):
                p = [0.0, 0.0, 0.0]
                p[a] = size[a] if sign > 0 else 0.0
                p[b], p[c] = pb, pc
                points.append(tuple(p))
            outward = [0.0, 0.0, 0.0]
            outward[a] = float(sign)
            polygons.append(oriented(points, tuple(outward)))
    # Edges: quarter cylinders along axis a at the corners of the other two axes.
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for sb in (-1, 1):
            for sc in (-1, 1):
                for k in range(segments):
                    strip = []
                    for phi in (k * 0.5 * math.pi / segments, (k + 1) * 0.5 * math.pi / segments):
                        d = [0.0, 0.0, 0.0]
                        d[b], d[c] = sb * math.cos(phi), sc * math.sin(phi)
                        strip.append(d)
                    points = []
                    for end, d in ((lo[a], strip[0]), (hi[a], strip[0]), (hi[a], strip[1]), (lo[a], strip[1])):
                        p = [0.0, 0.0, 0.0]
                        p[a] = end
                        p[b] = (hi[b] if sb > 0 else lo[b]) + radius * d[b]
                        p[c] = (hi[c] if sc > 0 else lo[c]) + radius * d[c]
                        points.append(tuple(p))
                    mid = [0.0, 0.0, 0.0]
                    mid[b], mid[c] = strip[0][b] + strip[1][b], strip[0][c] + strip[1][c]
                    polygons.append(oriented(points, tuple(mid)))
    # Corners: sphere octants on a latitude-longitude grid.
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                centre = corner((sx, sy, sz))

                def point(i, j):
                    theta, phi = i * 0.5 * math.pi / segments, j * 0.5 * math.pi / segments
                    d = (sx * math.sin(theta) * math.cos(phi), sy * math.sin(theta) * math.sin(phi),
                         sz * math.cos(theta))
                    return add(centre, mul(d, radius)), d

                for i in range(segments):
                    for j in range(segments):
                        quad = [point(i, j), point(i + 1, j), point(i + 1, j + 1), point(i, j + 1)]
                        points = []
                        for p, _ in quad:
                            if not any(length(sub(p, q)) < 1e-12 * max(1.0, radius) for q in points):
                                points.append(p)
                        if len(points) < 3:
                            continue
                        outward = (0.0, 0.0, 0.0)
                        for _, d in quad:
                            outward = add(outward, d)
                        polygons.append(oriented(points, outward))
    return polygons


def newell_normal(points):
    """Area-weighted normal of a polygon (Newell's method): length = 2 * area."""
    nx = ny = nz = 0.0
    count = len(points)
    for i in range(count):
        p, q = points[i], points[(i + 1) % count]
        nx += (p[1] - q[1]) * (p[2] + q[2])
        ny += (p[2] - q[2]) * (p[0] + q[0])
        nz += (p[0] - q[0]) * (p[1] + q[1])
    return (nx, ny, nz)


def polygon_primitive(modifier, name, points, where):
    return Primitive(modifier, "polygon", name, [], [c for p in points for c in p], where)


def genbox(args, where, options):
    usage = "genbox MAT NAME XSIZE YSIZE ZSIZE [-i] [-r RAD | -b BEV]"
    if len(args) < 5:
        raise RadError(where, "usage: " + usage)
    modifier, name = args[0], args[1]
    size = tuple(number(a, where, "genbox size") for a in args[2:5])
    if min(size) <= 0.0:
        raise RadError(where, "genbox '%s': sizes must be positive" % name)
    inward, radius, bevel = False, 0.0, 0.0
    rest = args[5:]
    i = 0
    while i < len(rest):
        if rest[i] == "-i":
            inward = True
            i += 1
        elif rest[i] in ("-r", "-b") and i + 1 < len(rest):
            value = number(rest[i + 1], where, "genbox " + rest[i])
            if rest[i] == "-r":
                radius = value
            else:
                bevel = value
            i += 2
        else:
            raise RadError(where, "genbox: unknown option '%s' (%s)" % (rest[i], usage))
    edge = max(radius, bevel)
    if edge < 0.0 or 2.0 * edge > min(size):
        raise RadError(where, "genbox '%s': rounding or bevel larger than half the box" % name)
    if edge == 0.0:
        polygons = box_polygons(size, inward)
    elif radius > 0.0:
        polygons = rounded_box_polygons(size, radius, circle_segments(radius, options) // 4, inward)
    else:
        polygons = rounded_box_polygons(size, bevel, 1, inward)
    return [polygon_primitive(modifier, "%s.%d" % (name, k), p, where) for k, p in enumerate(polygons)]


def genprism(args, where):
    usage = "genprism MAT NAME N X1 Y1 .. XN YN [-l X Y Z] [-c] [-e]"
    if len(args) < 3:
        raise RadError(where, "usage: " + usage)
    modifier, name = args[0], args[1]
    if not re.fullmatch(r"[0-9]+", args[2]):
        raise RadError(where, "genprism '%s': vertices must be given on the command line (%s)" % (name, usage))
    count = int(args[2])
    if count < 3 or len(args) < 3 + 2 * count:
        raise RadError(where, "genprism '%s': needs at least 3 vertices, given as %d x y pairs" % (name, count))
    profile = [(number(args[3 + 2 * k], where, "genprism x"), number(args[4 + 2 * k], where, "genprism y"), 0.0)
               for k in range(count)]
    extrusion, closed, ends = (0.0, 0.0, 1.0), True, True
    rest = args[3 + 2 * count:]
    i = 0
    while i < len(rest):
        if rest[i] == "-l" and i + 3 < len(rest):
            extrusion = tuple(number(v, where, "genprism -l") for v in rest[i + 1:i + 4])
            i += 4
        elif rest[i] == "-c":
            closed = False
            i += 1
        elif rest[i] == "-e":
            ends = False
            i += 1
        elif rest[i] == "-r":
            raise RadError(where, "genprism '%s': rounded corners (-r) are not supported" % name)
        else:
            raise RadError(where, "genprism: unknown option '%s' (%s)" % (rest[i], usage))
    # The profile's orientation and the extrusion decide which way the surfaces face: the caps
    # face away from each other and the sides outward when the profile winds counter-clockwise
    # seen from the extrusion direction, as genprism makes them.
    top = [add(p, extrusion) for p in profile]
    primitives = []
    if ends:
        ccw = dot(newell_normal(profile), extrusion) > 0.0
        bottom_cap = list(reversed(profile)) if ccw else list(profile)
        top_cap = list(top) if ccw else list(reversed(top))
        primitives.append(polygon_primitive(modifier, name + ".b", bottom_cap, where))
        primitives.append(polygon_primitive(modifier, name + ".t", top_cap, where))
    ccw = dot(newell_normal(profile), extrusion) >= 0.0
    sides = count if closed else count - 1
    for k in range(sides):
        a, b = profile[k], profile[(k + 1) % count]
        quad = [a, b, add(b, extrusion), add(a, extrusion)]
        if not ccw:
            quad.reverse()
        primitives.append(polygon_primitive(modifier, "%s.%d" % (name, k + 1), quad, where))
    return primitives


def genworm(args, where):
    usage = "genworm MAT NAME 'x(t)' 'y(t)' 'z(t)' 'r(t)' NSEG [-e EXPR]"
    if len(args) < 7:
        raise RadError(where, "usage: " + usage)
    modifier, name = args[0], args[1]
    if not re.fullmatch(r"[0-9]+", args[6]) or int(args[6]) < 1:
        raise RadError(where, "genworm '%s': the number of segments must be a positive integer" % name)
    segments = int(args[6])
    definitions_text = []
    rest = args[7:]
    i = 0
    while i < len(rest):
        if rest[i] == "-e" and i + 1 < len(rest):
            definitions_text.append(rest[i + 1])
            i += 2
        elif rest[i] == "-f":
            raise RadError(where, "genworm '%s': function files (-f) are not supported" % name)
        else:
            raise RadError(where, "genworm: unknown option '%s' (%s)" % (rest[i], usage))
    try:
        definitions = parse_definitions(definitions_text)
        functions = [Expression(text, definitions) for text in args[2:6]]
        samples = []
        for k in range(segments + 1):
            t = k / segments
            values = [f.evaluate({"t": t}) for f in functions]
            samples.append((tuple(values[0:3]), values[3]))
    except (ValueError, ZeroDivisionError, OverflowError, TypeError) as e:
        raise RadError(where, "genworm '%s': %s" % (name, e)) from None
    primitives = []
    for k, (p, r) in enumerate(samples):
        if r <= 0.0:
            raise RadError(where, "genworm '%s': radius %g at t = %g is not positive" % (name, r, k / segments))
        if k > 0:
            q, rq = samples[k - 1]
            if abs(r - rq) < 1e-12:
                primitives.append(Primitive(modifier, "cylinder", "%s.c%d" % (name, k), [], list(q) + list(p) + [r],
                                            where))
            else:
                primitives.append(Primitive(modifier, "cone", "%s.c%d" % (name, k), [], list(q) + list(p) + [rq, r],
                                            where))
        primitives.append(Primitive(modifier, "sphere", "%s.s%d" % (name, k), [], list(p) + [r], where))
    return primitives


def number(text, where, what):
    try:
        value = float(text)
    except ValueError:
        raise RadError(where, "%s: '%s' is not a number" % (what, text)) from None
    if not math.isfinite(value) or abs(value) > 1e10:
        raise RadError(where, "%s: '%s' is out of range" % (what, text))
    return value


# ---------------------------------------------------------------- xform

class Xform:
    """The options of one xform invocation: the matrices of its copies and what it does to names."""

    def __init__(self, args, where):
        self.prefix = None
        self.modifier = None
        self.invert = False
        self.files = []
        i = 0
        while i < len(args) and args[i] in ("-c", "-e", "-I", "-n", "-m", "-f"):
            option = args[i]
            if option in ("-n", "-m", "-f") and i + 1 >= len(args):
                raise RadError(where, "xform: %s needs an argument" % option)
            if option == "-n":
                self.prefix = args[i + 1]
            elif option == "-m":
                self.modifier = args[i + 1]
            elif option == "-f":
                raise RadError(where, "xform: argument files (-f) are not supported")
            elif option == "-I":
                self.invert = True
            i += 2 if option in ("-n", "-m") else 1
        # Transform segments: the transforms before any -i/-a, then (kind, count, matrix) per -i/-a.
        segments = [("i", 1, IDENTITY)]
        while i < len(args) and args[i].startswith("-") and not re.fullmatch(r"-[0-9.]+", args[i]):
            option = args[i]

            def take(n):
                if i + n >= len(args):
                    raise RadError(where, "xform: %s needs %d argument%s" % (option, n, "s" if n > 1 else ""))
                return [number(v, where, "xform " + option) for v in args[i + 1:i + 1 + n]]

            if option == "-t":
                step, i = translation(take(3)), i + 4
            elif option in ("-rx", "-ry", "-rz"):
                step, i = rotation("xyz".index(option[2]), take(1)[0]), i + 2
            elif option == "-s":
                factor = take(1)[0]
                if factor == 0.0:
                    raise RadError(where, "xform: scale factor 0")
                step, i = scaling((factor, factor, factor)), i + 2
            elif option in ("-mx", "-my", "-mz"):
                flip = [1.0, 1.0, 1.0]
                flip["xyz".index(option[2])] = -1.0
                step, i = scaling(flip), i + 1
            elif option in ("-i", "-a"):
                count = take(1)[0]
                if count != int(count) or count < (0 if option == "-i" else 1):
                    raise RadError(where, "xform: %s needs a %s integer" %
                                   (option, "non-negative" if option == "-i" else "positive"))
                segments.append((option[1], int(count), IDENTITY))
                i += 2
                continue
            else:
                raise RadError(where, "xform: unknown option '%s'" % option)
            kind, count, matrix = segments[-1]
            segments[-1] = (kind, count, matmul(step, matrix))
        self.files = args[i:]
        copies = [IDENTITY]
        for kind, count, matrix in segments:
            if kind == "i":
                power = IDENTITY
                for _ in range(count):
                    power = matmul(matrix, power)
                copies = [matmul(power, m) for m in copies]
            else:
                grown = []
                for m in copies:
                    power = IDENTITY
                    for _ in range(count):
                        grown.append(matmul(power, m))
                        power = matmul(matrix, power)
                copies = grown
        self.matrices = copies

    def apply(self, primitives):
        for m in self.matrices:
            for p in primitives:
                yield p.transformed(m, self.invert, self.prefix, self.modifier)


# ---------------------------------------------------------------- triangulation and tessellation

def triangulate(points):
    """Ear clipping in the polygon's plane; index triples with the polygon's orientation."""
    count = len(points)
    if count == 3:
        return [(0, 1, 2)]
    normal = newell_normal(points)
    axis = max(range(3), key=lambda a: abs(normal[a]))
    if normal[axis] == 0.0:
        return []
    u, v = ((axis + 1) % 3, (axis + 2) % 3) if normal[axis] > 0.0 else ((axis + 2) % 3, (axis + 1) % 3)
    flat = [(p[u], p[v]) for p in points]
    extent = max(max(abs(a), abs(b)) for a, b in flat) or 1.0
    eps = 1e-12 * extent * extent

    def area2(a, b, c):
        return (flat[b][0] - flat[a][0]) * (flat[c][1] - flat[a][1]) - \
               (flat[b][1] - flat[a][1]) * (flat[c][0] - flat[a][0])

    def same(a, b):
        return abs(flat[a][0] - flat[b][0]) <= 1e-9 * extent and abs(flat[a][1] - flat[b][1]) <= 1e-9 * extent

    remaining = list(range(count))
    triangles = []
    while len(remaining) > 3:
        n = len(remaining)
        clipped = False
        for k in range(n):
            a, b, c = remaining[k - 1], remaining[k], remaining[(k + 1) % n]
            if area2(a, b, c) <= eps:
                continue
            blocked = False
            for p in remaining:
                if p in (a, b, c) or same(p, a) or same(p, b) or same(p, c):
                    continue
                if area2(a, b, p) >= -eps and area2(b, c, p) >= -eps and area2(c, a, p) >= -eps:
                    blocked = True
                    break
            if not blocked:
                triangles.append((a, b, c))
                del remaining[k]
                clipped = True
                break
        if clipped:
            continue
        # No ear: drop a vertex that adds no area (collinear or doubled), else clip the most convex corner.
        k = min(range(n), key=lambda k: abs(area2(remaining[k - 1], remaining[k], remaining[(k + 1) % n])))
        a, b, c = remaining[k - 1], remaining[k], remaining[(k + 1) % n]
        if abs(area2(a, b, c)) > eps:
            k = max(range(n), key=lambda k: area2(remaining[k - 1], remaining[k], remaining[(k + 1) % n]))
            triangles.append((remaining[k - 1], remaining[k], remaining[(k + 1) % n]))
        del remaining[k]
    if abs(area2(*remaining)) > eps:
        triangles.append(tuple(remaining))
    return triangles


def circle_segments(radius, options):
    n = int(math.ceil(2.0 * math.pi * radius / options.max_edge / 4.0)) * 4
    return max(8, min(32, n))


class Mesh:
    """Triangles of one material; each primitive has its own vertices (no smoothing across primitives)."""

    def __init__(self):
        self.positions = []
        self.triangles = []

    def add(self, points, triangles):
        base = len(self.positions)
        self.positions.extend(points)
        self.triangles.extend((a + base, b + base, c + base) for a, b, c in triangles)

    def area(self):
        total = 0.0
        for a, b, c in self.triangles:
            total += 0.5 * length(cross(sub(self.positions[b], self.positions[a]),
                                        sub(self.positions[c], self.positions[a])))
        return total


def tessellate(prim, options):
    """Vertices and triangles (counter-clockwise seen from the front) of a surface primitive."""
    r = prim.reals
    if prim.type == "polygon":
        points = [tuple(r[i:i + 3]) for i in range(0, len(r), 3)]
        return points, triangulate(points)
    if prim.type in ("sphere", "bubble"):
        centre, radius = tuple(r[0:3]), abs(r[3])
        n = circle_segments(radius, options)
        rows = n // 2
        points = [add(centre, (0.0, 0.0, radius))]
        for i in range(1, rows):
            theta = math.pi * i / rows
            for j in range(n):
                phi = 2.0 * math.pi * j / n
                points.append(add(centre, mul((math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                                               math.cos(theta)), radius)))
        points.append(add(centre, (0.0, 0.0, -radius)))
        south = len(points) - 1

        def ring(i, j):
            return 1 + (i - 1) * n + j % n

        triangles = []
        for j in range(n):
            triangles.append((0, ring(1, j), ring(1, j + 1)))
            triangles.append((south, ring(rows - 1, j + 1), ring(rows - 1, j)))
        for i in range(1, rows - 1):
            for j in range(n):
                triangles.append((ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)))
                triangles.append((ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)))
        inward = prim.type == "bubble"
    elif prim.type in ("cone", "cup", "cylinder", "tube"):
        p0, p1 = tuple(r[0:3]), tuple(r[3:6])
        r0, r1 = (r[6], r[6]) if prim.type in ("cylinder", "tube") else (r[6], r[7])
        axis = sub(p1, p0)
        if length(axis) == 0.0:
            raise RadError(prim.where, "%s '%s' has zero length" % (prim.type, prim.name))
        if r0 < 0.0 or r1 < 0.0 or r0 == r1 == 0.0:
            raise RadError(prim.where, "%s '%s': radii must not be negative, nor both 0" % (prim.type, prim.name))
        axis = normalize(axis)
        e1, e2 = orthonormal_basis(axis)
        n = circle_segments(max(r0, r1), options)
        points, index = [], []
        for centre, radius in ((p0, r0), (p1, r1)):
            if radius == 0.0:
                points.append(centre)
                index.append([len(points) - 1] * n)
                continue
            row = []
            for j in range(n):
                phi = 2.0 * math.pi * j / n
                points.append(add(centre, add(mul(e1, radius * math.cos(phi)), mul(e2, radius * math.sin(phi)))))
                row.append(len(points) - 1)
            index.append(row)
        triangles = []
        for j in range(n):
            a, b = index[0][j], index[0][(j + 1) % n]
            c, d = index[1][(j + 1) % n], index[1][j]
            if a != b:
                triangles.append((a, b, c))
            if c != d:
                triangles.append((a, c, d))
        inward = prim.type in ("cup", "tube")
        if inward:
            triangles = [(a, c, b) for a, b, c in triangles]
        return points, triangles
    else:  # ring
        centre, direction = tuple(r[0:3]), tuple(r[3:6])
        if length(direction) == 0.0:
            raise RadError(prim.where, "ring '%s' has no normal direction" % prim.name)
        inner, outer = sorted((r[6], r[7]))
        if inner < 0.0 or outer <= 0.0 or inner == outer:
            raise RadError(prim.where, "ring '%s': radii must differ and not be negative" % prim.name)
        axis = normalize(direction)
        e1, e2 = orthonormal_basis(axis)
        n = circle_segments(outer, options)
        points = [centre] if inner == 0.0 else []
        for radius in ((outer,) if inner == 0.0 else (inner, outer)):
            for j in range(n):
                phi = 2.0 * math.pi * j / n
                points.append(add(centre, add(mul(e1, radius * math.cos(phi)), mul(e2, radius * math.sin(phi)))))
        triangles = []
        for j in range(n):
            if inner == 0.0:
                triangles.append((0, 1 + j, 1 + (j + 1) % n))
            else:
                a, b, c, d = j, (j + 1) % n, n + (j + 1) % n, n + j
                triangles.append((a, d, c))
                triangles.append((a, c, b))
        return points, triangles
    if inward != prim.inverted:
        triangles = [(a, c, b) for a, b, c in triangles]
    return points, triangles


# ---------------------------------------------------------------- materials

class Material:
    def __init__(self, prim, patterns):
        self.type = prim.type
        self.name = prim.name
        self.reals = prim.reals
        self.where = prim.where
        self.patterns = patterns   # the dropped pattern/texture primitives it sits on

    def key(self):
        return (self.type, tuple(self.reals))

    def is_emitter(self):
        return self.type in ("light", "glow")


def fmt(x):
    text = "%.6g" % x
    return "0" if text in ("-0", "0") else text


def rgb(values):
    return ", ".join(fmt(v) for v in values)


def bsdf_xml(material, ident, options):
    """The Mitsuba BSDF of a Radiance material (the mapping is documented at the top of the file)."""
    t, r = material.type, material.reals
    if material.is_emitter():
        return None
    if t == "plastic":
        colour, spec, rough = r[0:3], r[3], r[4]
        if spec <= 0.0:
            inner = '<bsdf type="diffuse">\n        <rgb name="reflectance" value="%s"/>\n    </bsdf>' % rgb(colour)
        else:
            root = math.sqrt(min(spec, 0.9))
            ior = (1.0 + root) / (1.0 - root)
            kind = "roughplastic" if rough > 0.0 else "plastic"
            inner = ('<bsdf type="%s">\n        <rgb name="diffuse_reflectance" value="%s"/>\n'
                     '        <float name="int_ior" value="%s"/>\n' % (kind, rgb(colour), fmt(ior)))
            if rough > 0.0:
                inner += ('        <string name="distribution" value="beckmann"/>\n'
                          '        <float name="alpha" value="%s"/>\n' % fmt(min(rough, 4.0)))
            inner += "    </bsdf>"
    elif t in ("metal", "mirror"):
        colour = r[0:3]
        rough = r[4] if t == "metal" else 0.0
        kind = "roughconductor" if rough > 0.0 else "conductor"
        inner = ('<bsdf type="%s">\n        <string name="material" value="none"/>\n'
                 '        <rgb name="specular_reflectance" value="%s"/>\n' % (kind, rgb(colour)))
        if rough > 0.0:
            inner += ('        <string name="distribution" value="beckmann"/>\n'
                      '        <float name="alpha" value="%s"/>\n' % fmt(min(rough, 4.0)))
        inner += "    </bsdf>"
    elif t == "glass":
        return ('<bsdf type="thindielectric" id="%s">\n    <float name="int_ior" value="1.52"/>\n</bsdf>' % ident)
    elif t == "dielectric":
        return ('<bsdf type="dielectric" id="%s">\n    <float name="int_ior" value="%s"/>\n</bsdf>'
                % (ident, fmt(r[3])))
    else:
        raise RadError(material.where, "material type '%s' is not supported" % t)
    return '<bsdf type="twosided" id="%s">\n    %s\n</bsdf>' % (ident, inner)


# ---------------------------------------------------------------- the scene

class Scene:
    def __init__(self, options):
        self.options = options
        self.modifiers = {}      # name -> ('material', Material) | ('pattern', Primitive, [names]) | alias
        self.meshes = {}         # material key -> Mesh
        self.materials = {}      # material key -> Material (first definition)
        self.dropped_patterns = {}   # (name, where) -> (type, arguments, names of the materials using it)
        self.missing = []        # (file, where it was named)
        self.counts = {}
        self.top_directory = None

    # -- modifiers

    def define(self, prim):
        if prim.type in PATTERN_TYPES:
            chain = self.pattern_chain(prim.modifier, prim.where)
            self.modifiers[prim.name] = ("pattern", prim, chain + [prim])
            return
        if prim.type == "alias":
            if len(prim.strings) > 1:
                raise RadError(prim.where, "alias '%s' takes one name" % prim.name)
            target = prim.strings[0] if prim.strings else prim.modifier
            if target not in self.modifiers:
                raise RadError(prim.where, "alias '%s': undefined modifier '%s'" % (prim.name, target))
            self.modifiers[prim.name] = self.modifiers[target]
            return
        if prim.type not in MATERIAL_TYPES:
            raise RadError(prim.where, "primitive type '%s' ('%s') is not supported" % (prim.type, prim.name))
        chain = self.pattern_chain(prim.modifier, prim.where)
        self.modifiers[prim.name] = ("material", Material(prim, chain))

    def pattern_chain(self, modifier, where):
        if modifier == "void":
            return []
        entry = self.modifiers.get(modifier)
        if entry is None:
            raise RadError(where, "undefined modifier '%s'" % modifier)
        if entry[0] != "pattern":
            raise RadError(where, "modifier '%s' is a material, not a pattern" % modifier)
        return entry[2]

    def material_of(self, prim):
        entry = self.modifiers.get(prim.modifier)
        if entry is None:
            raise RadError(prim.where, "%s '%s': undefined modifier '%s'" % (prim.type, prim.name, prim.modifier))
        if entry[0] != "material":
            raise RadError(prim.where, "%s '%s': modifier '%s' is a %s, not a material"
                           % (prim.type, prim.name, prim.modifier, entry[1].type))
        return entry[1]

    # -- surfaces

    def add_surface(self, prim):
        material = self.material_of(prim)
        for pattern in material.patterns:
            record = self.dropped_patterns.setdefault((pattern.name, pattern.where),
                                                      (pattern.type, " ".join(pattern.strings), set()))
            record[2].add(material.name)
        key = material.key()
        if key not in self.meshes:
            self.meshes[key] = Mesh()
            self.materials[key] = material
        points, triangles = tessellate(prim, self.options)
        self.meshes[key].add(points, triangles)
        self.counts[prim.type] = self.counts.get(prim.type, 0) + 1

    def consume(self, primitives):
        for prim in primitives:
            if prim.type in SURFACE_TYPES:
                self.add_surface(prim)
            else:
                self.define(prim)

    # -- files and commands

    def resolve(self, name, directory):
        candidates = [name] if os.path.isabs(name) else \
            [os.path.join(d, name) for d in (directory, self.top_directory, os.getcwd()) if d is not None]
        for path in candidates:
            if os.path.isfile(path):
                return path
        return None

    def read_file(self, path, where=None):
        """Primitives of a file with its commands expanded, as a list."""
        try:
            with open(path, encoding="utf-8", errors="surrogateescape") as f:
                text = f.read()
        except OSError as e:
            raise RadError(where or (path, 0), "cannot read '%s': %s" % (path, e.strerror)) from None
        result = []
        for item in Reader(text, path).items():
            if item[0] == "primitive":
                result.append(item[1])
            else:
                result.extend(self.run_command(item[1], item[2], os.path.dirname(path)))
        return result

    def run_command(self, command, where, directory):
        try:
            lexer = shlex.shlex(command, posix=True, punctuation_chars="|")
            lexer.whitespace_split = True
            lexer.commenters = ""
            words = list(lexer)
        except ValueError as e:
            raise RadError(where, "cannot read command: %s" % e) from None
        stages, current = [], []
        for word in words:
            if word == "|":
                stages.append(current)
                current = []
            else:
                current.append(word)
        stages.append(current)
        if any(not stage for stage in stages):
            raise RadError(where, "empty command in '!%s'" % command.strip())
        primitives = None
        for number_, stage in enumerate(stages):
            program, args = os.path.basename(stage[0]), stage[1:]
            if number_ > 0 and program != "xform":
                raise RadError(where, "only xform may read another command's output, not %s" % program)
            if program == "xform":
                xf = Xform(args, where)
                if number_ > 0:
                    if xf.files:
                        raise RadError(where, "xform after '|' reads its input, it cannot also read %s"
                                       % " ".join(xf.files))
                    primitives = list(xf.apply(primitives))
                    continue
                if not xf.files:
                    raise RadError(where, "xform without a file to read")
                found = []
                for name in xf.files:
                    path = self.resolve(name, directory)
                    if path is None:
                        if self.options.allow_missing:
                            if (name, where) in self.missing:
                                continue
                            self.missing.append((name, where))
                            print("warning: %s:%d: file '%s' not found, left out" % (where[0], where[1], name),
                                  file=sys.stderr)
                            continue
                        raise RadError(where, "file '%s' not found" % name)
                    found.extend(self.read_file(path, where))
                primitives = list(xf.apply(found))
            elif program == "genbox":
                primitives = genbox(args, where, self.options)
            elif program == "genprism":
                primitives = genprism(args, where)
            elif program == "genworm":
                primitives = genworm(args, where)
            else:
                raise RadError(where, "command '%s' is not supported" % program)
        return primitives

    def load(self, paths):
        self.top_directory = os.path.dirname(os.path.abspath(paths[0]))
        for path in paths:
            if not os.path.isfile(path):
                raise RadError((path, 0), "no such file")
            self.consume(self.read_file(path))


# ---------------------------------------------------------------- output

def to_output(p, unit):
    """Radiance z up -> y up, scaled: (x, y, z) -> (x, z, -y) * unit."""
    return (p[0] * unit, p[2] * unit, -p[1] * unit)


def fmt_length(x):
    text = ("%.5f" % x).rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def read_view(path):
    """A Radiance view file or option list (rview/rpict -vt -vp -vd -vu -vh -vv -x -y)."""
    try:
        with open(path, encoding="utf-8") as f:
            words = f.read().split()
    except OSError as e:
        raise RadError((path, 0), "cannot read view: %s" % e.strerror) from None
    view = {"vp": (0.0, 0.0, 0.0), "vd": (0.0, 1.0, 0.0), "vu": (0.0, 0.0, 1.0), "vh": 45.0, "vv": 45.0,
            "x": 512, "y": 512, "vt": "v"}
    i = 0
    while i < len(words):
        w = words[i]
        if w in ("-vp", "-vd", "-vu") and i + 3 < len(words):
            view[w[1:]] = tuple(number(v, (path, 1), w) for v in words[i + 1:i + 4])
            i += 4
        elif w in ("-vh", "-vv") and i + 1 < len(words):
            view[w[1:]] = number(words[i + 1], (path, 1), w)
            i += 2
        elif w in ("-x", "-y") and i + 1 < len(words):
            view[w[1:]] = int(number(words[i + 1], (path, 1), w))
            i += 2
        elif w.startswith("-vt"):
            view["vt"] = w[3:]
            i += 1
        else:
            i += 1
    if view["vt"] != "v":
        raise RadError((path, 1), "only perspective views (-vtv) are supported, not -vt%s" % view["vt"])
    return view


def sanitize(name):
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)


def write_scene(scene, out_dir, name, view):
    options = scene.options
    unit = options.unit
    mesh_dir = os.path.join(out_dir, "meshes")
    os.makedirs(mesh_dir, exist_ok=True)
    used_ids = set()
    lines = ['<scene version="3.0.0">',
             "    <!-- Written by tools/rad2mitsuba.py from %s -->" % " ".join(
                 os.path.basename(p) for p in options.files),
             '    <integrator type="path">', '        <integer name="max_depth" value="9"/>', "    </integrator>"]
    if view is not None:
        origin = to_output(view["vp"], unit)
        target = add(origin, to_output(view["vd"], 1.0))
        up = to_output(view["vu"], 1.0)
        lines += ['    <sensor type="perspective">',
                  '        <float name="fov" value="%s"/>' % fmt(view["vh"]),
                  '        <string name="fov_axis" value="x"/>',
                  '        <transform name="to_world">',
                  '            <lookat origin="%s" target="%s" up="%s"/>' % (
                      ", ".join(fmt_length(c) for c in origin), ", ".join(fmt_length(c) for c in target),
                      ", ".join(fmt(c) for c in up)),
                  "        </transform>",
                  '        <film type="hdrfilm">',
                  '            <integer name="width" value="%d"/>' % view["x"],
                  '            <integer name="height" value="%d"/>' % view["y"],
                  "        </film>",
                  "    </sensor>"]
    summary = []
    for key in sorted(scene.meshes, key=lambda k: scene.materials[k].name):
        material, mesh = scene.materials[key], scene.meshes[key]
        if not mesh.triangles:
            continue
        ident = sanitize(material.name)
        suffix = 2
        while ident in used_ids:
            ident = "%s.%d" % (sanitize(material.name), suffix)
            suffix += 1
        used_ids.add(ident)
        obj = os.path.join("meshes", ident + ".obj")
        write_obj(os.path.join(out_dir, obj), mesh, unit,
                  "%s %s %s (%s:%d)" % (material.type, material.name, " ".join(fmt(v) for v in material.reals),
                                        os.path.basename(material.where[0]), material.where[1]))
        lines.append("")
        lines.append("    <!-- %s %s %s -->" % (material.type, material.name, " ".join(fmt(v) for v in material.reals)))
        if material.is_emitter():
            radiance = [v * options.light_scale for v in material.reals[0:3]]
            lines += ['    <shape type="obj">',
                      '        <string name="filename" value="%s"/>' % obj,
                      '        <bsdf type="diffuse">',
                      '            <rgb name="reflectance" value="0"/>',
                      "        </bsdf>",
                      '        <emitter type="area">',
                      '            <rgb name="radiance" value="%s"/>' % rgb(radiance),
                      "        </emitter>",
                      "    </shape>"]
        else:
            bsdf = bsdf_xml(material, ident, options)
            lines += ["    " + line for line in bsdf.split("\n")]
            lines += ['    <shape type="obj">',
                      '        <string name="filename" value="%s"/>' % obj,
                      '        <ref id="%s"/>' % ident,
                      "    </shape>"]
        summary.append((ident, material, len(mesh.triangles), mesh.area() * unit * unit))
    lines.append("</scene>")
    with open(os.path.join(out_dir, name + ".xml"), "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    return summary


def write_obj(path, mesh, unit, header):
    out = ["# rad2mitsuba: " + header]
    out += ["v %s %s %s" % tuple(fmt_length(c) for c in to_output(p, unit)) for p in mesh.positions]
    out += ["f %d %d %d" % (a + 1, b + 1, c + 1) for a, b, c in mesh.triangles]
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(out) + "\n")


def report(scene, summary):
    total = sum(s[2] for s in summary)
    print("%d triangles in %d meshes" % (total, len(summary)))
    print("primitives: " + ", ".join("%s %d" % kv for kv in sorted(scene.counts.items())))
    for ident, material, triangles, area in summary:
        print("  %-28s %-10s %7d triangles %9.3f m2" % (ident, material.type, triangles, area))
    for (name, where), (type_, args, users) in sorted(scene.dropped_patterns.items()):
        print("dropped %s %s (%s) at %s:%d, used by %s" % (type_, name, args, where[0], where[1],
                                                          ", ".join(sorted(users))))
    for name, where in scene.missing:
        print("missing file %s named at %s:%d" % (name, where[0], where[1]))


def main(argv):
    parser = argparse.ArgumentParser(
        prog="rad2mitsuba.py", description=__doc__.split("\n\n")[0],
        usage="%(prog)s [-o DIR] [--name NAME] [--view FILE.vf] [--unit METRES] [--max-edge LEN] "
              "[--light-scale S] [--allow-missing] FILE.rad ...")
    parser.add_argument("files", nargs="+", metavar="FILE.rad")
    parser.add_argument("-o", "--output", default=".", metavar="DIR", help="output directory (default .)")
    parser.add_argument("--name", default="scene", help="stem of the XML file (default scene)")
    parser.add_argument("--view", metavar="FILE.vf", help="Radiance view file for the camera")
    parser.add_argument("--unit", type=float, default=0.3048,
                        help="output length of one input unit (default 0.3048: feet to metres)")
    parser.add_argument("--max-edge", type=float, default=0.1, metavar="LEN",
                        help="segment length of tessellated circles, input units (default 0.1)")
    parser.add_argument("--light-scale", type=float, default=1.0, metavar="S",
                        help="factor on the radiance of light and glow materials (default 1)")
    parser.add_argument("--allow-missing", action="store_true",
                        help="skip files named by commands that do not exist (listed at the end)")
    options = parser.parse_args(argv[1:])
    if not (options.unit > 0.0 and options.max_edge > 0.0 and options.light_scale >= 0.0):
        parser.error("--unit and --max-edge must be positive, --light-scale not negative")
    try:
        scene = Scene(options)
        scene.load(options.files)
        if not scene.meshes:
            raise RadError((options.files[0], 0), "no surfaces")
        view = read_view(options.view) if options.view else None
        summary = write_scene(scene, options.output, options.name, view)
    except RadError as e:
        print("rad2mitsuba: %s" % e, file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as e:
        print("rad2mitsuba: %s: %s" % (e.filename, e.strerror), file=sys.stderr)
        return EXIT_BAD_INPUT
    report(scene, summary)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
