#!/usr/bin/env python3
"""Runs fluxgraph_bench once and prints, from that one run:
  - raw Embree closest-hit throughput (rays/s) per thread count,
  - the `pt` pipeline's throughput (path segments/s = path vertices/s, samples/s) per schedule,
  - the ratio pt segments/s : Embree rays/s at equal thread count,
  - parallel efficiency of the `pt` pass: T(1) / (N * T(N)).
Usage: tools/bench_report.py [build-dir] [--markdown FILE]
"""
import json
import subprocess
import sys
from pathlib import Path


def fail(message):
    """Bad input or a missing prerequisite: one line on stderr, exit status 2."""
    print(message, file=sys.stderr)
    sys.exit(2)


def main():
    args = sys.argv[1:]
    markdown = None
    if "--markdown" in args:
        i = args.index("--markdown")
        markdown = args[i + 1]
        del args[i : i + 2]
    build = Path(args[0] if args else "build")
    binary = build / "tools" / "bench" / "fluxgraph_bench"
    if not binary.exists():
        fail(f"{binary}: not built (cmake --build {build} -j2)")
    out = subprocess.run([str(binary), "--benchmark_format=json", "--benchmark_filter=BM_EmbreeClosestHit|BM_PathTracer"], check=True, capture_output=True, text=True).stdout
    results = json.loads(out)["benchmarks"]

    embree = {}
    pt = {}
    for b in results:
        name = b["name"].split("/")
        if name[0] == "BM_EmbreeClosestHit":
            embree[int(name[1])] = b["rays_per_s"]
        elif name[0] == "BM_PathTracer":
            threads, schedule = int(name[1]), "wavefront" if name[2] == "0" else "tile"
            pt[(schedule, threads)] = b

    lines = ["| threads | Embree rays/s | schedule | pt segments/s | pt samples/s | pt / Embree | pt pass efficiency |",
             "|---:|---:|---|---:|---:|---:|---:|"]
    for (schedule, threads), b in sorted(pt.items()):
        base = pt.get((schedule, 1))
        eff = base["pass_wall_s"] / (threads * b["pass_wall_s"]) if base else float("nan")
        ray_rate = embree.get(threads, float("nan"))
        lines.append(
            f"| {threads} | {ray_rate / 1e6:.2f} M | {schedule} | {b['path_segments_per_s'] / 1e6:.2f} M | "
            f"{b['samples_per_s'] / 1e3:.1f} k | {b['path_segments_per_s'] / ray_rate:.3f} | {eff:.2f} |"
        )
    text = "\n".join(lines)
    print(text)
    if markdown:
        Path(markdown).write_text(text + "\n")


if __name__ == "__main__":
    main()
