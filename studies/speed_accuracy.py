# %% [markdown]
# # Speed ↔ accuracy: what to pick for homogenization and for the beam
#
# This demo shows:
# - the FFT homogenization of Voronoi foams at several resolutions N, discretizations and tolerances: the
#   error of E1, E2, E3, G23, G13, G12 against a Richardson-extrapolated reference, vs the solver's wall time;
# - the scatter of the same constants over seeds for RVEs of several sizes (n_cells);
# - the cantilever beam of Fig. 6 (gravity) at several mesh sizes × degree {1, 2} × model {linear,
#   corotational, svk} × Newton tolerance: the error of the tip sag against the finest P2 result of the same
#   model, vs wall time;
# - a Pareto plot per study and a markdown "what to pick" table: for each target error, the cheapest setting.
#
# - the cross-check of the FFT reference with the periodic FEM RVE (P1, P2) on the conforming mesh of the same
#   smooth foam (meshes.rve.mesh_rve): the relative difference of each constant;
# - the Tripod, case B, as `demos/scenes/tripod_case_b_flat.toml` declares it (the `make demo` scene: foam_material
#   TI fit of the 15 %, γ = 0.1 foam, spiral l field, its load steps), built through ElasticityProblem so that
#   the mesh is shared by the settings: centre height and rotation at rest / middle (19°) / top (38°) for mesh
#   size × degree × model, against the finest P2 of the same model, with the small-strain validity measure of
#   fenicsfoam.validity.
#
# Run: `python studies/speed_accuracy.py --out out/speed_accuracy [--size ci|default|full]`, also under
# `mpirun -n N` (a batch: the beam and the Tripod run on all ranks; the homogenization runs — FFT, RVE size, FEM
# RVE — are independent serial jobs spread over the ranks by estimated cost, each on one thread and
# MPI.COMM_SELF, gathered on rank 0). `full` is the complete grid (~1.5 h on 2 ranks of the 2-core machine),
# `default` a reduced one (~10 min serial).
# Outputs (rank 0): `homogenization.csv`, `fem_crosscheck.csv`, `rve_size.csv`, `beam.csv`, `tripod.csv`,
# `*_pareto.png`, `what_to_pick.md`.
#
# Modelling choices (documented, not tuned):
# - reference of a foam: the rotated, zero-void runs at the two finest resolutions N₁ < N₂ and the reference
#   tolerance, Richardson-extrapolated assuming first order in the voxel size (the voxelized boundary is O(h)):
#   `X_ref = X(N₂) + (X(N₂) − X(N₁)) / (N₂/N₁ − 1)`;
# - tolerance: each FFT run goes to its block's tightest tol and records the result at every looser tolerance
#   on the way (`homogenize_fft(checkpoints=...)`: bit for bit what a run with that tol returns, with the wall
#   time it would have taken), so the tolerance axis costs no extra runs;
# - error of a setting: the largest relative error over E1, E2, E3, G23, G13, G12, leaving out constants below
#   1 % of the largest (E1 of the γ = 0.1 foam: not resolved at these N);
# - wall time: the FFT solver's on one thread (set-up and six load cases) or the beam's (problem set-up +
#   Newton), not the foam generation or meshing, which any setting pays once;
# - FEM cross-check: zero void, two-phase mesh_rve at h = 1/n (n grid cubes per side); difference of a constant
#   `(X_fem − X_ref) / |X_ref|`. P2 on a mesh is below P1 in energy (nested spaces), P1 is far too stiff in
#   bending-dominated struts, and the piecewise-linear interface loses solid volume (biasing the FEM low), so
#   the FEM is a cross-check with its own error, not a better reference; the report gives the meshed solid
#   fraction next to it;
# - the solid is isotropic E = 1, ν = 0.3; the void has zero stiffness (the reference) or, as a speed setting,
#   an ersatz stiffness 1e-3 × the solid's (CG converges much faster; its bias is ~1e-3 relative);
# - the beam is 250 × 15 × 15 mm, isotropic E = 1 MPa, ν = 0.3, ρ = 180 kg/m³, clamped at x = 0, gravity −z
#   (Euler–Bernoulli sag 46.0 mm, near the paper's −48 mm).

# %%
from __future__ import annotations

import argparse
import csv
import itertools
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from mpi4py import MPI

from homogenization.convergence import richardson_two_level

CONSTANTS = ("E1", "E2", "E3", "G23", "G13", "G12")
TARGETS = (0.1, 0.03, 0.01, 0.003)
BEAM = {"length": 0.25, "width": 0.015, "height": 0.015}
BEAM_MATERIAL = {"E": 1.0e6, "nu": 0.3, "rho": 180.0}
#: The Tripod study's scene (what `make demo` runs); its mesh size, degree and model are varied, nothing else.
TRIPOD_SCENE = Path(__file__).resolve().parents[1] / "demos" / "scenes" / "tripod_case_b_flat.toml"
#: The load steps the study reports (the scene's); the error is measured at the last one.
TRIPOD_STEPS = ("rest", "middle", "top")

