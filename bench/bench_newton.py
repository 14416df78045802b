"""Cost of a Newton iteration of the macro FEM on a cantilever beam (250 × 15 × 15 mm proportions).

For ~2.7k, ~20k and ~150k tetrahedra (``dolfinx.mesh.create_box``), P1 and P2, each model, and a direct
(MUMPS LU) or an iterative (GMRES + GAMG with the rigid-body near-nullspace) linear solver, two load steps
are solved: ``gravity`` (0 → 1 g in one increment) and ``servo`` (the clamped root turned by 20° about the
transverse axis, one increment). Printed and written to ``OUT/bench_newton.csv``: Newton iterations per
step, milliseconds per Newton iteration and their breakdown — residual assembly, Jacobian assembly (both
with the corotational rotation update), preconditioner set-up (the LU factorization, or the GAMG hierarchy)
and the rest of the linear solve — from PETSc's event log.

    python bench/bench_newton.py --out out/bench            # everything (P2 at 150k tets with GAMG only)
    python bench/bench_newton.py --out out/bench --quick    # without the 150k case

Two studies behind design choices (README, "Macro FEM"), each with its own table and CSV:

    python bench/bench_newton.py --out out/bench --study linesearch   # SNES line searches on large rotations
    python bench/bench_newton.py --out out/bench --study polar        # polar-decomposition iterations vs accuracy
"""

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from dolfinx import mesh
from mpi4py import MPI
from petsc4py import PETSc
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from fenicsfoam import orientation
from fenicsfoam.bcs import RigidMotion
from fenicsfoam.constitutive import MODELS, MaterialField, polar_rotation
from fenicsfoam.materials import TransverseIsotropic
from fenicsfoam.solver import ConvergenceError, ElasticityProblem, LoadStep
from foambase.files import atomic_open

L, H = 0.25, 0.015
#: create_box divisions (nx, n, n): 6 nx n² tetrahedra.
SIZES = {"2.7k": (50, 3), "20k": (100, 6), "150k": (200, 11)}
#: A TI foam-like material, soft along l (γ < 1 in the paper), l axis across the beam.
MATERIAL = TransverseIsotropic(E_t=1.15e6, E_l=0.4e6, nu_t=0.3, nu_tl=0.15, G_l=0.2e6, rho=216.0)
#: Linear solvers: PETSc options per model ("gamg": CG, or GMRES for the non-symmetric corotational TI tangent).
SOLVERS = {
    "mumps": lambda model: {},
    "gamg": lambda model: {"ksp_type": "cg" if MODELS[model].symmetric_tangent else "gmres", "ksp_rtol": 1e-8,
                           "pc_type": "gamg"},
}
#: PETSc events of the "pc setup" (factorization or AMG set-up) and "ksp" (solve, without the set-up) columns.
EVENTS = ("PCSetUp", "KSPSolve")


def event_times() -> dict[str, float]:
    return {name: PETSc.Log.Event(name).getPerfInfo()["time"] for name in EVENTS}


def run_case(size: str, degree: int, model: str, solver: str) -> dict:
    nx, n = SIZES[size]
    comm = MPI.COMM_WORLD
    msh = mesh.create_box(comm, [[0.0, 0.0, 0.0], [L, H, H]], [nx, n, n])
    root = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.0))
    t0 = time.perf_counter()
    problem = ElasticityProblem(
        msh, MaterialField.uniform(msh, MATERIAL), orientation=orientation.uniform(msh, (0.0, 1.0, 0.0)),
        model=model, degree=degree, motions=[RigidMotion("servo", root, axis=(0, 1, 0), point=(0, H / 2, H / 2))],
        prefix=f"bench_{model}_", options=SOLVERS[solver](model))
    setup = time.perf_counter() - t0
    before = event_times()
    steps = problem.run([LoadStep("gravity", gravity=1.0), LoadStep("servo", angles={"servo": np.radians(20.0)})])
    after = event_times()
    its = sum(s.newton_iterations for s in steps)
    wall = sum(s.wall_s for s in steps)
    pc_setup = after["PCSetUp"] - before["PCSetUp"]
    ksp = after["KSPSolve"] - before["KSPSolve"]  # SNES sets the KSP up before KSPSolve: no PCSetUp inside
    ms = 1e3 / its
    return {
        "size": size, "cells": msh.topology.index_map(3).size_global, "degree": degree, "model": model,
        "solver": solver, "dofs": problem.V.dofmap.index_map.size_global * 3, "ranks": comm.size,
        "ksp_its": problem.snes.getLinearSolveIterations(),
        "its_gravity": steps[0].newton_iterations, "its_servo": steps[1].newton_iterations,
        "ms_per_it": wall * ms, "residual_ms": problem.timings["residual"] * ms,
        "jacobian_ms": problem.timings["jacobian"] * ms, "pc_setup_ms": pc_setup * ms, "ksp_ms": ksp * ms,
        "setup_s": setup, "tip_z_mm": 1e3 * comm.allreduce(problem.u.x.array[2::3].min(initial=0.0), op=MPI.MIN),
    }


