#!/usr/bin/env python3
"""Checks tools/rad2mitsuba.py on small hand-written Radiance scenes.

    test_rad_converter.py [WORK_DIR]

Each case writes a scene into WORK_DIR (default: a temporary directory),
converts it with --unit 1 (so output = (x, z, -y) of the input) and checks
the OBJ meshes and the Mitsuba XML: polygon triangulation (area and normal),
genbox plain, bevelled and rounded, genprism, genworm, xform chains (-t, -r*,
-s, -m*, -i, -a, nested files), tessellated cylinder, cone, ring and sphere
areas within 1 % of the analytic ones, the material mapping, and that bad
input exits with code 2 naming the file and line. Exits 1 on any failure.
"""

import math
import os
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CONVERTER = os.path.join(ROOT, "tools", "rad2mitsuba.py")

failures = []


def check(condition, message):
    if not condition:
        failures.append(message)
        print("FAIL: " + message)


def close(a, b, rel=1e-6, absolute=1e-6):
    return abs(a - b) <= max(absolute, rel * abs(b))


def convert(work, name, files, extra=()):
    """Writes `files` ({relative path: text}) under work/name, converts the first; (rc, stdout, stderr, dir)."""
    case = os.path.join(work, name)
    os.makedirs(case, exist_ok=True)
    for rel, text in files.items():
        path = os.path.join(case, rel)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write(text)
    out = os.path.join(case, "out")
    main = os.path.join(case, next(iter(files)))
    result = subprocess.run([sys.executable, CONVERTER, "-o", out, "--name", "scene", "--unit", "1", *extra, main],
                            capture_output=True, text=True, timeout=60)
    return result.returncode, result.stdout, result.stderr, out


def read_obj(path):
    positions, triangles = [], []
    with open(path) as f:
        for line in f:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                positions.append(tuple(float(v) for v in parts[1:4]))
            elif parts[0] == "f":
                triangles.append(tuple(int(v) - 1 for v in parts[1:4]))
    return positions, triangles


def sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def norm(a):
    return math.sqrt(sum(x * x for x in a))


def triangle_normals(mesh):
    """(area-weighted normal, centroid) per triangle."""
    positions, triangles = mesh
    result = []
    for a, b, c in triangles:
        pa, pb, pc = positions[a], positions[b], positions[c]
        n = cross(sub(pb, pa), sub(pc, pa))
        result.append((tuple(0.5 * x for x in n), tuple((pa[k] + pb[k] + pc[k]) / 3.0 for k in range(3))))
    return result


def area(mesh):
    return sum(norm(n) for n, _ in triangle_normals(mesh))


def mesh_of(out, ident):
    return read_obj(os.path.join(out, "meshes", ident + ".obj"))


def material_header(rgb="0.5 0.5 0.5"):
    return "void plastic grey\n0\n0\n5 %s 0 0\n\n" % rgb


def ok(name, rc, err):
    check(rc == 0, "%s: converter failed (exit %d): %s" % (name, rc, err.strip()))
    return rc == 0


# ---------------------------------------------------------------- cases

def test_polygons(work):
    scene = material_header() + (
        # A 2 x 3 rectangle in z = 0, counter-clockwise seen from +z: output normal +y.
        "grey polygon rect\n0\n0\n12\n0 0 0  2 0 0  2 3 0  0 3 0\n\n")
    rc, _, err, out = convert(work, "polygon", {"scene.rad": scene})
    if not ok("polygon", rc, err):
        return
    mesh = mesh_of(out, "grey")
    check(len(mesh[1]) == 2, "polygon: a quadrilateral gives 2 triangles, got %d" % len(mesh[1]))
    check(close(area(mesh), 6.0), "polygon: area %g, expected 6" % area(mesh))
    for n, _ in triangle_normals(mesh):
        unit = tuple(x / norm(n) for x in n)
        check(close(unit[1], 1.0), "polygon: z-up normal must become +y, got %s" % (unit,))

    # Non-convex (an L) and a Radiance keyhole polygon: a 4 x 4 square with a 2 x 2 hole joined
    # by a doubled edge (as conf.rad cuts the projection window into big_shaft.4620).
    scene = material_header() + (
        "grey polygon ell\n0\n0\n18\n0 0 0  3 0 0  3 1 0  1 1 0  1 3 0  0 3 0\n\n")
    rc, _, err, out = convert(work, "polygon-l", {"scene.rad": scene})
    if ok("polygon-l", rc, err):
        check(close(area(mesh_of(out, "grey")), 5.0), "L polygon: area %g, expected 5" % area(mesh_of(out, "grey")))
        for n, _ in triangle_normals(mesh_of(out, "grey")):
            check(n[1] > 0.0, "L polygon: every triangle faces +y")
    scene = material_header() + (
        "grey polygon keyhole\n0\n0\n30\n"
        "0 0 0  4 0 0  4 4 0  0 4 0  0 1 0  1 1 0  1 3 0  3 3 0  3 1 0  0 1 0\n\n")
    rc, _, err, out = convert(work, "polygon-keyhole", {"scene.rad": scene})
    if ok("polygon-keyhole", rc, err):
        mesh = mesh_of(out, "grey")
        check(close(area(mesh), 12.0), "keyhole polygon: area %g, expected 16 - 4 = 12" % area(mesh))
        inside_hole = [c for _, c in triangle_normals(mesh) if 1.0 < c[0] < 3.0 and 1.0 < -c[2] < 3.0]
        check(not inside_hole, "keyhole polygon: no triangle may cover the hole")


