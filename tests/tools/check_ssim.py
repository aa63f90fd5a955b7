#!/usr/bin/env python3
"""Checks `fluxgraph compare` against independent implementations.

SSIM is compared with scikit-image's structural_similarity (Gaussian window,
sigma 1.5, population covariance, data_range 1) on the luminance the README
defines, Y / (1 + Y); RMSE, relMSE, MAE and PSNR with numpy. The image pairs
are generated here and written as PFM (32-bit float, read by OpenImageIO), so
nothing but Debian's python3-numpy and python3-skimage is needed.

usage: check_ssim.py FLUXGRAPH_BINARY SCRATCH_DIRECTORY
Exit status 0 when every metric agrees, 1 otherwise (also when scikit-image
is missing: tools/install-deps.sh installs python3-skimage).
"""
import os
import subprocess
import sys

try:
    import numpy as np
    from skimage.metrics import structural_similarity
except ImportError as error:
    print(f"check_ssim: FAILED: {error}; {sys.executable} needs Debian's python3-numpy and "
          "python3-skimage (tools/install-deps.sh installs them)")
    sys.exit(1)

SSIM_TOLERANCE = 1e-4
RELATIVE_TOLERANCE = 1e-6


def write_pfm(path, rgb):
    """rgb: float32 array (height, width, 3), top row first; PFM stores the bottom row first."""
    height, width, _ = rgb.shape
    with open(path, "wb") as f:
        f.write(b"PF\n%d %d\n-1.0\n" % (width, height))
        f.write(np.ascontiguousarray(rgb[::-1]).astype("<f4").tobytes())


def tone_mapped_luminance(rgb):
    y = 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]
    y = np.maximum(y, 0.0)
    return y / (1.0 + y)


def expected_metrics(test, reference):
    test = test.astype(np.float64)
    reference = reference.astype(np.float64)
    difference = test - reference
    mse = np.mean(difference ** 2)
    return {
        "rmse": np.sqrt(mse),
        "relmse": np.mean(difference ** 2 / (reference + 0.01) ** 2),
        "mae": np.mean(np.abs(difference)),
        "psnr": -10.0 * np.log10(mse),
        "ssim": structural_similarity(tone_mapped_luminance(test), tone_mapped_luminance(reference),
                                      gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                      data_range=1.0),
    }


def smooth_hdr_scene(rng, height, width):
    """Gradients, a soft bright highlight well above 1 and a sharp-edged block: structure at several scales."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    base = 0.05 + 0.6 * (x / width) * (1.0 - y / height)
    highlight = 40.0 * np.exp(-((x - 0.7 * width) ** 2 + (y - 0.3 * height) ** 2) / (2.0 * 3.0 ** 2))
    block = np.where((x > 0.15 * width) & (x < 0.45 * width) & (y > 0.5 * height), 2.5, 0.0)
    tint = np.array([1.0, 0.8, 0.55])
    image = (base + highlight + block)[..., None] * tint + 0.02 * rng.random((height, width, 3))
    return image.astype(np.float32)


def box_blur(image):
    padded = np.pad(image, ((1, 1), (1, 1), (0, 0)), mode="edge")
    out = sum(padded[dy:dy + image.shape[0], dx:dx + image.shape[1]] for dy in range(3) for dx in range(3))
    return (out / 9.0).astype(np.float32)


def run_compare(binary, test_path, reference_path, extra):
    command = [binary, "compare", test_path, reference_path, "--metric", "all", *extra]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {result.returncode}: {result.stderr.strip()}")
    values = {}
    for line in result.stdout.splitlines():
        name, value = line.split()
        values[name] = float(value)
    return values


def main():
    if len(sys.argv) != 3:
        print(__doc__)
        return 1
    binary, scratch = sys.argv[1], sys.argv[2]
    os.makedirs(scratch, exist_ok=True)
    rng = np.random.default_rng(20240611)
    height, width = 41, 53  # not square, so a transposed image would show
    reference = smooth_hdr_scene(rng, height, width)
    noisy = (reference * (1.0 + 0.3 * rng.standard_normal(reference.shape))).clip(0.0, None).astype(np.float32)
    # Firefly-like outliers: a few pixels far above the reference.
    for _ in range(6):
        noisy[rng.integers(height), rng.integers(width)] += 25.0
    blurred_brighter = (1.2 * box_blur(reference)).astype(np.float32)

    paths = {name: os.path.join(scratch, name + ".pfm") for name in ("reference", "noisy", "blurred")}
    write_pfm(paths["reference"], reference)
    write_pfm(paths["noisy"], noisy)
    write_pfm(paths["blurred"], blurred_brighter)

    crop_x, crop_y, crop_w, crop_h = 7, 3, 30, 25
    cases = [
        ("noisy", noisy, reference, []),
        ("blurred", blurred_brighter, reference, []),
        ("noisy crop", noisy[crop_y:crop_y + crop_h, crop_x:crop_x + crop_w],
         reference[crop_y:crop_y + crop_h, crop_x:crop_x + crop_w], ["--crop", f"{crop_x},{crop_y},{crop_w},{crop_h}"]),
    ]
    failures = 0
    for label, test, ref, extra in cases:
        test_path = paths["noisy" if label.startswith("noisy") else "blurred"]
        got = run_compare(binary, test_path, paths["reference"], extra)
        want = expected_metrics(test, ref)
        for name, expected in want.items():
            actual = got.get(name)
            if name == "ssim":
                ok = actual is not None and abs(actual - expected) <= SSIM_TOLERANCE
            else:
                ok = actual is not None and abs(actual - expected) <= RELATIVE_TOLERANCE * abs(expected)
            print(f"{'ok  ' if ok else 'FAIL'} {label:11s} {name:6s} fluxgraph {actual!s:>22s}  expected {expected:.10g}")
            failures += 0 if ok else 1
    if failures:
        print(f"check_ssim: FAILED: {failures} metric(s) disagree")
        return 1
    print("check_ssim: all metrics agree")
    return 0


if __name__ == "__main__":
    sys.exit(main())