def cases(quick: bool):
    for size in SIZES:
        if quick and size == "150k":
            continue
        for degree in (1, 2):
            for solver in SOLVERS:
                if size == "150k" and degree == 2 and solver == "mumps":
                    continue  # ~640k dofs: MUMPS needs minutes and many GB; GAMG is the way there
                for model in MODELS:
                    yield size, degree, model, solver


COLUMNS = ("size", "cells", "degree", "model", "solver", "ranks", "dofs", "its_gravity", "its_servo", "ksp_its",
           "ms_per_it", "residual_ms", "jacobian_ms", "pc_setup_ms", "ksp_ms", "setup_s", "tip_z_mm")


def write_csv(rows: list[dict], path: Path, columns) -> None:
    """Write rows to ``path`` through a temporary file in the same directory (rank 0 only)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {path}")


def newton_table(out: Path, quick: bool) -> None:
    comm = MPI.COMM_WORLD
    rows = []
    if comm.rank == 0:
        print(f"{'size':>5} {'cells':>7} P {'model':>12} {'solver':>6} {'dofs':>7} {'its g/s':>7} {'ksp':>5} "
              f"{'ms/it':>8} {'resid':>7} {'jacob':>7} {'pc set':>8} {'ksp':>7} {'tip mm':>7}")
    for case in cases(quick):
        r = run_case(*case)
        rows.append(r)
        if comm.rank == 0:
            print(f"{r['size']:>5} {r['cells']:>7} {r['degree']} {r['model']:>12} {r['solver']:>6} {r['dofs']:>7} "
                  f"{r['its_gravity']:>3}/{r['its_servo']:<3} {r['ksp_its']:>5} {r['ms_per_it']:8.1f} "
                  f"{r['residual_ms']:7.1f} {r['jacobian_ms']:7.1f} {r['pc_setup_ms']:8.1f} {r['ksp_ms']:7.1f} "
                  f"{r['tip_z_mm']:7.2f}", flush=True)
    if comm.rank == 0:
        write_csv(rows, out / "bench_newton.csv", COLUMNS)


# --------------------------------------------------------------------------------------------------
# Studies
# --------------------------------------------------------------------------------------------------
def linesearch_cases(L_beam: float, h: float) -> dict[str, tuple[bool, list[LoadStep]]]:
    """Large-rotation load cases of a 40×3×3 P1 beam: (needs a tip motion, steps)."""
    theta = np.pi  # pure bending into a half circle: tip rotated by θ and moved to the end of the arc
    arc_end = (L_beam * np.sin(theta) / theta - L_beam, 0.0, -(1 - np.cos(theta)) * L_beam / theta)
    return {
        "cantilever, gravity x10, 1 increment": (False, [LoadStep("g", gravity=10.0)]),
        "cantilever, gravity x10, 4 increments": (False, [LoadStep("g", gravity=10.0, increments=4)]),
        "root turned 360 deg under gravity, 8 incr.": (False, [LoadStep("g", gravity=1.0), LoadStep(
            "turn", angles={"root": 2 * np.pi}, increments=8)]),
        "pure bending to 180 deg, 4 increments": (True, [LoadStep(
            "bend", angles={"tip": theta}, translations={"tip": arc_end}, increments=4)]),
    }


def linesearch_study(out: Path) -> None:
    comm = MPI.COMM_WORLD
    msh = mesh.create_box(comm, [[0.0, 0.0, 0.0], [L, H, H]], [40, 3, 3])
    field = MaterialField.uniform(msh, MATERIAL)
    a = orientation.uniform(msh, (1.0, 0.0, 1.0))
    root = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.0))
    tip = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], L))
    rows = []
    for model in ("svk", "corotational"):
        for linesearch in ("basic", "bt", "l2", "cp"):
            for name, (bend, steps) in linesearch_cases(L, H).items():
                motions = [RigidMotion("root", root, axis=(0, 1, 0), point=(0, H / 2, H / 2))]
                if bend:
                    motions.append(RigidMotion("tip", tip, axis=(0, 1, 0), point=(L, H / 2, H / 2)))
                problem = ElasticityProblem(msh, field, orientation=a, model=model, motions=motions,
                                            prefix=f"ls_{model}_{linesearch}_", max_cutbacks=5,
                                            options={"snes_linesearch_type": linesearch, "snes_max_it": 50})
                t0 = time.perf_counter()
                try:
                    stats = problem.run(steps)
                    row = {"newton_its": sum(s.newton_iterations for s in stats),
                           "cutbacks": sum(s.cutbacks for s in stats), "result": "converged"}
                except ConvergenceError as e:
                    row = {"newton_its": "", "cutbacks": e.cutbacks,
                           "result": f"failed at {e.load_factor:.3f}: {e.reason}"}
                row.update(model=model, linesearch=linesearch, case=name, wall_s=time.perf_counter() - t0)
                rows.append(row)
                if comm.rank == 0:
                    print(f"{model:>12} {linesearch:>6} {name:44s} its {row['newton_its']!s:>4} cut-backs "
                          f"{row['cutbacks']:>2} {row['wall_s']:6.2f} s  {row['result']}", flush=True)
    if comm.rank == 0:
        write_csv(rows, out / "bench_newton_linesearch.csv",
                  ("model", "linesearch", "case", "newton_its", "cutbacks", "wall_s", "result"))


def polar_study(out: Path) -> None:
    """max |R_n - R| over random F with principal stretches in a range, after n scaled Newton iterations."""
    if MPI.COMM_WORLD.rank != 0:
        return
    n = 2000
    rng = np.random.default_rng(0)
    Q1 = Rotation.random(n, random_state=1).as_matrix()
    Q2 = Rotation.random(n, random_state=2).as_matrix()
    rows = []
    print(f"{'stretches':>12} " + " ".join(f"{f'n={k}':>8}" for k in range(1, 7)))
    for lo, hi in ((0.9, 1.1), (0.8, 1.25), (0.5, 2.0), (0.3, 3.0)):
        stretches = np.exp(rng.uniform(np.log(lo), np.log(hi), (n, 3)))
        F = Q1 @ (stretches[:, :, None] * Q2)
        R = np.array([polar(f)[0] for f in F])
        errors = [np.abs(polar_rotation(F, tol=0.0, max_iterations=k) - R).max() for k in range(1, 7)]
        rows.append({"stretch_min": lo, "stretch_max": hi, **{f"error_{k}": e for k, e in enumerate(errors, 1)}})
        print(f"{f'[{lo}, {hi}]':>12} " + " ".join(f"{e:8.1e}" for e in errors))
    write_csv(rows, out / "bench_newton_polar.csv", list(rows[0]))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench"))
    parser.add_argument("--quick", action="store_true", help="skip the ~150k-tetrahedra cases")
    parser.add_argument("--study", choices=("newton", "linesearch", "polar"), default="newton")
    args = parser.parse_args()
    PETSc.Log.begin()
    {"newton": lambda: newton_table(args.out, args.quick), "linesearch": lambda: linesearch_study(args.out),
     "polar": lambda: polar_study(args.out)}[args.study]()
