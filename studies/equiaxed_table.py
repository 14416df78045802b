"""The ``equiaxed`` foam table: Euclidean strut foams of 27 cells in the box (γ, 1, 1), resolved by strut width.

The ``cube`` table (``fenicsfoam table``) uses one grid for every γ. In the equiaxed box the struts of a γ = 0.1
foam are about three times thinner, relative to the box, than at γ = 1, and a voxel strut of about two voxels
across is held together by voxels that share only an edge: its stiffness is a voxel artefact (the
[RVE-size page](../docs/validation/2026-11-24-foam-rve.md) measures a factor 2.4 between 2.3 and 3.5 voxels across).
So the grid is chosen per γ from the strut width: ``N`` (voxels along y and z, a multiple of 10 so that γN is an
integer for γ = 0.1, 0.3, 0.5) is the smallest with at least ``--voxels-per-strut`` voxels across the strut
diameter of the thinnest foam of the sweep (seed 0, lowest density). The default, 3.85, gives N = 150 at γ = 0.1
and 60 at γ = 1 for 27 cells (and 100 and 200 for 8 and 64 cells at γ = 0.1, the RVE-size study's grids): the
finest strut resolution the 64-cell RVE of that study could afford.

Every sample goes through :func:`homogenization.tables.run_sweep` (cached one JSON per sample under ``--cache``,
shared with ``studies/foam_rve_study.py`` and ``fenicsfoam table``); the table is written as
``foam_table_equiaxed*`` under ``--out`` and with ``--ship`` into ``homogenization/data``. Its voxels are the
rotated scheme's (one-point), with which the shipped table was made, not the library's default for new tables.
Checks: every sample within 0.002 of its density; exits 1 otherwise.

Run: ``OMP_NUM_THREADS=1 nice -n 10 python studies/equiaxed_table.py --cache out/foam-cache --out out/equiaxed``
(``mpirun -n 2`` deals the samples to two ranks). ``--ci``: two tiny samples.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from mpi4py import MPI

from homogenization import tables


def resolution_for(n_cells: int, density: float, gamma: float, voxels_per_strut: float) -> int:
    """The smallest multiple of 10 giving ``voxels_per_strut`` voxels across the strut diameter (seed 0)."""
    settings = tables.SweepSettings(n_cells=n_cells, box="equiaxed")
    return tables.resolution_for_strut(settings, density, gamma, voxels_per_strut, multiple=10)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--cache", type=Path, default=None, help="sample cache (default OUT/cache)")
    p.add_argument("--densities", type=float, nargs="+", default=[0.18])
    p.add_argument("--gammas", type=float, nargs="+", default=[0.1, 1.0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--cells", type=int, default=27)
    p.add_argument("--voxels-per-strut", type=float, default=3.85)
    p.add_argument("--tol", type=float, default=1e-3)
    p.add_argument("--maxiter", type=int, default=10000, help="CG iterations per load case")
    p.add_argument("--ship", action="store_true", help="also write the table into homogenization/data")
    p.add_argument("--ci", action="store_true", help="two tiny samples")
    a = p.parse_args(argv)
    if a.ci:
        a.densities, a.gammas, a.seeds, a.cells, a.voxels_per_strut, a.ship = [0.3], [1.0, 0.5], [0], 4, 2.0, False
    comm = MPI.COMM_WORLD
    cache = a.cache or a.out / "cache"
    start = time.perf_counter()
    rows, settings = [], {}
    for gamma in a.gammas:
        N = max(resolution_for(a.cells, d, gamma, a.voxels_per_strut) for d in a.densities)
        s = tables.SweepSettings(n_cells=a.cells, resolution=N, tol=a.tol, box="equiaxed", maxiter=a.maxiter,
                                 discretization="rotated")  # the shipped table's voxels (its provenance)
        settings[str(gamma)] = tables.settings_dict(s)
        rows += tables.run_sweep(tables.grid(a.densities, (gamma,), a.seeds), s, cache, comm, threads=1,
                                 progress=False)
    if comm.rank != 0:
        return 0
    launcher = f"mpirun -n {comm.size} " if comm.size > 1 else ""
    provenance = {"command": launcher + " ".join(["python", "studies/equiaxed_table.py", *sys.argv[1:]]),
                  "date": datetime.now(UTC).isoformat(timespec="seconds"), "ranks": comm.size,
                  "wall_s_this_run": time.perf_counter() - start,
                  "sample_wall_s_total": float(sum(r["wall_s"] for r in rows)), "n_samples": len(rows),
                  "voxels_per_strut": a.voxels_per_strut, "settings_per_gamma": settings}
    paths = tables.write_tables(rows, a.out, provenance, "equiaxed")
    if a.ship:
        tables.write_tables(rows, tables.DATA_DIR, provenance, "equiaxed")
    print(tables.format_table(tables.aggregate(rows)))
    print("N per gamma: " + ", ".join(f"{g}: {s['resolution']}" for g, s in settings.items()))
    print("written: " + ", ".join(str(v) for v in paths.values()))
    off = [r for r in rows if abs(r["measured_density"] - r["density"]) > 0.002]
    for r in off:
        print(f"FAILED: sample density {r['measured_density']:.4f} for target {r['density']}")
    return 1 if off else 0


if __name__ == "__main__":
    sys.exit(main())
