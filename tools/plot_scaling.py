#!/usr/bin/env python3
"""Draws the CSV of `fluxgraph scale` as a PNG: speed-up against thread count,
one line per pass and one for the whole pipeline, with the ideal S(N) = N.

    tools/plot_scaling.py scale.csv scaling.png

Needs Debian's python3-matplotlib (tools/install-deps.sh installs it). On any
failure it prints one line to stderr and exits with code 1.
"""
import csv
import sys


def fail(message):
    print(f"plot_scaling: {message}", file=sys.stderr)
    sys.exit(1)


def read_series(path):
    series = {}
    try:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                series.setdefault(row["pass"], []).append((int(row["threads"]), float(row["speedup"])))
    except (OSError, KeyError, ValueError) as e:
        fail(f"{path}: cannot read the scaling CSV ({e})")
    if not series:
        fail(f"{path}: no rows")
    return series


def main():
    if len(sys.argv) != 3:
        fail("usage: plot_scaling.py SCALE.csv OUT.png")
    csv_path, png_path = sys.argv[1], sys.argv[2]
    series = read_series(csv_path)
    try:
        import matplotlib
    except ImportError:
        fail("matplotlib is not installed (apt-get install python3-matplotlib)")
    matplotlib.use("Agg")  # no display needed
    import matplotlib.pyplot as plt

    threads = sorted({n for points in series.values() for n, _ in points})
    fig, ax = plt.subplots(figsize=(7, 5))
    ax.plot(threads, threads, color="grey", linestyle="--", label="ideal")
    # The pipeline last, thicker: it is what a user waits for.
    names = [name for name in series if name != "pipeline"] + (["pipeline"] if "pipeline" in series else [])
    for name in names:
        points = sorted(series[name])
        ax.plot([n for n, _ in points], [s for _, s in points], marker="o",
                linewidth=2.5 if name == "pipeline" else 1.2, label=name)
    ax.set_xscale("log", base=2)
    ax.set_xticks(threads)
    ax.set_xticklabels([str(n) for n in threads])
    ax.set_xlabel("threads")
    ax.set_ylabel("speed-up T(1) / T(N)")
    ax.set_title("thread scaling")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    fig.tight_layout()
    try:
        fig.savefig(png_path, format="png", dpi=100)
    except OSError as e:
        fail(f"{png_path}: cannot write ({e})")


if __name__ == "__main__":
    main()