def test_genbox(work):
    x, y, z = 2.0, 3.0, 4.0
    plain = 2 * (x * y + y * z + z * x)
    for label, option, expected, tolerance in (
            ("plain", "", plain, 1e-6),
            ("bevel", "-b .5", plain - 0.5 * 0.5 * (12 * 2.0) - 8 * 0.5 * 0.5 * 1.5
             + 0.5 * math.sqrt(2.0) * 4 * ((x - 1) + (y - 1) + (z - 1)) + 8 * math.sqrt(3) / 2 * 0.25, 1e-6),
            ("round", "-r .5", None, 0.01)):
        if label == "round":
            r = 0.5
            expected = (2 * ((x - 2 * r) * (y - 2 * r) + (y - 2 * r) * (z - 2 * r) + (z - 2 * r) * (x - 2 * r))
                        + 4 * ((x - 2 * r) + (y - 2 * r) + (z - 2 * r)) * (math.pi * r / 2) + 4 * math.pi * r * r)
        if label == "bevel":
            b = 0.5
            expected = (2 * ((x - 2 * b) * (y - 2 * b) + (y - 2 * b) * (z - 2 * b) + (z - 2 * b) * (x - 2 * b))
                        + 4 * ((x - 2 * b) + (y - 2 * b) + (z - 2 * b)) * b * math.sqrt(2.0)
                        + 8 * math.sqrt(3) / 2 * b * b)
        scene = material_header() + "!genbox grey box %g %g %g %s\n" % (x, y, z, option)
        rc, _, err, out = convert(work, "genbox-" + label, {"scene.rad": scene}, ["--max-edge", "0.05"])
        if not ok("genbox " + label, rc, err):
            continue
        mesh = mesh_of(out, "grey")
        got = area(mesh)
        check(abs(got - expected) <= tolerance * expected,
              "genbox %s: area %g, expected %g (within %g %%)" % (label, got, expected, 100 * tolerance))
        # Every face looks outward: from the box centre (output frame) to the triangle.
        centre = (x / 2, z / 2, -y / 2)
        inward = [c for n, c in triangle_normals(mesh) if sum(n[k] * (c[k] - centre[k]) for k in range(3)) <= 0]
        check(not inward, "genbox %s: %d triangles face inward" % (label, len(inward)))
        lo = [min(p[k] for p in mesh[0]) for k in range(3)]
        hi = [max(p[k] for p in mesh[0]) for k in range(3)]
        check(all(close(a, b) for a, b in zip(lo + hi, [0, 0, -y, x, z, 0])),
              "genbox %s: bounds %s %s, expected [0, %g] x [0, %g] x [-%g, 0]" % (label, lo, hi, x, z, y))
    # -i turns the faces inward.
    scene = material_header() + "!genbox grey box 1 1 1 -i\n"
    rc, _, err, out = convert(work, "genbox-inward", {"scene.rad": scene})
    if ok("genbox -i", rc, err):
        outward = [c for n, c in triangle_normals(mesh_of(out, "grey"))
                   if sum(n[k] * (c[k] - (0.5, 0.5, -0.5)[k]) for k in range(3)) > 0]
        check(not outward, "genbox -i: %d triangles face outward" % len(outward))


