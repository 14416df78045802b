# %% [markdown]
# # The pipeline of `make demo`: foam → homogenized constants → the Tripod robot
#
# This demo shows:
# - one stochastic Voronoi foam of the Tripod's material (15 %, γ = 0.1, 8 cells, seed 0) homogenized by the
#   FFT solver exactly as each sample of the shipped table is (`homogenization.tables.homogenize_sample`);
# - the plate's transversely isotropic constants interpolated from the shipped, seed-averaged table
#   (`fenicsfoam.materials.foam_material`, TPU: E_s = 12 MPa, ν_s = 0.3, 1190 kg/m³);
# - `demos/scenes/tripod_case_b_flat.toml` run through `fenicsfoam.scene.run_scene`: rest, middle (+19°) and top
#   (+38°) servo positions; the centre's height and rotation as changes from rest beside the paper's Table I.
#
# ## Stage 1: the cell problem
#
# *Continuous.* On the periodic unit cell Y with stiffness C(y) (the isotropic solid in the struts, zero in the
# void), for each macroscopic strain E find the periodic fluctuation ũ such that
#
#     div σ = 0 in Y,     σ = C(y) : (E + ε(ũ)),     ũ periodic,     then C_hom : E = ⟨σ⟩.
#
# *Weak form.* ∫_Y ε(w) : C : (E + ε(ũ)) dy = 0 for every periodic w; equivalently, in Fourier space, the
# compatible part of the stress vanishes: G[C : ε] = 0 with ε = E + ε̃ (the Green operator G projects onto
# compatible strain fields).
#
# *Discrete.* The foam voxelized at N³ = 48³, Willot's rotated finite-difference Green operator (trilinear
# hexahedra with one-point integration), the equation solved by conjugate gradients to a relative equilibrium
# residual 1e-4 for the six unit strains; the six columns ⟨σ⟩ give the 6×6 C_hom.
#
# ## Stage 2: the table
# `foam_material(density, gamma, E_solid, nu_solid)` interpolates the seed-averaged table (PCHIP in density
# and in log γ) and returns the closest TI material with its l axis along the foam's x axis.
#
# ## Stage 3: the robot
# Quasi-static finite strain of the plate under its weight and the servo motions (see `demos/tripod.py` for
# the continuous problem, the weak form and the discretization: P1, corotational TI model, SNES Newton).
#
# ## Checks (exit status 1 if one fails)
# - full size: the recomputed foam sample reproduces the shipped table's sample of the same seed and settings
#   (every engineering constant to 1e-6 relative: the table can be regenerated from its recorded settings);
#   `--ci` (a smaller foam, not a table node): the γ = 0.1 foam is softest along its x axis;
# - the plate material is transversely isotropic and soft along l (E_l < E_t);
# - the centre rises from rest to middle to top, and its rise and twist are within `TABLE_I_RATIO_BAND`
#   = [0.7, 1.3] of the real robot's (measured 0.87–1.22; see `demos/tripod.py`).
#
# Outputs under `--out`: `tripod_case_b_flat/` (summary.json, probes.csv, solution.xdmf, pictures) and
# `pipeline.json`. `--ci` runs a smaller foam (6 cells, N = 24) and a coarser plate (h = 6 mm).
#
# Run: `python demos/pipeline.py --out out [--ci]` (`make demo`), also under `mpirun -n 2`.

# %%
import json
import sys
import tomllib
from pathlib import Path

import numpy as np
from _demo import SCENES, TABLE_I, TABLE_I_RATIO_BAND, deltas, parse_args, print0, ratio_check, report
from mpi4py import MPI

from fenicsfoam.materials import TransverseIsotropic, foam_material
from fenicsfoam.scene import run_scene
from homogenization import tables

SCENE = "tripod_case_b_flat"
#: The recomputed sample against the shipped one (same foam, same settings): a round-off bound.
REPRODUCE_RTOL = 1e-6
CONSTANTS = ("E1", "E2", "E3", "G23", "G12")
#: --ci: foam settings and the plate's mesh size (m).
CI_SETTINGS = tables.SweepSettings(n_cells=6, resolution=24, tol=1e-3)
CI_H = 0.006
#: Why the Tripod runs at degree 1 although the mesh check warns against it (one line, printed before the run).
DEGREE_NOTE = ("Tripod at degree 1 as the paper's Table I model (2.7k linear tets, about one through the 5 mm plate), "
               "so the P1 warning below is expected; on the shipped mesh degree 2 gives a rise and twist at top of "
               "19.2 mm, -15.9 deg "
               "(P1: 25.1 mm, -19.2 deg; real robot 20.5 mm, 22.1 deg)")


# %% [markdown]
# ## Stage 1 and 2: one foam sample, and the plate's constants from the table


# %%
def homogenize_one_foam(density: float, gamma: float, settings: tables.SweepSettings, comm: MPI.Comm
                        ) -> dict | None:
    """One foam sample (seed 0), exactly as the table's sweep computes it (rank 0; None elsewhere)."""
    if comm.rank != 0:
        return None
    return tables.homogenize_sample(tables.Sample(density, gamma, seed=0), settings)


def table_rows(path: Path, density: float, gamma: float, **match: float) -> list[dict]:
    """The rows of a shipped table CSV at (density, gamma) whose other columns equal ``match``."""
    t = tables.read_csv(path)
    mask = np.isclose(t["density"], density) & np.isclose(t["gamma"], gamma)
    for key, value in match.items():
        mask &= np.isclose(t[key], value)
    return [{k: t[k][i] for k in t} for i in np.flatnonzero(mask)]


