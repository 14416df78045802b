"""Benchmark of meshes.foam.VoronoiFoam: build time (periodic Voronoi + radius from density) and voxelization.

Cases: density 0.18, gamma ∈ {1, 0.1}, n_cells ∈ {20, 50}; ``voxelize(N)`` for N ∈ {64, 128}. Goal (issue 3):
``voxelize(128)`` under 10 s on one core. The process runs with one OpenBLAS thread and scipy's KD-tree is
single-threaded, so the figures are one-core figures (wall-clock, noisy on a shared machine).

A second table times ``mesh_rve`` (serial): element count, meshing time and the meshed solid volume against the
foam's sampled density, for a small foam (4 cells, density 0.25) and the 20-cell foams above (h ≤ 2 r is required).

Usage: ``bench_foam.py --out DIR`` (``--ci``: one small case, N = 32 only). Prints the tables and writes
``DIR/bench_foam.csv`` and ``DIR/bench_foam_mesh.csv``.
"""

import argparse
import csv
import time
from pathlib import Path

from foambase.threads import single_threaded_blas_by_default

single_threaded_blas_by_default()  # before numpy loads OpenBLAS: its threads spin against FFTW's

from foambase.files import atomic_open
from meshes.foam import VoronoiFoam

CASES = [(20, 1.0), (20, 0.1), (50, 1.0), (50, 0.1)]
RESOLUTIONS = (64, 128)
CI_CASES, CI_RESOLUTIONS = [(12, 1.0)], (32,)
DENSITY = 0.18
GOAL_S = 10.0
FIELDS = ["n_cells", "gamma", "n_struts", "radius", "build_s", "N", "voxelize_s", "voxel_density"]
MESH_CASES = [((4, 0.25, 1.0), (12, 16, 24)), ((20, 0.18, 1.0), (24, 32)), ((20, 0.18, 0.1), (32,))]
CI_MESH_CASES = [((4, 0.25, 1.0), (12,))]
MESH_FIELDS = ["n_cells", "density", "gamma", "radius", "n", "n_elements", "meshing_s", "solid_volume",
               "volume_error"]


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


def run_mesh(cases) -> list[dict]:
    import dolfinx
    import ufl
    from mpi4py import MPI

    from meshes.foam import mesh_rve
    from meshes.rve import SOLID

    rows = []
    for (n_cells, density, gamma), grids in cases:
        foam = VoronoiFoam(n_cells, density, gamma=gamma, seed=1)
        for n in grids:
            rve = mesh_rve(foam, 1.0 / n, MPI.COMM_SELF)
            dx = ufl.Measure("dx", domain=rve.mesh, subdomain_data=rve.cell_tags)
            volume = dolfinx.fem.assemble_scalar(dolfinx.fem.form(dolfinx.fem.Constant(rve.mesh, 1.0) * dx(SOLID)))
            rows.append({"n_cells": n_cells, "density": density, "gamma": gamma, "radius": round(foam.radius, 5),
                         "n": n, "n_elements": rve.n_elements, "meshing_s": round(rve.meshing_s, 2),
                         "solid_volume": round(volume, 5), "volume_error": round(volume - foam.measured_density, 5)})
            print("  ".join(f"{k}={v}" for k, v in rows[-1].items()), flush=True)
    return rows


def write_csv(path: Path, rows: list[dict], fields=FIELDS) -> None:
    with atomic_open(path) as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


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
    mesh_rows = run_mesh(CI_MESH_CASES if args.ci else MESH_CASES)
    write_csv(args.out / "bench_foam_mesh.csv", mesh_rows, MESH_FIELDS)
    print("\nmesh_rve (serial; n = grid cells per side, h = 1/n):")
    print("  ".join(f"{k:>12s}" for k in MESH_FIELDS))
    for r in mesh_rows:
        print("  ".join(f"{r[k]!s:>12s}" for k in MESH_FIELDS))
    print(f"CSV: {args.out / 'bench_foam.csv'}, {args.out / 'bench_foam_mesh.csv'}")