def test_genprism_genworm(work):
    # A right triangle (legs 3 and 4) extruded by 2: caps 2 * 6, sides (3 + 4 + 5) * 2.
    scene = material_header() + "!genprism grey prism 3 0 0 3 0 0 4 -l 0 0 2\n"
    rc, _, err, out = convert(work, "genprism", {"scene.rad": scene})
    if ok("genprism", rc, err):
        check(close(area(mesh_of(out, "grey")), 36.0), "genprism: area %g, expected 36" % area(mesh_of(out, "grey")))
    scene = material_header() + "!genprism grey strip 3 0 0 3 0 0 4 -l 0 0 2 -e -c\n"
    rc, _, err, out = convert(work, "genprism-open", {"scene.rad": scene})
    if ok("genprism -e -c", rc, err):
        check(close(area(mesh_of(out, "grey")), 16.0),
              "genprism -e -c: area %g, expected (3 + 5) * 2 = 16 (no closing side)" % area(mesh_of(out, "grey")))
    # A straight worm of constant radius: 3 spheres and 2 cylinders along x.
    scene = material_header() + "!genworm grey worm '2*t' 0 0 'r' 2 -e 'r=.5'\n"
    rc, stdout, err, out = convert(work, "genworm", {"scene.rad": scene})
    if ok("genworm", rc, err):
        check("cylinder 2" in stdout and "sphere 3" in stdout,
              "genworm: expected 2 cylinders and 3 spheres, report: %s" % stdout.splitlines()[1])
        xs = [p[0] for p in mesh_of(out, "grey")[0]]
        check(close(min(xs), -0.5, 1e-3) and close(max(xs), 2.5, 1e-3),
              "genworm: x from -0.5 to 2.5, got %g to %g" % (min(xs), max(xs)))


def test_xform(work):
    triangle = material_header() + "grey polygon tri\n0\n0\n9\n1 0 0  0 1 0  0 0 0\n"
    cases = [
        # (arguments, where the vertex (1, 0, 0) goes in Radiance coordinates)
        ("-t 1 2 3", [(2, 2, 3)]),
        ("-rz 90", [(0, 1, 0)]),
        ("-rx 90 -t 0 0 1", [(1, 0, 1)]),
        ("-ry 90", [(0, 0, -1)]),
        ("-s 2 -t 1 0 0", [(3, 0, 0)]),
        ("-t 1 0 0 -s 2", [(4, 0, 0)]),
        ("-mx", [(-1, 0, 0)]),
        ("-i 3 -t 1 0 0", [(4, 0, 0)]),
        ("-t 0 0 5 -a 3 -t 2 0 0", [(1, 0, 5), (3, 0, 5), (5, 0, 5)]),
        ("-a 2 -t 1 0 0 -a 2 -t 0 1 0", [(1, 0, 0), (2, 0, 0), (1, 1, 0), (2, 1, 0)]),
    ]
    for k, (args, expected) in enumerate(cases):
        scene = "!xform %s part.rad\n" % args
        rc, _, err, out = convert(work, "xform-%d" % k, {"scene.rad": scene, "part.rad": triangle})
        if not ok("xform " + args, rc, err):
            continue
        positions = mesh_of(out, "grey")[0]
        corner = [p for i, p in enumerate(positions)]
        got = sorted(tuple(round(c, 6) for c in p) for p in corner)
        want_points = [(e[0], e[2], -e[1]) for e in expected]
        for w in want_points:
            check(any(all(close(a, b) for a, b in zip(g, w)) for g in got),
                  "xform %s: vertex (1, 0, 0) should reach %s (output %s); vertices %s" % (args, expected, w, got))
        check(len(positions) == 3 * len(expected), "xform %s: %d copies expected" % (args, len(expected)))
        # Orientation: the triangle faces +z in Radiance; -mx keeps it facing +z (xform reverses it).
        if args == "-mx":
            n, _ = triangle_normals(mesh_of(out, "grey"))[0]
            check(n[1] > 0, "xform -mx: the mirrored polygon must keep facing up")
    # Chains through pipes and nested files: a file in lib/ names a bare file next to it.
    files = {
        "scene.rad": material_header() + "!xform -n outer -t 10 0 0 lib/outer.rad\n"
                     "!genbox grey b 1 1 1 | xform -s 2 | xform -t 0 0 1\n",
        "lib/outer.rad": "!xform -n inner -t 0 5 0 inner.rad\n",
        "lib/inner.rad": "grey polygon p\n0\n0\n9\n0 0 0  1 0 0  0 1 0\n",
    }
    rc, _, err, out = convert(work, "xform-nested", files)
    if ok("xform nested", rc, err):
        positions = mesh_of(out, "grey")[0]
        check(any(all(close(a, b) for a, b in zip(p, (10, 0, -5))) for p in positions),
              "nested xform: lib/inner.rad's origin should land at (10, 5, 0)")
        box_top = max(p[1] for p in positions)
        check(close(box_top, 3.0), "genbox | xform -s 2 | xform -t 0 0 1: top at z = 3, got %g" % box_top)


