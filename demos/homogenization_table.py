# %% [markdown]
# # The homogenized foam table: FFT homogenization of density × γ × seed foams, as an MPI batch
#
# This demo shows:
# - the sweep behind the shipped table (`homogenization.tables.run_sweep`): foams
#   `VoronoiFoam(n_cells, density, gamma, seed, box=, distance=)` voxelized with cubic voxels and homogenized by
#   the FFT solver in their periodic box (`--box equiaxed`: the box (γ, 1, 1) that follows the cells;
#   `--distance polyhedral`: the printed wall foam; each setting writes a table of its own name);
# - the samples dealt to the MPI ranks, each finished sample cached as one JSON file (`--cache`), so an
#   interrupted run resumes without recomputing anything;
# - the table of means and standard deviations over seeds per (density, γ), with the closest transversely
#   isotropic and isotropic fits; `--ship` also writes it into the package (`homogenization/data`) with its
#   provenance.
#
# ## The cell problem
#
# *Continuous.* On the periodic unit cell Y, with C(y) the isotropic solid (E_s = 1, ν_s = 0.3) in the struts
# and zero in the void, find for each macroscopic strain E the periodic fluctuation ũ with div σ = 0,
# σ = C(y) : (E + ε(ũ)); then C_hom : E = ⟨σ⟩.
#
# *Weak form.* ∫_Y ε(w) : C : (E + ε(ũ)) dy = 0 for every periodic w, written in Fourier space as G[C : ε] = 0
# with the compatibility projection G.
#
# *Discrete.* N³ voxels, Willot's rotated scheme (trilinear hexahedra with one-point integration; the shipped
# tables', so this demo's default, while `--discretization hex8`, fully integrated voxels, is the library's default
# for new tables), conjugate gradients to the relative equilibrium residual `--tol`, six unit strains → the 6×6
# C_hom (Voigt).
#
# ## Checks (exit status 1 if one fails)
# - the Voigt bound, which holds for any microstructure: every Young's modulus E_i ≤ φ E_s and every shear
#   modulus G_ij ≤ φ G_s, with φ the measured solid fraction;
# - the moduli grow with density at every γ;
# - a γ < 0.5 foam is softest along x, its l axis.
#
# Run: `mpirun -n 2 python demos/homogenization_table.py --cache out/foam-cache --out out/foam-table [--ship]`
# (the shipped table: 96 samples, ~24 min on 2 ranks); `--ci`: a tiny sweep on a coarse grid.

# %%
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from _demo import parser, report
from mpi4py import MPI

from homogenization import tables


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


# %% [markdown]
# ## The sweep