# Study sizes. "ci" runs in seconds, "default" in ~10 min serial, "full" is the complete grid (the tables of
# docs/benchmarks/).
# fft: blocks of runs, each N × discretization × void of a block run once to the block's tol, recording every
# tolerance of "tols" down to it; the reference pair must be among the rotated, zero-void runs at reference_tol.
# rve_resolution: n_cells → N, N ≈ 16 ∛n_cells so that every RVE has ~16 voxels per cell width.
_MACRO = {
    "beam_h": [0.0075, 0.005, 0.00375], "degrees": [1, 2], "models": ["linear", "corotational", "svk"],
    "rtols": [1e-4, 1e-8], "tripod_h": [0.006, 0.0046, 0.0035], "tripod_degrees": [1, 2],
    "tripod_models": ["linear", "corotational", "svk"],
}
SIZES = {
    "ci": {
        "foams": [(0.34, 1.0)], "n_cells": 8, "tols": [1e-2, 1e-3],
        "fft": [{"N": [12, 16, 20], "discretizations": ["rotated"], "voids": [0.0, 1e-3], "tol": 1e-3,
                 "maxiter": 200}],
        "reference": (16, 20), "reference_tol": 1e-3,
        "rve_foams": [(0.34, 1.0)], "rve_resolution": {8: 16}, "rve_seeds": [1, 2], "rve_tol": 1e-3,
        "fem_grid": [8], "fem_degrees": [1],
        "beam_h": [0.0075], "degrees": [1, 2], "models": ["linear", "corotational"], "rtols": [1e-8],
        "tripod_h": [0.006], "tripod_degrees": [1], "tripod_models": ["corotational"],
    },
    "default": {
        "foams": [(0.34, 1.0), (0.18, 1.0), (0.34, 0.1)], "n_cells": 8, "tols": [1e-2, 1e-3],
        "fft": [{"N": [16, 24, 32, 48, 64], "discretizations": ["rotated"], "voids": [0.0, 1e-3], "tol": 1e-3,
                 "maxiter": 400}],
        "reference": (48, 64), "reference_tol": 1e-3,
        "rve_foams": [(0.34, 1.0)], "rve_resolution": {8: 32, 16: 40}, "rve_seeds": [1, 2, 3], "rve_tol": 1e-3,
        "fem_grid": [12, 16], "fem_degrees": [1, 2], **_MACRO,
    },
    "full": {
        "foams": [(d, g) for g in (1.0, 0.1) for d in (0.09, 0.18, 0.34)], "n_cells": 8,
        "tols": [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
        "fft": [{"N": [24, 32, 48, 64], "discretizations": ["rotated", "spectral"], "voids": [1e-3], "tol": 1e-8,
                 "maxiter": 1200},
                {"N": [24, 32, 48, 64], "discretizations": ["rotated"], "voids": [0.0], "tol": 1e-8,
                 "maxiter": 1200},
                {"N": [24, 32], "discretizations": ["spectral"], "voids": [0.0], "tol": 1e-8, "maxiter": 1200},
                {"N": [96, 128], "discretizations": ["rotated"], "voids": [0.0], "tol": 1e-4, "maxiter": 1200}],
        "reference": (96, 128), "reference_tol": 1e-4,
        "rve_foams": [(0.34, 1.0), (0.18, 1.0)], "rve_resolution": {8: 32, 16: 40, 32: 50, 64: 64},
        "rve_seeds": [1, 2, 3], "rve_tol": 1e-4, "fem_grid": [12, 16], "fem_degrees": [1, 2], **_MACRO,
    },
}


# %% [markdown]
# ## Homogenization: resolution × discretization × tolerance, RVE size, FEM cross-check of the reference

# %%
def constants_of(C: np.ndarray) -> np.ndarray:
    """E1, E2, E3, G23, G13, G12 of a Voigt stiffness (homogenization.tensors.engineering_constants)."""
    from homogenization.tensors import engineering_constants

    eng = engineering_constants(C)
    return np.array([eng[k] for k in CONSTANTS])


def relative_error(values: np.ndarray, reference: np.ndarray) -> float:
    """``max_i |X_i − X_ref,i| / |X_ref,i|`` over the constants with ``|X_ref,i| ≥ 0.01 max_j |X_ref,j|``.

    Constants below 1 % of the largest (E1 of a γ = 0.1 foam, ~1e-3 of E2) are left out: at these resolutions
    they are not resolved at all (their Richardson value may even be negative) and would hide the others.
    """
    kept = np.abs(reference) >= 0.01 * np.abs(reference).max()
    return float(np.max(np.abs(values[kept] - reference[kept]) / np.abs(reference[kept])))


def study_jobs(size: dict) -> list[dict]:
    """Every run of the homogenization studies, each independent and serial (MPI.COMM_SELF).

    ``fft``: one FFT run per foam × block × N × discretization × void, to the block's tol, recording every
    tolerance of ``size["tols"]`` down to it (``homogenize_fft(checkpoints=...)``); ``rve``: one FFT run per
    RVE-study foam × n_cells × seed; ``fem``: the FEM RVE (all degrees) per foam × mesh size.
    ``cost`` is a rough estimate in seconds, used only to balance the ranks.
    """
    jobs = []
    for density, gamma in size["foams"]:
        for block in size["fft"]:
            for N, discretization, void in itertools.product(block["N"], block["discretizations"], block["voids"]):
                iterations = 6 * (block["maxiter"] if void == 0.0 else min(block["maxiter"], 300))
                jobs.append({"kind": "fft", "density": density, "gamma": gamma, "N": N,
                             "discretization": discretization, "void": void, "tol": block["tol"],
                             "maxiter": block["maxiter"], "cost": 7e-8 * N**3 * iterations})
        for n in size["fem_grid"]:
            jobs.append({"kind": "fem", "density": density, "gamma": gamma, "n": n,
                         "cost": sum(20.0 * (n / 16) ** 3 * degree**3 for degree in size["fem_degrees"])})
    for (density, gamma), (n_cells, N), seed in itertools.product(
            size["rve_foams"], size["rve_resolution"].items(), size["rve_seeds"]):
        jobs.append({"kind": "rve", "density": density, "gamma": gamma, "n_cells": n_cells, "N": N, "seed": seed,
                     "cost": 7e-8 * N**3 * 6 * 300})
    return jobs


def run_jobs(comm: MPI.Comm, size: dict, jobs: list[dict], store: Path, resume: bool) -> list[dict] | None:
    """Run the jobs spread over the ranks (greedily, by estimated cost); rank 0 gets the rows, others None.

    Each rank runs its jobs one after the other on one thread (`threads=1`, MPI.COMM_SELF), so that wall times do
    not depend on how many ranks share the machine's cores. Each job's rows are written to ``store`` as it
    finishes (a JSON file named by the job); with ``resume`` a job whose file exists is read instead of rerun, so
    an interrupted multi-hour batch loses at most the jobs under way.
    """
    load, mine = np.zeros(comm.size), []
    for i in sorted(range(len(jobs)), key=lambda i: -jobs[i]["cost"]):
        rank = int(np.argmin(load))
        load[rank] += jobs[i]["cost"]
        if rank == comm.rank:
            mine.append(i)
    cache: dict[tuple, Any] = {}
    store.mkdir(parents=True, exist_ok=True)
    done = {}
    for i in sorted(mine):
        name = "_".join(f"{k}={v}" for k, v in jobs[i].items() if k != "cost")
        path = store / f"{name}.json"
        if resume and path.exists():
            done[i] = json.loads(path.read_text())
        else:
            done[i] = run_job(size, jobs[i], cache)
            write_text(path, json.dumps(done[i], default=lambda x: x.item()))
    gathered = comm.gather(done, root=0)
    if comm.rank != 0:
        return None
    merged = {i: rows for part in gathered for i, rows in part.items()}
    return [row for i in range(len(jobs)) for row in merged[i]]


def run_job(size: dict, job: dict, cache: dict) -> list[dict]:
    """The rows of one job (see :func:`study_jobs`); ``cache`` keeps this rank's foams and voxel images."""
    from homogenization.fem import homogenize_fem
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import InadmissibleMaterialError, isotropic_voigt
    from meshes.foam import FoamParameterError, VoronoiFoam
    from meshes.rve import SOLID, VOID, mesh_rve

    n_cells, seed = job.get("n_cells", size["n_cells"]), job.get("seed", 1)
    key = (job["density"], job["gamma"], n_cells, seed)
    if key not in cache:
        cache[key] = VoronoiFoam(n_cells=n_cells, density=job["density"], gamma=job["gamma"], seed=seed)
    foam = cache[key]
    solid = isotropic_voigt(1.0, 0.3)
    common = {k: job[k] for k in ("kind", "density", "gamma")}

    def constants_or_nan(C):
        try:
            return constants_of(C)
        except InadmissibleMaterialError as error:   # e.g. struts not resolved: the solid does not percolate
            print(f"  {job}: {error}", flush=True)
            return np.full(len(CONSTANTS), np.nan)

    if job["kind"] == "fem":
        try:
            rve = mesh_rve(foam, 1.0 / job["n"], MPI.COMM_SELF)
        except FoamParameterError as error:   # h too coarse for this foam's struts: reported, not run
            print(f"FEM RVE foam {job['density']} γ={job['gamma']} h=1/{job['n']}: {error}", flush=True)
            return [{**common, "h": f"1/{job['n']}", "failure": str(error)}]
        rows = []
        for degree in size["fem_degrees"]:
            r = homogenize_fem(rve.mesh, rve.cell_tags, {SOLID: solid, VOID: np.zeros((6, 6))}, degree=degree,
                               comm=MPI.COMM_SELF)
            rows.append({**common, "h": f"1/{job['n']}", "tets": rve.n_elements, "degree": degree,
                         "dofs": r.info["n_dofs"], "solid_fraction": r.info["volume_fractions"][SOLID],
                         "mesh_s": rve.meshing_s, "wall_s": r.wall_s,
                         **{f"C{j + 1}{j + 1}": r.C[j, j] for j in range(6)}})
            try:
                rows[-1].update(zip(CONSTANTS, constants_of(r.C)))
            except InadmissibleMaterialError as error:   # the meshed solid does not percolate at this h
                rows[-1]["failure"] = f"P{degree}: {error}"
            print(f"FEM RVE foam {job['density']} γ={job['gamma']} h=1/{job['n']} ({rve.n_elements} tets) P{degree}: "
                  f"solid {rows[-1]['solid_fraction']:.4f}, {r.wall_s:.1f} s", flush=True)
        return rows

    image_key = (*key, job["N"])
    if image_key not in cache:
        cache[image_key] = foam.voxelize(job["N"]).astype(np.int8)
    if job["kind"] == "rve":
        r = homogenize_fft(cache.pop(image_key), [0.0 * solid, solid], tol=size["rve_tol"], threads=1,
                           raise_on_failure=False, allow_singular=True)  # a singular C: NaN constants below
        return [{**common, "n_cells": n_cells, "N": job["N"], "seed": seed, "wall_s": r.wall_s,
                 "converged": r.converged, **dict(zip(CONSTANTS, constants_or_nan(r.C)))}]

    tols = [t for t in size["tols"] if t >= job["tol"]]
    r = homogenize_fft(cache[image_key], [job["void"] * solid, solid], discretization=job["discretization"],
                       tol=job["tol"], maxiter=job["maxiter"], threads=1, checkpoints=tols, raise_on_failure=False,
                       allow_singular=True)  # a coarse foam that does not percolate: NaN constants (constants_or_nan)
    rows = []
    for point in r.info["checkpoints"]:
        rows.append({**common, "N": job["N"], "discretization": job["discretization"], "void": job["void"],
                     "tol": point["tol"], "wall_s": point["wall_s"], "iterations": int(sum(point["iterations"])),
                     "converged": point["converged"], **dict(zip(CONSTANTS, constants_or_nan(point["C"])))})
    print(f"foam {job['density']} γ={job['gamma']} N={job['N']:3d} {job['discretization']:8s} void={job['void']:g}: "
          + ", ".join(f"tol {p['tol']:.0e} {sum(p['iterations'])} its {p['wall_s']:.1f} s"
                      + ("" if p["converged"] else " (not reached)") for p in r.info["checkpoints"]), flush=True)
    return rows


def homogenization_study(comm: MPI.Comm, size: dict, store: Path, resume: bool = False
                         ) -> tuple[list[dict], list[dict], list[dict]] | None:
    """Rows of the FFT resolution study, of the FEM cross-check and of the RVE-size study (rank 0; None elsewhere).

    Per foam the FFT reference is the Richardson extrapolation of the rotated, zero-void runs at
    ``size["reference"] = (N₁, N₂)`` and ``size["reference_tol"]``; each FFT row gets its ``error`` against it and
    ``{X}_ref``, each FEM row ``{X}_diff = (X_fem − X_ref)/|X_ref|``, ``{X}_fft_finest_diff`` (the same for
    X(N₂)) and ``max_diff``; each RVE row (n_cells, N) the mean and scatter (std/mean) over the seeds.
    """
    rows = run_jobs(comm, size, study_jobs(size), store, resume)
    if rows is None:
        return None
    n1, n2 = size["reference"]
    hom_rows, fem_rows, rve_rows = [], [], []
    for density, gamma in size["foams"]:
        foam_rows = [r for r in rows if (r["density"], r["gamma"]) == (density, gamma)]

        def at(N, foam_rows=foam_rows):
            match = [r for r in foam_rows if r["kind"] == "fft" and r["N"] == N and r["discretization"] == "rotated"
                     and r["void"] == 0.0 and r["tol"] == size["reference_tol"]]
            return np.array([match[0][k] for k in CONSTANTS])

        finest = at(n2)
        # first order (the voxel staircase); a reference level without a positive-definite C (NaN constants)
        # leaves the reference NaN, which self_checks reports
        coarse = at(n1)
        finite = np.all(np.isfinite(coarse)) and np.all(np.isfinite(finest))
        reference = (richardson_two_level(coarse, finest, n2 / n1, order=1.0) if finite
                     else np.full(len(CONSTANTS), np.nan))
        for r in foam_rows:
            values = np.array([r.get(k, np.nan) for k in CONSTANTS])
            if r["kind"] == "fft":
                r["error"] = relative_error(values, reference) if np.all(np.isfinite(values)) else np.inf
                hom_rows.append({**r, **{f"{k}_ref": x for k, x in zip(CONSTANTS, reference)}})
            elif r["kind"] == "fem" and r.get("failure"):
                fem_rows.append(r)
            elif r["kind"] == "fem":
                fem_rows.append({**r, "max_diff": relative_error(values, reference),
                                 **{f"{k}_ref": x for k, x in zip(CONSTANTS, reference)},
                                 **{f"{k}_diff": (v - x) / abs(x) for k, v, x in zip(CONSTANTS, values, reference)},
                                 **{f"{k}_fft_finest_diff": (f - x) / abs(x)
                                    for k, f, x in zip(CONSTANTS, finest, reference)}})
    for (density, gamma), (n_cells, N) in itertools.product(size["rve_foams"], size["rve_resolution"].items()):
        values = np.array([[r[k] for k in CONSTANTS] for r in rows if r["kind"] == "rve" and r["n_cells"] == n_cells
                           and (r["density"], r["gamma"]) == (density, gamma)])
        scatter = values.std(axis=0, ddof=1) / np.abs(values.mean(axis=0))
        rve_rows.append({"density": density, "gamma": gamma, "n_cells": n_cells, "N": N, "seeds": len(values),
                         "max_scatter": float(np.nanmax(scatter)),
                         **{f"{k}_mean": v for k, v in zip(CONSTANTS, values.mean(axis=0))},
                         **{f"{k}_scatter": v for k, v in zip(CONSTANTS, scatter)}})
        print(f"RVE ρ={density} γ={gamma} n_cells={n_cells} N={N}: seed scatter (std/mean) max "
              f"{np.nanmax(scatter):.3f}", flush=True)
    return hom_rows, fem_rows, rve_rows


# %% [markdown]
# ## Macro FEM: the Fig. 6 beam under gravity

# %%
def finest_p2(rows: list[dict], degrees: list[int]) -> dict | None:
    """The macro reference: the row of the highest degree, smallest mesh size and tightest Newton rtol.

    ``None`` when no row has the highest degree (e.g. every P2 Tripod run of a model failed).
    """
    candidates = [r for r in rows if r["degree"] == max(degrees)]
    return min(candidates, key=lambda r: (r["h_mm"], r.get("snes_rtol", 0))) if candidates else None


def same_mesh_and_degree(a: dict, b: dict) -> bool:
    """Whether two macro rows share mesh size and degree (a row on the reference's mesh is no "setting")."""
    return (a["h_mm"], a["degree"]) == (b["h_mm"], b["degree"])


def beam_study(comm: MPI.Comm, size: dict) -> list[dict]:
    """Tip sag of the beam for every mesh size × degree × model × Newton rtol (collective)."""
    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.materials import Isotropic
    from fenicsfoam.probes import TipDeflection
    from fenicsfoam.solver import ElasticityProblem, LoadStep
    from meshes.beam import CLAMPED_FACE, TIP_FACE, make_beam

    material = Isotropic(**BEAM_MATERIAL)
    rows = []
    for h in size["beam_h"]:
        beam = make_beam(comm, h=h, **BEAM)
        field = MaterialField.uniform(beam.mesh, material)
        for degree in size["degrees"]:
            for model in size["models"]:
                for rtol in size["rtols"]:
                    t0 = time.perf_counter()
                    problem = ElasticityProblem(
                        beam.mesh, field, model=model, degree=degree, prefix=f"speed_{model}_",
                        motions=[RigidMotion("clamp", beam.facet_tags.find(CLAMPED_FACE))],
                        options={"snes_rtol": rtol})
                    stats = problem.run([LoadStep("gravity", gravity=1.0)])
                    sag = -TipDeflection(problem.V, beam.facet_tags, TIP_FACE, (0.0, 0.0, 1.0))(problem.u)
                    wall = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
                    rows.append({"h_mm": 1e3 * h, "tets": beam.n_cells, "degree": degree, "model": model,
                                 "snes_rtol": rtol, "dofs": problem.V.dofmap.index_map.size_global * 3,
                                 "newton_iterations": stats[0].newton_iterations, "wall_s": wall, "sag_m": sag})
                    if comm.rank == 0:
                        print(f"beam h={1e3 * h:.2f} mm ({beam.n_cells} tets) P{degree} {model:12s} rtol={rtol:.0e}: "
                              f"sag {1e3 * sag:.3f} mm, {wall:.2f} s", flush=True)
    for model in size["models"]:
        finest = finest_p2([r for r in rows if r["model"] == model], size["degrees"])
        for r in rows:
            if r["model"] == model:
                r["reference_sag_m"] = finest["sag_m"]
                r["error"] = abs(r["sag_m"] - finest["sag_m"]) / abs(finest["sag_m"])
    return rows


# %% [markdown]
# ## Macro FEM: the Tripod, case B, from its scene file

# %%
def tripod_study(comm: MPI.Comm, size: dict) -> list[dict]:
    """Centre height and rotation after each step of TRIPOD_SCENE for every mesh size × degree × model.

    Everything but h, degree and model is the scene's (materials through ``foam_material`` with the scene's
    parameters, spiral l field, gravity, servo steps and their increments, PETSc options); each mesh is built once.
    """
    from fenicsfoam import orientation
    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.materials import foam_material
    from fenicsfoam.probes import CenterHeight, CenterRotation
    from fenicsfoam.scene import load_scene, spiral_directions
    from fenicsfoam.scene.build import load_steps
    from fenicsfoam.solver import ConvergenceError, ElasticityProblem
    from fenicsfoam.validity import small_strain_validity
    from meshes.tripod import ARM_END, RING, TripodGeometry, make_tripod

    scene = load_scene(TRIPOD_SCENE)
    if tuple(s.label for s in scene.steps) != TRIPOD_STEPS or scene.orientation["kind"] != "spiral":
        raise ValueError(f"{TRIPOD_SCENE}: the study needs the steps {TRIPOD_STEPS} and a spiral orientation")
    region_materials = {region.name: foam_material(**region.parameters) for region in scene.regions}
    materials = {tag: region_materials[region.name] for region in scene.regions for tag in region.tags}
    spec = scene.orientation
    geometry = dict(scene.geometry)
    del geometry["h"]
    order, layers = geometry.pop("order"), geometry.pop("layers")
    steps = load_steps(scene)  # the scene's schedule: its servo angles in radians
    rows = []
    for h in size["tripod_h"]:
        tripod = make_tripod(comm, h, TripodGeometry(**geometry), order, layers)
        field = MaterialField.from_regions(tripod.mesh, tripod.cell_tags, materials)
        l_axis = orientation.from_callable(tripod.mesh, lambda x: spiral_directions(
            x, spec["pitch_deg"], spec["handedness"], spec["center"]))
        servos = [RigidMotion(f"servo{i}", tripod.cell_tags.find(ARM_END[i]), dim=3, axis=tuple(frame.axis),
                              point=tuple(frame.pivot)) for i, frame in enumerate(tripod.geometry.servo_frames())]
        for degree in size["tripod_degrees"]:
            for model in size["tripod_models"]:
                t0 = time.perf_counter()
                problem = ElasticityProblem(tripod.mesh, field, orientation=l_axis, model=model, degree=degree,
                                            gravity=scene.gravity, motions=servos, options=dict(scene.petsc),
                                            prefix=f"speed_tripod_{model}_")
                height, rotation = (CenterHeight(problem.V, tripod.cell_tags, RING),
                                    CenterRotation(problem.V, tripod.cell_tags, RING))
                row = {"h_mm": 1e3 * h, "tets": tripod.n_cells, "degree": degree, "model": model,
                       "dofs": problem.V.dofmap.index_map.size_global * 3, "newton_iterations": 0, "failure": "",
                       **{f"{label}_{q}": np.nan for label in TRIPOD_STEPS for q in ("height_mm", "rotation_deg")}}
                try:
                    for step in steps:
                        stats = problem.solve_step(step)
                        row["newton_iterations"] += stats.newton_iterations
                        row[f"{step.label}_height_mm"] = 1e3 * height(problem.u)
                        row[f"{step.label}_rotation_deg"] = rotation(problem.u)
                except ConvergenceError as failure:    # recorded: a limit of the model, not of the demo
                    row["failure"] = str(failure)
                row["wall_s"] = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
                row["quadratic_strain"] = small_strain_validity(problem.u).quadratic_strain
                rows.append(row)
                if comm.rank == 0:
                    print(f"tripod h={1e3 * h:.1f} mm ({tripod.n_cells} tets) P{degree} {model}: top height "
                          f"{row['top_height_mm']:.2f} mm, rotation {row['top_rotation_deg']:.2f}°, "
                          f"{row['wall_s']:.1f} s {row['failure']}", flush=True)
    # error: against the finest highest-degree completed result of the same model, largest over the top
    # state's height (relative; z = 0 is the plate's mid-plane at rest) and rotation (relative); NaN if the run
    # failed or if no highest-degree run of the model completed (no reference)
    for model in size["tripod_models"]:
        ref = finest_p2([r for r in rows if r["model"] == model and not r["failure"]], size["tripod_degrees"])
        for r in rows:
            if r["model"] == model:
                r["error"] = np.nan if r["failure"] or ref is None else max(
                    abs(r["top_height_mm"] - ref["top_height_mm"]) / abs(ref["top_height_mm"]),
                    abs(r["top_rotation_deg"] - ref["top_rotation_deg"]) / abs(ref["top_rotation_deg"]))
    return rows


# %% [markdown]
# ## Pareto fronts and "what to pick"

# %%
def pareto_front(rows: list[dict]) -> list[dict]:
    """Rows not dominated in (wall_s, error): no other row is both faster and more accurate."""
    front, best = [], np.inf
    for r in sorted(rows, key=lambda r: (r["wall_s"], r["error"])):
        if r["error"] < best:
            front.append(r)
            best = r["error"]
    return front


def cheapest(rows: list[dict], target: float) -> dict | None:
    """The fastest row with error ≤ target (None if none reaches it)."""
    ok = [r for r in rows if r["error"] <= target and r.get("converged", True)]
    return min(ok, key=lambda r: r["wall_s"]) if ok else None


def what_to_pick(groups: list[tuple[str, list[dict]]], describe, exclude=None) -> str:
    """Markdown table: per group and target error, the cheapest setting, its error and wall time.

    ``exclude(row)`` leaves rows out (the reference itself, whose error is zero by construction).
    """
    lines = ["| case | target error | cheapest setting | error | wall s |", "|---|---|---|---|---|"]
    for name, group in groups:
        if exclude is not None:
            group = [r for r in group if not exclude(r)]
        for target in TARGETS:
            r = cheapest(group, target)
            setting = describe(r) if r else "none of the settings run"
            error = f"{r['error']:.1e}" if r else "–"
            wall = f"{r['wall_s']:.2f}" if r else "–"
            lines.append(f"| {name} | {target:g} | {setting} | {error} | {wall} |")
    return "\n".join(lines)


def plot_pareto(path: Path, groups: list[tuple[str, list[dict]]], title: str) -> None:
    """Error vs wall time, one colour per group, the Pareto front as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for name, group in groups:
        points = [r for r in group if r["error"] > 0]
        line = ax.loglog([r["wall_s"] for r in points], [r["error"] for r in points], "o", alpha=0.5, label=name)
        front = pareto_front(points)
        ax.loglog([r["wall_s"] for r in front], [r["error"] for r in front], "-", color=line[0].get_color())
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("relative error")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    os.replace(tmp, path)


def write_csv(path: Path, rows: list[dict]) -> None:
    """All rows (union of keys) to CSV, atomically."""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


def write_text(path: Path, text: str) -> None:
    """Text file, atomically."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


# %% [markdown]
# ## Driver and self-checks

# %%
def groups_by(rows: list[dict], keys: tuple[str, ...], values: list[tuple], label) -> list[tuple[str, list[dict]]]:
    """``[(label(*v), rows whose keys equal v) for v in values]``."""
    return [(label(*v), [r for r in rows if tuple(r[k] for k in keys) == tuple(v)]) for v in values]


def fft_table(size: dict, hom_rows: list[dict]) -> str:
    """Markdown: one line per foam × N × discretization × void, one column per tolerance (error / its / s)."""
    tols = size["tols"]
    lines = ["| foam | N | discretization | void | " + " | ".join(f"tol {t:g}" for t in tols) + " |",
             "|" + "---|" * (4 + len(tols))]
    runs = dict.fromkeys((r["density"], r["gamma"], r["N"], r["discretization"], r["void"]) for r in hom_rows)
    for run in runs:
        at = {r["tol"]: r for r in hom_rows
              if (r["density"], r["gamma"], r["N"], r["discretization"], r["void"]) == run}
        cells = [f"{at[t]['error']:.2g} / {at[t]['iterations']} / {at[t]['wall_s']:.3g}"
                 + ("" if at[t]["converged"] else " (n.r.)") if t in at else "–" for t in tols]
        lines.append(f"| ρ={run[0]} γ={run[1]} | {run[2]} | {run[3]} | {run[4]:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def report(size_name: str, size: dict, hom_rows, fem_rows, rve_rows, beam_rows, tripod_rows) -> str:
    """The markdown "what to pick" report (what_to_pick.md)."""
    foam_groups = groups_by(hom_rows, ("density", "gamma"), size["foams"], lambda d, g: f"ρ={d} γ={g}")
    beam_groups = groups_by(beam_rows, ("model",), [(m,) for m in size["models"]], str)
    tripod_groups = groups_by(tripod_rows, ("model",), [(m,) for m in size["tripod_models"]], str)
    beam_ref = {m: finest_p2(g, size["degrees"]) for m, g in beam_groups}
    tripod_ref = {m: finest_p2([r for r in g if not r["failure"]], size["tripod_degrees"]) for m, g in tripod_groups}
    fem_ok = [r for r in fem_rows if not r.get("failure")]   # refused or non-percolating meshes are listed apart
    return "\n".join([
        "# What to pick", "", f"Study size `{size_name}`; errors are relative (see the demo's header).", "",
        "## FFT homogenization (max relative error over E1, E2, E3, G23, G13, G12 ≥ 1 % of the largest)", "",
        what_to_pick(foam_groups, lambda r: f"N = {r['N']}, {r['discretization']}, void {r['void']:g}, "
                                            f"tol {r['tol']:g}"), "",
        "Every run: error / iterations (six load cases) / wall s at each tolerance; \"–\" where the run's tol was "
        "looser, \"(n.r.)\" where the run stopped at maxiter before reaching it.", "",
        fft_table(size, hom_rows), "",
        "## FEM RVE cross-check of the FFT reference (zero void; difference (X_fem − X_ref)/|X_ref|)", "",
        "| foam | FEM | tets | dofs | solid | " + " | ".join(f"Δ{k}" for k in CONSTANTS) + " | wall s |",
        "|" + "---|" * (6 + len(CONSTANTS)),
        *[f"| ρ={r['density']} γ={r['gamma']} | P{r['degree']}, h = {r['h']} | {r['tets']} | {r['dofs']} | "
          f"{r['solid_fraction']:.4f} | " + " | ".join(f"{100 * r[f'{k}_diff']:+.1f} %" for k in CONSTANTS)
          + f" | {r['wall_s']:.1f} |" for r in fem_ok], "",
        *[f"Not used: ρ={r['density']} γ={r['gamma']} h = {r['h']}: {r['failure']}" for r in fem_rows
          if r.get("failure")], "",
        "Finest FFT (no extrapolation) vs the reference: " + "; ".join(
            f"ρ={d} γ={g}: " + ", ".join(f"{k} {100 * r[f'{k}_fft_finest_diff']:+.1f} %" for k in CONSTANTS)
            for (d, g), r in {(r["density"], r["gamma"]): r for r in fem_ok}.items()), "",
        "## RVE size: scatter over seeds (std/mean, max over the six constants)", "",
        "| foam | n_cells | N | seeds | max scatter | " + " | ".join(f"{k} mean" for k in CONSTANTS) + " |",
        "|" + "---|" * (5 + len(CONSTANTS)),
        *[f"| ρ={r['density']} γ={r['gamma']} | {r['n_cells']} | {r['N']} | {r['seeds']} | {r['max_scatter']:.3f} | "
          + " | ".join(f"{r[f'{k}_mean']:.4g}" for k in CONSTANTS) + " |" for r in rve_rows], "",
        "## Beam tip sag (error against the finest P2 of the same model)", "",
        what_to_pick(beam_groups, lambda r: f"h = {r['h_mm']:g} mm ({r['tets']} tets), P{r['degree']}, "
                                            f"rtol {r['snes_rtol']:g}",
                     exclude=lambda r: same_mesh_and_degree(r, beam_ref[r["model"]])), "",
        "Finest P2 sag per model (mm): " + ", ".join(f"{m} {1e3 * r['sag_m']:.3f}" for m, r in beam_ref.items()), "",
        "## Tripod case B, top position (error: max of relative height and rotation errors)", "",
        what_to_pick(tripod_groups, lambda r: f"h = {r['h_mm']:g} mm ({r['tets']} tets), P{r['degree']}",
                     exclude=lambda r: tripod_ref[r["model"]] is not None
                     and same_mesh_and_degree(r, tripod_ref[r["model"]])), "",
        *[f"No completed P{max(size['tripod_degrees'])} run of {m}: no reference, its errors are NaN." for m, ref
          in tripod_ref.items() if ref is None], "",
        "| h mm | tets | P | model | rest height mm | rest rot ° | middle height mm | middle rot ° | "
        "top height mm | top rot ° | max ‖½∇uᵀ∇u‖ | Newton its | wall s |", "|" + "---|" * 13,
        *[f"| {r['h_mm']:g} | {r['tets']} | {r['degree']} | {r['model']} | {r['rest_height_mm']:.2f} | "
          f"{r['rest_rotation_deg']:.2f} | {r['middle_height_mm']:.2f} | {r['middle_rotation_deg']:.2f} | "
          f"{r['top_height_mm']:.2f} | {r['top_rotation_deg']:.2f} | {r['quadratic_strain']:.2f} | "
          f"{r['newton_iterations']} | "
          f"{r['wall_s']:.1f} |" for r in tripod_rows], "",
        *[f"Failed: h = {r['h_mm']:g} mm P{r['degree']} {r['model']}: {r['failure']}" for r in tripod_rows
          if r["failure"]], ""])


def timoshenko_sag() -> float:
    """Tip sag of the study's beam: q L⁴/(8 E I) + q L²/(2 κ G A), κ = 10(1+ν)/(12+11ν), q = ρ g A."""
    E, nu, rho = BEAM_MATERIAL["E"], BEAM_MATERIAL["nu"], BEAM_MATERIAL["rho"]
    L, a = BEAM["length"], BEAM["width"]
    q, kappa = rho * 9.81 * a * a, 10 * (1 + nu) / (12 + 11 * nu)
    return q * L**4 / (8 * E * a**4 / 12) + q * L**2 / (2 * kappa * E / (2 * (1 + nu)) * a * a)


def self_checks(size: dict, hom_rows, fem_rows, beam_rows, tripod_rows) -> list[str]:
    """The demo's checks; returns the failures.

    Every macro error of a completed run is finite (a Tripod run may fail with ConvergenceError, a limit of its
    model that is reported, not hidden; a model none of whose highest-degree runs completed has no reference);
    every FFT reference is finite, and every FFT error where C was positive
    definite; for the isotropic foams the finest N beats the coarsest at the tightest tol with zero void
    (γ = 0.1: its soft shear moduli are not in the asymptotic range, measured non-monotone, so no such check);
    the finest P2 linear sag is within 5 % of Timoshenko; every FEM RVE constant is finite and on each mesh the
    diagonal of the P2 stiffness is at most the P1 one (nested spaces: the P2 energy minimum is lower).
    """
    failures = []
    tripod_models = {r["model"] for r in tripod_rows if not r["failure"] and r["degree"] == max(size["tripod_degrees"])}
    if not all(np.isfinite(r["error"]) for r in beam_rows + [r for r in tripod_rows if not r["failure"]
                                                             and r["model"] in tripod_models]):
        failures.append("non-finite macro error")
    if not all(np.isfinite(r["E2_ref"]) for r in hom_rows):
        failures.append("a Richardson reference is not finite")
    if not all(np.isfinite(r["error"]) for r in hom_rows if np.isfinite(r["E2"])):
        failures.append("non-finite FFT error with a positive-definite C")
    for density, gamma in size["foams"]:
        tight = sorted((r for r in hom_rows if (r["density"], r["gamma"]) == (density, gamma)
                        and r["tol"] == size["reference_tol"] and r["void"] == 0.0
                        and r["discretization"] == "rotated"), key=lambda r: r["N"])
        if gamma == 1.0 and not tight[-1]["error"] < tight[0]["error"]:
            failures.append(f"foam {density}: N = {tight[-1]['N']} is not more accurate than N = {tight[0]['N']}")
    fem_rows = [r for r in fem_rows if not r.get("failure")]   # refused or non-percolating meshes (reported)
    if not all(np.isfinite(r[k]) for r in fem_rows for k in CONSTANTS):
        failures.append("non-finite FEM RVE constant")
    for p1 in (r for r in fem_rows if r["degree"] == 1):
        for p2 in (r for r in fem_rows if r["degree"] == 2 and (r["density"], r["gamma"], r["h"]) == (
                p1["density"], p1["gamma"], p1["h"])):
            if any(p2[f"C{j}{j}"] > p1[f"C{j}{j}"] * (1 + 1e-8) for j in range(1, 7)):
                failures.append(f"FEM RVE foam {p1['density']} γ={p1['gamma']} h={p1['h']}: P2 stiffer than P1")
    linear = [r for r in beam_rows if r["model"] == "linear"]
    if linear:
        sag = finest_p2(linear, size["degrees"])["sag_m"]
        if abs(sag / timoshenko_sag() - 1) > 0.05:
            failures.append(f"linear P2 sag {sag:.4g} m vs Timoshenko {timoshenko_sag():.4g} m")
    return failures


def main(out: Path, size_name: str, comm: MPI.Comm = MPI.COMM_WORLD, resume: bool = False) -> list[str]:
    """Run the studies; write outputs on rank 0; return the failed checks (empty when all pass)."""
    size = SIZES[size_name]
    beam_rows = beam_study(comm, size)
    tripod_rows = tripod_study(comm, size)
    studies = homogenization_study(comm, size, out / "jobs", resume)
    failures = []
    if comm.rank == 0:
        hom_rows, fem_rows, rve_rows = studies
        out.mkdir(parents=True, exist_ok=True)
        for name, rows in (("homogenization", hom_rows), ("fem_crosscheck", fem_rows), ("rve_size", rve_rows),
                           ("beam", beam_rows), ("tripod", tripod_rows)):
            write_csv(out / f"{name}.csv", rows)
        plot_pareto(out / "homogenization_pareto.png",
                    groups_by(hom_rows, ("density", "gamma"), size["foams"], lambda d, g: f"ρ={d} γ={g}"),
                    "FFT homogenization: error vs wall time")
        for name, rows, degrees, title in (
                ("beam", beam_rows, size["degrees"], "beam tip sag: error vs finest P2, wall time"),
                ("tripod", tripod_rows, size["tripod_degrees"], "Tripod case B (top): error vs finest P2")):
            models = sorted({r["model"] for r in rows})
            groups = groups_by([r for r in rows if r["error"] > 0], ("model", "degree"),
                               [(m, p) for m in models for p in degrees], lambda m, p: f"{m} P{p}")
            plot_pareto(out / f"{name}_pareto.png", groups, title)
        text = report(size_name, size, hom_rows, fem_rows, rve_rows, beam_rows, tripod_rows)
        write_text(out / "what_to_pick.md", text)
        print(text)
        failures = self_checks(size, hom_rows, fem_rows, beam_rows, tripod_rows)
    return comm.bcast(failures, root=0)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Speed ↔ accuracy study: FFT homogenization, beam, Tripod case B.")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--size", choices=sorted(SIZES), default="default",
                        help="study size: ci (seconds), default (~10 min serial), full (the complete grid, hours)")
    parser.add_argument("--ci", action="store_const", const="ci", dest="size", help="same as --size ci")
    parser.add_argument("--resume", action="store_true",
                        help="reuse the homogenization jobs already in OUT/jobs (an interrupted run) instead of "
                             "rerunning")
    args = parser.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    failed = main(args.out, args.size, resume=args.resume)
    if MPI.COMM_WORLD.rank == 0:
        print("checks:", "; ".join(failed) if failed else "all passed")
    sys.exit(1 if failed else 0)