def test_tessellation(work):
    cases = [
        ("cylinder", "7 0 0 0  0 0 2  1", 2 * math.pi * 1 * 2),
        ("cone", "8 0 0 0  0 0 1  1 .5", math.pi * 1.5 * math.sqrt(1 + 0.25)),
        ("cone", "8 0 0 0  0 0 1  1 0", math.pi * 1 * math.sqrt(2)),
        ("ring", "8 0 0 0  0 0 1  .5 1", math.pi * (1 - 0.25)),
        ("ring", "8 0 0 0  1 1 1  0 1.5", math.pi * 2.25),
        ("sphere", "4 1 2 3 1", 4 * math.pi),
        ("tube", "7 0 0 0  3 0 0  2", 2 * math.pi * 2 * 3),
    ]
    for k, (type_, args, expected) in enumerate(cases):
        scene = material_header() + "grey %s s\n0\n0\n%s\n" % (type_, args)
        rc, _, err, out = convert(work, "tess-%d" % k, {"scene.rad": scene})
        if not ok(type_, rc, err):
            continue
        mesh = mesh_of(out, "grey")
        got = area(mesh)
        check(abs(got - expected) <= 0.01 * expected,
              "%s %s: area %g, analytic %g (%.2f %%)" % (type_, args, got, expected, 100 * (got / expected - 1)))
        if type_ == "ring":
            n = tuple(sum(t[0][i] for t in triangle_normals(mesh)) for i in range(3))
            d = [float(v) for v in args.split()[4:7]]
            d = (d[0], d[2], -d[1])
            check(sum(a * b for a, b in zip(n, d)) > 0, "ring %s: faces along its direction" % args)
        if type_ == "sphere":
            centre = (1, 3, -2)
            radii = [norm(sub(p, centre)) for p in mesh[0]]
            check(all(close(r, 1.0, 1e-4) for r in radii), "sphere: vertices on the sphere around (1, 3, -2)")
            inward = [c for n, c in triangle_normals(mesh) if sum(n[i] * (c[i] - centre[i]) for i in range(3)) <= 0]
            check(not inward, "sphere: %d triangles face inward" % len(inward))


def test_materials(work):
    scene = (
        "void plastic matte\n0\n0\n5 .6 .5 .4 0 0\n\n"
        "void plastic shiny\n0\n0\n5 .2 .3 .4 .05 .1\n\n"
        "void plastic smooth\n0\n0\n5 .2 .3 .4 .02 0\n\n"
        "void metal brushed\n0\n0\n5 .7 .7 .7 .9 .2\n\n"
        "void metal chrome\n0\n0\n5 .6 .6 .6 .95 0\n\n"
        "void glass pane\n0\n0\n3 .96 .96 .96\n\n"
        "void light lamp\n0\n0\n3 10 9 8\n\n"
        "void glow sign\n0\n0\n4 1 .05 .025 0\n\n"
        "void brightfunc dirt\n4 dirt dirt.cal -s .1\n0\n1 .2\n\n"
        "dirt plastic dirty\n0\n0\n5 .3 .3 .3 0 0\n\n")
    for k, name in enumerate(("matte", "shiny", "smooth", "brushed", "chrome", "pane", "lamp", "sign", "dirty")):
        scene += "%s polygon p%d\n0\n0\n9\n%d 0 0  %d 1 0  %d 0 1\n\n" % (name, k, k, k, k)
    rc, stdout, err, out = convert(work, "materials", {"scene.rad": scene}, ["--light-scale", "2"])
    if not ok("materials", rc, err):
        return
    root = ET.parse(os.path.join(out, "scene.xml")).getroot()
    bsdfs = {b.get("id"): b for b in root.findall("bsdf")}

    def inner(ident):
        b = bsdfs.get(ident)
        if b is None:
            return None
        return b.find("bsdf") if b.get("type") == "twosided" else b

    def value(element, tag, name):
        found = [e for e in element.findall(tag) if e.get("name") == name]
        return found[0].get("value") if found else None

    check(inner("matte") is not None and inner("matte").get("type") == "diffuse"
          and value(inner("matte"), "rgb", "reflectance") == "0.6, 0.5, 0.4", "plastic without specular -> diffuse")
    shiny = inner("shiny")
    check(shiny is not None and shiny.get("type") == "roughplastic", "plastic .05 .1 -> roughplastic")
    if shiny is not None:
        check(value(shiny, "float", "alpha") == "0.1" and value(shiny, "string", "distribution") == "beckmann",
              "roughplastic: Beckmann alpha = Radiance roughness")
        ior = float(value(shiny, "float", "int_ior"))
        check(close(((ior - 1) / (ior + 1)) ** 2, 0.05, 1e-4), "roughplastic: Fresnel F0 of int_ior = specularity")
    check(inner("smooth") is not None and inner("smooth").get("type") == "plastic", "plastic .02 0 -> plastic")
    brushed = inner("brushed")
    check(brushed is not None and brushed.get("type") == "roughconductor"
          and value(brushed, "float", "alpha") == "0.2"
          and value(brushed, "rgb", "specular_reflectance") == "0.7, 0.7, 0.7", "metal .9 .2 -> roughconductor")
    check(inner("chrome") is not None and inner("chrome").get("type") == "conductor", "metal rough 0 -> conductor")
    check(bsdfs.get("pane") is not None and bsdfs["pane"].get("type") == "thindielectric", "glass -> thindielectric")
    check(all(b.get("type") == "twosided" for i, b in bsdfs.items() if i != "pane"),
          "opaque materials are two-sided as in Radiance")
    emitters = {}
    for shape in root.findall("shape"):
        filename = value(shape, "string", "filename")
        emitter = shape.find("emitter")
        if emitter is not None:
            emitters[os.path.basename(filename)] = value(emitter, "rgb", "radiance")
    check(emitters.get("lamp.obj") == "20, 18, 16", "light -> area emitter, radiance x --light-scale: %s" % emitters)
    check(emitters.get("sign.obj") == "2, 0.1, 0.05", "glow -> area emitter: %s" % emitters)
    check("dropped brightfunc dirt" in stdout, "the dropped pattern is reported")
    check(inner("dirty") is not None and value(inner("dirty"), "rgb", "reflectance") == "0.3, 0.3, 0.3",
          "a material on a dropped pattern keeps its colour")