def foam_stage(region: dict, ci: bool, comm: MPI.Comm) -> tuple[dict | None, object, list[str]]:
    """Homogenize one foam, resolve the plate's material and check both; prints on rank 0."""
    density, gamma = region["density"], region["gamma"]
    # the full run recomputes a shipped sample, so with the settings the shipped table records (its provenance)
    settings = CI_SETTINGS if ci else tables.recorded_settings("cube")[float(gamma)]
    sample = homogenize_one_foam(density, gamma, settings, comm)
    material = foam_material(density, gamma, region["E_solid"], region["nu_solid"], rho_solid=region["rho_solid"],
                             fit=region["fit"])
    failures = []
    if comm.rank == 0:
        mean = table_rows(tables.TABLE_CSV, density, gamma)[0]
        print(f"foam {density:.0%}, gamma = {gamma}: one RVE (n_cells = {settings.n_cells}, N = "
              f"{settings.resolution}, {sample['wall_s']:.1f} s) vs the shipped table (mean ± std over seeds)")
        print(f"{'':8s} {'one RVE':>10s} {'table':>10s} {'± std':>9s}   (normalised by E_s)")
        for name in CONSTANTS:
            print(f"{name:8s} {sample[name]:10.3e} {mean[name]:10.3e} {mean[name + '_std']:9.1e}")
        print(f"plate material (fit = {region['fit']}): " + ", ".join(
            f"{k} = {v / 1e3:.1f} kPa" if k.startswith(("E", "G")) else f"{k} = {v:.3f}"
            for k, v in material.constants.items()) + f", rho = {material.rho:.1f} kg/m³")
        if ci:
            if not sample["E1"] < min(sample["E2"], sample["E3"]):
                failures.append("the gamma = 0.1 foam is not softest along its x axis")
        else:
            shipped = table_rows(tables.SAMPLES_CSV, density, gamma, seed=0, n_cells=settings.n_cells,
                                 resolution=settings.resolution, tol=settings.tol)
            if len(shipped) != 1:
                failures.append(f"the shipped samples hold {len(shipped)} rows for this foam and settings, not 1")
            else:
                failures += [f"{name}: recomputed {sample[name]:.6e} differs from the shipped sample "
                             f"{shipped[0][name]:.6e} by more than {REPRODUCE_RTOL:g} (relative)"
                             for name in CONSTANTS
                             if not abs(sample[name] - shipped[0][name]) <= REPRODUCE_RTOL * abs(shipped[0][name])]
        if not (isinstance(material, TransverseIsotropic) and material.E_l < material.E_t):
            failures.append(f"the plate material is not TI and soft along l: {material}")
    return sample, material, failures


# %% [markdown]
# ## Stage 3: Tripod case B, against Table I


# %%
def robot_stage(scene: dict, out: Path, ci: bool, comm: MPI.Comm) -> tuple[object, list[str]]:
    """Run the scene; print its table and the changes from rest beside Table I (rank 0); check them."""
    if ci:
        scene["geometry"]["h"] = CI_H
        scene["outputs"] = {"png": [scene["steps"][-1]["label"]]}
    print0(DEGREE_NOTE, comm=comm)
    result = run_scene(scene, out / SCENE, comm=comm)
    height = deltas(1e3 * v for v in result.probe("center_height").values())
    angle = deltas(result.probe("center_rotation").values())
    sim = {q: deltas(TABLE_I[SCENE][q][0]) for q in ("height", "angle")}
    real = {q: deltas(TABLE_I[SCENE][q][1]) for q in ("height", "angle")}
    print0(result.table(), comm=comm)
    print0(f"\nTripod case B, change from rest ({result.n_cells} tets; Table I: real robot / paper's simulation)",
           comm=comm)
    print0(f"{'':8s} {'Δheight (mm)':>13s} {'real':>7s} {'paper':>7s} | {'Δangle (deg)':>13s} {'real':>7s} "
           f"{'paper':>7s}", comm=comm)
    failures = []
    for k, label in enumerate(("middle", "top")):
        print0(f"{label:8s} {height[k]:13.2f} {real['height'][k]:7.2f} {sim['height'][k]:7.2f} | "
               f"{angle[k]:13.2f} {real['angle'][k]:7.2f} {sim['angle'][k]:7.2f}", comm=comm)
        failures += ratio_check(SCENE, height[k], real["height"][k], TABLE_I_RATIO_BAND,
                                f"rise of the centre at {label} (mm) vs the real robot")
        failures += ratio_check(SCENE, abs(angle[k]), abs(real["angle"][k]), TABLE_I_RATIO_BAND,
                                f"|twist| at {label} (deg) vs the real robot")
    heights = list(result.probe("center_height").values())
    if not heights[0] < heights[1] < heights[2]:
        failures.append(f"the centre does not rise from rest to middle to top: {heights} m")
    return result, failures


def main(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> int:
    """The three stages; writes ``pipeline.json`` (rank 0) and returns the exit status."""
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    scene = tomllib.loads((SCENES / f"{SCENE}.toml").read_text())
    sample, material, failures = foam_stage(scene["regions"]["plate"], ci, comm)
    result, robot_failures = robot_stage(scene, out, ci, comm)
    failures += robot_failures
    if comm.rank == 0:
        record = {"foam_sample": sample, "plate_material": material.constants | {"rho": material.rho},
                  "tripod_case_b_flat": result.summary()["steps"], "failures": failures}
        tmp = out / ".pipeline.json.tmp"
        tmp.write_text(json.dumps(record, indent=2, default=float))
        tmp.replace(out / "pipeline.json")
    return report(failures, comm)


if __name__ == "__main__":
    args = parse_args("make demo: foam → homogenized table → Tripod case B.", "out",
                      "smaller foam and coarser plate, for the test suite")
    sys.exit(main(args.out, args.ci))