# %%
def main(out: Path, cache: Path, settings: tables.SweepSettings, samples, ship: bool, stop_after=None,
         comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    """Run the sweep, write (and with ``ship`` install) the tables, check them; returns the exit status."""
    start = time.perf_counter()
    rows = tables.run_sweep(samples, settings, cache, comm, stop_after=stop_after)
    wall = time.perf_counter() - start
    if rows is None:  # a rank stopped early (--stop-after): nothing to check yet
        return 0
    failures = table_stage(rows, out, ship, settings, wall, comm) if comm.rank == 0 else None
    return report(failures, comm)


def table_stage(rows: list[dict], out: Path, ship: bool, settings: tables.SweepSettings, wall: float,
                comm: MPI.Comm) -> list[str]:
    """Write and print the tables (rank 0); returns the failed checks."""
    provenance = {"command": f"mpirun -n {comm.size} python3 {' '.join(sys.argv)}", "commit": _commit(),
                  "date": datetime.now(UTC).isoformat(timespec="seconds"), "ranks": comm.size,
                  "wall_s_this_run": wall, "sample_wall_s_total": float(sum(r["wall_s"] for r in rows)),
                  "n_samples": len(rows), "settings": tables.settings_dict(settings)}
    paths = tables.write_tables(rows, out, provenance, settings.name)
    if ship:
        tables.write_tables(rows, tables.DATA_DIR, provenance, settings.name)
    table = tables.aggregate(rows)
    print(f"{len(rows)} samples, {len(table)} (density, gamma) points; {settings.distance} foam, {settings.box} box, "
          f"N = {settings.resolution}, n_cells = {settings.n_cells}, tol = {settings.tol:g}; this run {wall:.0f} s "
          f"on {comm.size} ranks")
    print(f"{'density':>8} {'gamma':>6} {'E1/Es':>10} {'E2/Es':>10} {'E3/Es':>10} {'G23/Es':>10} {'TI err':>7} "
          f"{'iso err':>7}")
    for t in table:
        print(f"{t['density']:8.2f} {t['gamma']:6.2f} {t['E1']:10.3e} {t['E2']:10.3e} {t['E3']:10.3e} "
              f"{t['G23']:10.3e} {t['ti_error']:7.3f} {t['iso_error']:7.3f}")
    print("written:", ", ".join(str(p) for p in paths.values()))
    return check(rows, table)


# %% [markdown]
# ## Checks


# %%
def check(rows: list[dict], table: list[dict]) -> list[str]:
    """Failed checks, as messages (empty if all pass)."""
    failures = []
    g_solid = 1.0 / (2 * (1 + tables.NU_SOLID))  # E_s = 1
    for r in rows:
        phi = r["measured_density"]
        over = [f"{n} = {r[n]:.4g} > {phi:.4g}" for n in ("E1", "E2", "E3") if not r[n] <= phi]
        over += [f"{n} = {r[n]:.4g} > {phi * g_solid:.4g}" for n in ("G23", "G13", "G12")
                 if not r[n] <= phi * g_solid]
        if over:
            failures.append(f"sample (density {r['density']}, gamma {r['gamma']}, seed {r['seed']}) above the "
                            f"Voigt bound: {', '.join(over)}")
    for g in sorted({t["gamma"] for t in table}):
        E = np.array([[t["E1"], t["E2"], t["E3"]] for t in table if t["gamma"] == g])
        if len(E) > 1 and not np.all(np.diff(E, axis=0) > 0):
            failures.append(f"moduli do not increase with density at gamma = {g}")
        if g < 0.5 and not np.all(E[:, 0] < E[:, 1:].min(axis=1)):
            failures.append(f"gamma = {g} is not softest along x")
    return failures


if __name__ == "__main__":
    p = parser("Homogenized foam table: FFT homogenization of density x gamma x seed foams.", "out/foam-table",
               "tiny sweep at a coarse grid")
    p.add_argument("--cache", type=Path, default=None, help="sample cache (default: OUT/cache)")
    p.add_argument("--densities", type=float, nargs="+", default=tables.DENSITIES)
    p.add_argument("--gammas", type=float, nargs="+", default=tables.GAMMAS)
    p.add_argument("--seeds", type=int, nargs="+", default=tables.SEEDS)
    p.add_argument("--cells", type=int, default=tables.SweepSettings.n_cells)
    p.add_argument("--resolution", type=int, default=tables.SweepSettings.resolution)
    p.add_argument("--tol", type=float, default=tables.SweepSettings.tol)
    p.add_argument("--box", choices=("cube", "equiaxed"), default=tables.SweepSettings.box,
                   help="the RVE box: the unit cube or (gamma, 1, 1) (resolution: voxels along y and z)")
    p.add_argument("--distance", choices=tables.FOAMS, default=tables.SweepSettings.distance,
                   help="the foam: Euclidean struts or polyhedral walls")
    p.add_argument("--maxiter", type=int, default=None, help="CG iterations per load case (default 1000)")
    p.add_argument("--discretization", choices=tables.SWEEP_DISCRETIZATIONS, default="rotated",
                   help="voxels: rotated (default here: this demo regenerates the shipped tables, made with it) or "
                        "hex8 (the library's default for new tables; the table's name ends in _hex8)")
    p.add_argument("--ship", action="store_true", help="also write the tables into homogenization/data")
    p.add_argument("--stop-after", type=int, default=None, help="stop each rank after this many new samples")
    a = p.parse_args()
    if a.ci:
        a.densities, a.gammas, a.seeds, a.resolution, a.cells = (0.15, 0.3), (0.1,), (0,), 20, 6
    settings = tables.SweepSettings(n_cells=a.cells, resolution=a.resolution, tol=a.tol, box=a.box,
                                    distance=a.distance, maxiter=a.maxiter, discretization=a.discretization)
    sys.exit(main(a.out, a.cache or a.out / "cache", settings, tables.grid(a.densities, a.gammas, a.seeds),
                  a.ship and not a.ci, a.stop_after))