def test_bad_input(work):
    cases = [
        ("undefined", material_header() + "\n\nnothing polygon p\n0\n0\n9\n0 0 0 1 0 0 0 1 0\n",
         "scene.rad:8:", "undefined modifier 'nothing'"),
        ("not-a-number", material_header() + "grey polygon p\n0\n0\n9\n0 0 0\n1 zero 0\n0 1 0\n",
         "scene.rad:11:", "expected a number"),
        ("short", material_header() + "grey sphere s\n0\n0\n3 0 0 0\n", "scene.rad:6:", "needs 4 real arguments"),
        ("missing", material_header() + "\n!xform -t 1 0 0 nowhere.rad\n", "scene.rad:7:", "'nowhere.rad' not found"),
        ("command", material_header() + "!gensurf grey s x y z 4 4\n", "scene.rad:6:", "not supported"),
        ("type", material_header() + "grey mesh m\n1 m.rtm\n0\n0\n", "scene.rad:6:", "not supported"),
    ]
    for label, scene, where, message in cases:
        rc, _, err, _ = convert(work, "bad-" + label, {"scene.rad": scene})
        check(rc == 2, "bad input (%s): exit code %d, expected 2" % (label, rc))
        lines = err.strip().splitlines()
        check(len(lines) == 1 and where in err and message in err,
              "bad input (%s): one line naming %s and '%s', got: %s" % (label, where, message, err.strip()))
    # The usage line for a bad command line.
    result = subprocess.run([sys.executable, CONVERTER], capture_output=True, text=True, timeout=60)
    check(result.returncode == 2 and "usage:" in result.stderr, "no arguments: usage and exit code 2")
    # --allow-missing skips the file and lists it.
    rc, stdout, _, _ = convert(work, "allow-missing",
                               {"scene.rad": material_header() + "!genbox grey b 1 1 1\n!xform nowhere.rad\n"},
                               ["--allow-missing"])
    check(rc == 0 and "missing file nowhere.rad" in stdout, "--allow-missing: skipped and listed")


def main(argv):
    work = argv[1] if len(argv) > 1 else tempfile.mkdtemp(prefix="rad2mitsuba-")
    os.makedirs(work, exist_ok=True)
    for test in (test_polygons, test_genbox, test_genprism_genworm, test_xform, test_tessellation, test_materials,
                 test_bad_input):
        test(work)
    if failures:
        print("%d check(s) failed" % len(failures))
        return 1
    print("rad2mitsuba: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
