"""Homogenized foam table: FFT homogenization of density × γ × seed foams, as an mpirun batch.

    mpirun -n 2 python3 demos/homogenization_table.py --cache out/foam-cache --out out/foam-table

Samples are dealt to the ranks; finished samples are cached (``--cache``), so an interrupted run resumes.
``--ship`` also writes the tables into the package (``homogenization/data``), with their provenance.
``--ci`` runs a tiny sweep at a coarse grid and checks the table's structure and physics.
"""

import argparse
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from mpi4py import MPI

from homogenization import tables


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(out: Path, cache: Path, settings: tables.SweepSettings, samples, ship: bool, stop_after=None) -> int:
    comm = MPI.COMM_WORLD
    start = time.perf_counter()
    rows = tables.run_sweep(samples, settings, cache, comm, stop_after=stop_after)
    wall = time.perf_counter() - start
    if rows is None or comm.rank != 0:
        return 0
    provenance = {"command": f"mpirun -n {comm.size} python3 {' '.join(sys.argv)}", "commit": _commit(),
                  "date": datetime.now(UTC).isoformat(timespec="seconds"), "ranks": comm.size,
                  "wall_s_this_run": wall, "sample_wall_s_total": float(sum(r["wall_s"] for r in rows)),
                  "n_samples": len(rows), "settings": tables.settings_dict(settings)}
    paths = tables.write_tables(rows, out, provenance)
    if ship:
        tables.write_tables(rows, tables.DATA_DIR, provenance)
    table = tables.aggregate(rows)
    print(f"{len(rows)} samples, {len(table)} (density, gamma) points; N = {settings.resolution}, "
          f"n_cells = {settings.n_cells}, tol = {settings.tol:g}; this run {wall:.0f} s on {comm.size} ranks")
    print(f"{'density':>8} {'gamma':>6} {'E1/Es':>10} {'E2/Es':>10} {'E3/Es':>10} {'G23/Es':>10} {'TI err':>7} "
          f"{'iso err':>7}")
    for t in table:
        print(f"{t['density']:8.2f} {t['gamma']:6.2f} {t['E1']:10.3e} {t['E2']:10.3e} {t['E3']:10.3e} "
              f"{t['G23']:10.3e} {t['ti_error']:7.3f} {t['iso_error']:7.3f}")
    print("written:", ", ".join(str(p) for p in paths.values()))
    # Checks: moduli grow with density at every gamma; gamma < 1 is softest along x (its l axis).
    ok = True
    for g in sorted({t["gamma"] for t in table}):
        E = np.array([[t["E1"], t["E2"], t["E3"]] for t in table if t["gamma"] == g])
        if len(E) > 1 and not np.all(np.diff(E, axis=0) > 0):
            print(f"FAILED: moduli do not increase with density at gamma = {g}")
            ok = False
        if g < 0.5 and not np.all(E[:, 0] < E[:, 1:].min(axis=1)):
            print(f"FAILED: gamma = {g} is not softest along x")
            ok = False
    return 0 if ok else 1


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/foam-table"))
    p.add_argument("--cache", type=Path, default=None, help="sample cache (default: OUT/cache)")
    p.add_argument("--densities", type=float, nargs="+", default=tables.DENSITIES)
    p.add_argument("--gammas", type=float, nargs="+", default=tables.GAMMAS)
    p.add_argument("--seeds", type=int, nargs="+", default=tables.SEEDS)
    p.add_argument("--cells", type=int, default=tables.SweepSettings.n_cells)
    p.add_argument("--resolution", type=int, default=tables.SweepSettings.resolution)
    p.add_argument("--tol", type=float, default=tables.SweepSettings.tol)
    p.add_argument("--ship", action="store_true", help="also write the tables into homogenization/data")
    p.add_argument("--stop-after", type=int, default=None, help="stop each rank after this many new samples")
    p.add_argument("--ci", action="store_true", help="tiny sweep at a coarse grid")
    a = p.parse_args()
    if a.ci:
        a.densities, a.gammas, a.seeds, a.resolution, a.cells = (0.15, 0.3), (0.1,), (0,), 20, 6
    settings = tables.SweepSettings(n_cells=a.cells, resolution=a.resolution, tol=a.tol)
    sys.exit(main(a.out, a.cache or a.out / "cache", settings, tables.grid(a.densities, a.gammas, a.seeds),
                  a.ship and not a.ci, a.stop_after))
