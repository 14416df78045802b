"""Benchmark of meshes.foam.VoronoiFoam: build time (periodic Voronoi + radius from density) and voxelization.

Cases: density 0.18, gamma ∈ {1, 0.1}, n_cells ∈ {20, 50}; ``voxelize(N)`` for N ∈ {64, 128}. Goal (issue 3):
``voxelize(128)`` under 10 s on one core. The process runs with one OpenBLAS thread and scipy's KD-tree is
single-threaded, so the figures are one-core figures (wall-clock, noisy on a shared machine).

Usage: ``bench_foam.py --out DIR`` (``--ci``: one small case, N = 32 only). Prints a table and writes
``DIR/bench_foam.csv``.
"""

import argparse
import csv
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from meshes.foam import VoronoiFoam

CASES = [(20, 1.0), (20, 0.1), (50, 1.0), (50, 0.1)]
RESOLUTIONS = (64, 128)
CI_CASES, CI_RESOLUTIONS = [(12, 1.0)], (32,)
DENSITY = 0.18
GOAL_S = 10.0
FIELDS = ["n_cells", "gamma", "n_struts", "radius", "build_s", "N", "voxelize_s", "voxel_density"]


def run(cases, resolutions) -> list[dict]:
    rows = []
    for n_cells, gamma in cases:
        start = time.perf_counter()
        foam = VoronoiFoam(n_cells, DENSITY, gamma=gamma, seed=1)
        build_s = time.perf_counter() - start
        for N in resolutions:
            start = time.perf_counter()
            img = foam.voxelize(N)
            rows.append({"n_cells": n_cells, "gamma": gamma, "n_struts": foam.summary.n_struts,
                         "radius": round(foam.radius, 6), "build_s": round(build_s, 3), "N": N,
                         "voxelize_s": round(time.perf_counter() - start, 3),
                         "voxel_density": round(float(img.mean()), 5)})
            print("  ".join(f"{k}={v}" for k, v in rows[-1].items()), flush=True)
    return rows


def write_csv(path: Path, rows: list[dict]) -> None:
    with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(f.name, path)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--ci", action="store_true")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = run(CI_CASES, CI_RESOLUTIONS) if args.ci else run(CASES, RESOLUTIONS)
    write_csv(args.out / "bench_foam.csv", rows)
    print(f"\nVoronoiFoam, density {DENSITY}, seed 1 (times in s, one core):")
    print("  ".join(f"{k:>13s}" for k in FIELDS))
    for r in rows:
        print("  ".join(f"{r[k]!s:>13s}" for k in FIELDS))
    worst = max(r["voxelize_s"] for r in rows if r["N"] == max(r["N"] for r in rows))
    print(f"\nslowest voxelize({max(r['N'] for r in rows)}): {worst:.2f} s (goal for N = 128: < {GOAL_S} s)")
    print(f"CSV: {args.out / 'bench_foam.csv'}")
