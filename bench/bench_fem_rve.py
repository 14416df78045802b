"""Benchmark of the periodic FEM RVE (homogenization.fem): cost per phase, six load cases vs one, memory.

Problem: the unit cube with a stiff cubic inclusion [1/4, 3/4]³ (E = 10, ν = 0.3) in a soft matrix (E = 1, ν = 0.2)
on dolfinx's structured tetrahedral mesh, P1 and P2 at three sizes each (up to ~100k dofs), with the default
direct solver (MUMPS LDLᵀ) and, at the largest sizes, CG + GAMG with the rigid-body near-nullspace
(``homogenization.fem.iterative_options()``, rtol 1e-8).

Each configuration runs in a fresh Python process, so that its peak resident memory is its own. Reported:
n_dofs, setup (spaces, constraint, forms), matrix assembly, factorization (or GAMG set-up), time per right-hand side,
averages (stress and energy C), ``one`` = setup + assembly + factorization + first solve and
``six`` = setup + assembly + factorization + six solves + averages, their ratio (goal ≤ 1.5), peak RSS.

A second table measures the void handling on the same mesh with a void cubic inclusion: the exact zero-stiffness
void (void-only dofs removed) against an ersatz void of stiffness ratio 1e-3, 1e-6, 1e-9.

Usage: ``bench_fem_rve.py --out DIR`` (``--ci`` for small sizes). Timings are wall-clock and noisy on a shared
machine.
"""

import argparse
import csv
import json
import resource
import subprocess
import sys
from pathlib import Path

from foambase.threads import single_threaded_blas_by_default

single_threaded_blas_by_default()  # before numpy loads OpenBLAS: its threads spin against FFTW's

import numpy as np

from foambase.files import atomic_open

SIZES = {1: (16, 24, 32), 2: (8, 12, 16)}  # 14.7k, 46.9k, 108k dofs for both degrees
CI_SIZES = {1: (4, 8), 2: (4, 6)}
FIELDS = ["degree", "n", "solver", "n_dofs", "setup_s", "assembly_s", "factorization_s", "solve_s",
          "averages_s", "one_case_s", "six_cases_s", "six_over_one", "iterations", "peak_rss_mb", "C11",
          "energy_vs_stress_rel_diff"]


def _problem(n, void_ratio=None):
    from dolfinx import mesh as dmesh
    from mpi4py import MPI

    from homogenization.tensors import isotropic_voigt

    msh = dmesh.create_unit_cube(MPI.COMM_WORLD, n, n, n)
    n_cells = msh.topology.index_map(3).size_local
    cells = np.arange(n_cells, dtype=np.int32)
    midpoints = dmesh.compute_midpoints(msh, 3, cells)
    tags = np.where(np.all(np.abs(midpoints - 0.5) < 0.25, axis=1), 1, 2).astype(np.int32)
    cell_tags = dmesh.meshtags(msh, 3, cells, tags)
    C_stiff, C_soft = isotropic_voigt(10.0, 0.3), isotropic_voigt(1.0, 0.2)
    if void_ratio is None:
        return msh, cell_tags, {1: C_stiff, 2: C_soft}
    return msh, cell_tags, {1: void_ratio * C_stiff, 2: C_stiff}  # void (or ersatz) inclusion in a stiff matrix


def run_case(degree, n, solver):
    """One configuration in this process; returns a row of the table."""
    from homogenization.fem import homogenize_fem, iterative_options

    msh, cell_tags, materials = _problem(n)
    options = iterative_options() if solver == "gamg" else None
    r = homogenize_fem(msh, cell_tags, materials, degree=degree, petsc_options=options)
    t = r.info["timings"]
    solves = np.asarray(t["solves"])
    head = t["setup"] + t["assembly"] + t["factorization"]
    one, six = head + solves[0], head + solves.sum() + t["averages"]
    return {"degree": degree, "n": n, "solver": solver, "n_dofs": r.info["n_dofs"], "setup_s": t["setup"],
            "assembly_s": t["assembly"], "factorization_s": t["factorization"], "solve_s": float(solves.mean()),
            "averages_s": t["averages"], "one_case_s": one, "six_cases_s": six, "six_over_one": six / one,
            "iterations": int(max(r.iterations)),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "C11": float(r.C[0, 0]), "energy_vs_stress_rel_diff": r.info["energy_vs_stress_rel_diff"]}


def run_void_study(n):
    """Exact zero void vs ersatz stiffness ratios on a void cubic inclusion (P1)."""
    from homogenization.fem import homogenize_fem

    rows, exact = [], None
    for ratio in (0.0, 1e-9, 1e-6, 1e-3):
        r = homogenize_fem(*_problem(n, void_ratio=ratio))
        exact = r.C if exact is None else exact
        rows.append({"void_ratio": ratio, "n_dofs": r.info["n_dofs"], "n_void_dofs": r.info["n_void_dofs"],
                     "C11": float(r.C[0, 0]), "C44": float(r.C[3, 3]),
                     "rel_diff_to_exact": float(np.abs(r.C - exact).max() / np.abs(exact).max()),
                     "factorization_s": r.info["timings"]["factorization"]})
    return rows


def _in_subprocess(args):
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark case {args} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _write_csv(path: Path, rows, fields):
    with atomic_open(path) as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


def _print_table(rows, fields):
    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    cells = [[fmt(row[k]) for k in fields] for row in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(fields)]
    print("  ".join(k.rjust(w) for k, w in zip(fields, widths)))
    for c in cells:
        print("  ".join(v.rjust(w) for v, w in zip(c, widths)))


def main(out: Path, ci: bool = False) -> int:
    sizes = CI_SIZES if ci else SIZES
    rows = []
    for degree, ns in sizes.items():
        for n in ns:
            rows.append(_in_subprocess(["--case", str(degree), str(n), "mumps"]))
            print(f"  P{degree} n={n}: {rows[-1]['n_dofs']} dofs, six/one = {rows[-1]['six_over_one']:.3f}",
                  flush=True)
        rows.append(_in_subprocess(["--case", str(degree), str(ns[-1]), "gamg"]))
    void_rows = _in_subprocess(["--void", str(sizes[1][0])])

    out.mkdir(parents=True, exist_ok=True)
    _write_csv(out / "bench_fem_rve.csv", rows, FIELDS)
    _write_csv(out / "bench_fem_rve_void.csv", void_rows, list(void_rows[0]))
    print("\nPeriodic FEM RVE, cubic inclusion, serial (times in s):")
    _print_table(rows, FIELDS[:-2])
    print("\nVoid handling (void cubic inclusion, P1): exact zero void vs ersatz stiffness ratio:")
    _print_table(void_rows, list(void_rows[0]))
    worst = max(r["six_over_one"] for r in rows if r["solver"] == "mumps")
    print(f"\nsix cases / one case (direct solver), worst: {worst:.3f} (goal <= 1.5)")
    print(f"CSV: {out / 'bench_fem_rve.csv'}, {out / 'bench_fem_rve_void.csv'}")
    return 0 if worst <= 1.5 else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument("--ci", action="store_true", help="small sizes only")
    parser.add_argument("--case", nargs=3, metavar=("DEGREE", "N", "SOLVER"), help=argparse.SUPPRESS)
    parser.add_argument("--void", type=int, metavar="N", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(int(args.case[0]), int(args.case[1]), args.case[2])))
    elif args.void:
        print(json.dumps(run_void_study(args.void)))
    else:
        sys.exit(main(args.out, ci=args.ci))
