#!/usr/bin/env python3
"""How PDS's advantage over SPM on the refraction case study depends on the
wave: data/water-wave-sine (a single sinusoid under collimated light, Frisvad
et al. 2014 §4.1) rebuilt with other wave amplitudes, everything else as
committed (wavelength, floor depth, light, camera, eye sampling, the caustic
reference's job), each measured as tools/caustics_report.py measures its case
studies: a 40M-photon caustic reference, then at ~20k caustic photons SPM's k
and PDS's s swept with 4 independent photon sets each, the RMSE-optimal PDS /
SPM ratio on linear and on display values (clamped to [0, 1]).

The paper does not give its wave's amplitude, depth or wavelength. What the
amplitude changes is where the floor lies relative to the crests' focal depth
f = n / ((n - 1) A k^2) (a crest of height A sin(k x) has curvature A k^2;
n = 1.33): before it, the caustic is smooth; just past it, every crest draws a
fold line; far past it, the folds cross.

Each amplitude renders its own reference (3.32G photon paths, about 4 minutes
on 2 cores, 4.5 GB), so the whole run takes about 20 minutes.
Usage: tools/wave_amplitude_report.py [--build DIR] [--amplitude A ...]
Prints a Markdown table; the scenes are built in a temporary folder.
"""
import argparse
import math
import shutil
import subprocess
import tempfile
from pathlib import Path

import caustics_report as report
import make_geometry

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "data" / "water-wave-sine"
# The committed scene's wave train (tools/make_geometry.py SCENE_MESHES).
COMMITTED = make_geometry.WATER_WAVES[0]
REFRACTIVE_INDEX = 1.33
WAVE_HEIGHT = 1.0  # above the floor, as in data/water-wave-sine


def build_scene(folder, amplitude):
    """data/water-wave-sine with the wave's amplitude replaced, in folder/water-wave-sine/."""
    scene = folder / "water-wave-sine"
    (scene / "meshes").mkdir(parents=True)
    (scene / "reference").mkdir()
    shutil.copy(SCENE / "water-wave-sine.xml", scene)
    wave = (amplitude,) + tuple(COMMITTED[1:])
    mesh = make_geometry.build("wave", dict(size=1.4, grid=80, height=WAVE_HEIGHT, waves=[wave]))
    make_geometry.write_obj(mesh, str(scene / "meshes" / "wave.obj"), [f"wave amplitude {amplitude}"])
    shutil.copy(SCENE / "caustic-reference.toml", scene)
    return scene


def render_reference(binary, scene):
    subprocess.run([str(binary), "render", str(scene / "caustic-reference.toml"), "-q", "--out",
                    str(scene / "reference"), "--set", "output.half=true"], check=True)


def measure(runner, scene):
    study = report.Study(scene, caustic=True)
    emitted = report.emitted_for(runner, study.scene, report.CAUSTIC_TARGET, study.tag)
    spm, pds = report.sweeps(runner, study, emitted, report.SWEEP_KS, report.SWEEP_SS, report.REPEATS)
    result = {}
    for key in ("rmse", "rmse_display"):
        a, b = report.best(spm, key), report.best(pds, key)
        result[key] = (a, b, b[key] / a[key])
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--build", default="build")
    parser.add_argument("--amplitude", type=float, action="append",
                        help="wave amplitude (repeatable); default 0.5, 0.75, 1 and 1.5 times the committed one")
    args = parser.parse_args()
    amplitudes = args.amplitude or [COMMITTED[0] * f for f in (0.5, 0.75, 1.0, 1.5)]
    if any(not a > 0.0 for a in amplitudes):
        report.fail("wave_amplitude_report.py: amplitudes must be positive")
    wavenumber = 2.0 * math.pi / COMMITTED[1]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        runner = report.Runner(ROOT / args.build, Path(tmp))
        for i, amplitude in enumerate(amplitudes):
            scene = build_scene(Path(tmp) / f"a{i}", amplitude)
            print(f"== amplitude {amplitude:g}: reference", flush=True)
            render_reference(runner.binary, scene)
            print(f"== amplitude {amplitude:g}: sweeps", flush=True)
            focal = REFRACTIVE_INDEX / ((REFRACTIVE_INDEX - 1.0) * amplitude * wavenumber ** 2)
            rows.append((amplitude, WAVE_HEIGHT / focal, measure(runner, scene)))

    def cell(result, key, name):
        row = result[key][0] if name == "k" else result[key][1]
        return f"{row[key]:.4f} ({name} = {row[name]}{report.EDGE if row['edge'] else ''})"

    lines = ["| amplitude | floor depth / focal depth | SPM best RMSE | PDS best RMSE | PDS / SPM | "
             "on display values: SPM | PDS | PDS / SPM |", "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for amplitude, depth, result in rows:
        mark = " (committed)" if math.isclose(amplitude, COMMITTED[0]) else ""
        lines.append(f"| {amplitude:g}{mark} | {depth:.2f} | {cell(result, 'rmse', 'k')} | {cell(result, 'rmse', 's')} | "
                     f"**{result['rmse'][2]:.3f}** | {cell(result, 'rmse_display', 'k')} | "
                     f"{cell(result, 'rmse_display', 's')} | {result['rmse_display'][2]:.3f} |")
    lines.append(f"\n{report.EDGE} the optimum lies at the end of the sweep.")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
