# %% [markdown]
# # The paper's Fig. 4 for our foams: normalised moduli against relative density, with power-law fits
#
# This demo shows:
# - reading the shipped, seed-averaged foam table (`homogenization/data/foam_table.csv`, produced by
#   `demos/homogenization_table.py`): 8 densities × 4 anisotropies γ, 3 seeds each;
# - the normalised Young's and shear moduli and Poisson's ratios against density for γ = 1 and 0.1 (error bars:
#   the standard deviation over seeds), as the paper's Fig. 4 plots them;
# - least-squares power laws E/E_s = a ρ^b in log–log, printed and written to `fig4_fits.csv`, the figure to
#   `fig4_curves.png`.
#
# There is no field problem solved here; each table entry is the homogenized stiffness of one periodic foam
# cell (see `demos/pipeline.py`, stage 1).
#
# ## Checks (exit status 1 if one fails), against the scaling laws of cellular solids (Gibson–Ashby)
# - γ = 1: the open-cell foam is bending-dominated, E ∝ ρ²: every Young's and shear modulus has an exponent b
#   in [1.8, 2.5] (measured 2.11–2.17);
# - γ = 0.1: the struts lie in the y–z plane, whose moduli E2, E3 are closer to stretching-dominated (b = 1):
#   b in [1.0, 1.5] (measured 1.20); the soft x axis bends its flattened cells: E1 has b > 2.5 (measured 3.26).
#
# Run: `python demos/homogenization_curves.py --out out/fig4 [--ci]` (`--ci` is the same run: it only reads the
# shipped table), also under `mpirun -n 2` (rank 0 works, the others wait for the verdict).

# %%
import sys
from pathlib import Path

import matplotlib
import numpy as np
from _demo import parser, report
from mpi4py import MPI

from homogenization import tables

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

QUANTITIES = ("E1", "E2", "E3", "G23", "G12", "nu23", "nu21")
#: Exponent bands checked: (gamma, quantities, lowest b, highest b).
EXPONENT_BANDS = ((1.0, ("E1", "E2", "E3", "G23", "G12"), 1.8, 2.5),
                  (0.1, ("E2", "E3"), 1.0, 1.5),
                  (0.1, ("E1",), 2.5, np.inf))


def power_law(density: np.ndarray, value: np.ndarray) -> tuple[float, float]:
    """Least-squares fit of ``log value = log a + b log density``; returns (a, b)."""
    b, log_a = np.polyfit(np.log(density), np.log(value), 1)
    return float(np.exp(log_a)), float(b)


def figure(out: Path, table_path: Path, gammas=(1.0, 0.1)) -> list[dict]:
    """Plot the curves, fit the power laws, write the PNG and the CSV; returns the fits."""
    t = tables.read_csv(table_path)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    fits = []
    for gamma, style in zip(gammas, ("-", "--"), strict=True):
        rows = t["gamma"] == gamma
        if not rows.any():
            raise SystemExit(f"gamma = {gamma} is not in {table_path}")
        rho = t["density"][rows]
        for ax, names in zip(axes, (("E1", "E2", "E3"), ("G23", "G12"), ("nu23", "nu21")), strict=True):
            for name in names:
                ax.errorbar(rho, t[name][rows], yerr=t.get(f"{name}_std", np.zeros(rows.sum()))[rows], ls=style,
                            marker="o", ms=3, capsize=2, label=f"{name}, γ={gamma:g}")
        for name in ("E1", "E2", "E3", "G23", "G12"):
            a, b = power_law(rho, t[name][rows])
            fits.append({"gamma": gamma, "quantity": name, "a": a, "b": b})
    for ax, title in zip(axes, ("Young's moduli / E_s", "shear moduli / E_s", "Poisson's ratios"), strict=True):
        ax.set_xlabel("relative density ρ")
        ax.set_title(title)
        ax.legend(fontsize=7)
        if "moduli" in title:
            ax.set_yscale("log")
    fig.tight_layout()
    fig.savefig(out / "fig4_curves.png", dpi=120)
    tables.to_csv(fits, out / "fig4_fits.csv")
    print("power-law fits E/E_s = a·ρ^b (x = the foam's distinct axis)")
    print(f"{'gamma':>6} {'quantity':>8} {'a':>9} {'b':>6}")
    for f in fits:
        print(f"{f['gamma']:6.2f} {f['quantity']:>8} {f['a']:9.4f} {f['b']:6.2f}")
    return fits


# %% [markdown]
# ## Checks: the fitted exponents against the bending- and stretching-dominated scaling laws


# %%
def check(fits: list[dict]) -> list[str]:
    """Failed checks, as messages (empty if all pass)."""
    b = {(f["gamma"], f["quantity"]): f["b"] for f in fits}
    return [f"gamma = {gamma:g}, {name}: exponent {b[gamma, name]:.2f} is outside [{low:g}, {high:g}]"
            for gamma, names, low, high in EXPONENT_BANDS for name in names if not low <= b[gamma, name] <= high]


def main(out: Path, table_path: Path, comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    """Figure, fits and checks on rank 0; returns the exit status on every rank."""
    failures = check(figure(out, table_path)) if comm.rank == 0 else None
    return report(failures, comm)




if __name__ == "__main__":
    cli = parser("Paper Fig. 4 from the shipped foam table: moduli vs density, power-law fits.", "out/fig4",
                 "same as the default run (it only reads the shipped table)")
    cli.add_argument("--table", type=Path, default=tables.TABLE_CSV, help="the aggregated table (CSV)")
    args = cli.parse_args()
    sys.exit(main(args.out, args.table))
