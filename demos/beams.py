# %% [markdown]
# # Fig. 6: foam cantilever beams sagging under their own weight, against the paper
#
# This demo shows:
# - running the scene files `demos/scenes/beam_iso.toml`, `beam_ti_y.toml`, `beam_ti_z.toml` with
#   `fenicsfoam.scene.run_scene` (the library call behind `fenicsfoam run`);
# - three 250 × 15 × 15 mm TPU foam beams (18 %; γ = 1, and γ = 0.1 with the l axis along y or z), clamped at
#   x = 0, under gravity, with the foam constants interpolated from the homogenized table (`foam_material`);
# - the tip deflections side by side with the paper's real and simulated ones (Fig. 6), and the pictures
#   (deformed shape coloured by |u|, orientation glyphs) under `--out`;
# - how a stop at a material instability (loss of strong ellipticity) is diagnosed and reported.
#
# ## The problem
#
# *Continuous.* Find the displacement u of the beam Ω = (0, L) × (−w/2, w/2) × (−h/2, h/2) (reference
# configuration X) such that
#
#     −Div P(F) = ρ g   in Ω,      u = 0 on the clamped face x = 0,      P N = 0 on the rest of ∂Ω,
#
# with F = I + ∇u and the first Piola–Kirchhoff stress P of the corotational model: ψ = ½ ε_c : C(a) : ε_c,
# ε_c = sym(RᵀF) − I, R the rotation of the polar decomposition F = RU, and C(a) the transversely isotropic
# stiffness with its symmetry (l) axis along the unit vector a (Spencer form with the structural tensor a ⊗ a).
#
# *Weak form.* Find u ∈ V (vector fields vanishing on the clamp) such that, for every v ∈ V,
#
#     ∫_Ω P(F(u)) : ∇v dX − ∫_Ω ρ g · v dX = 0.
#
# *Discrete.* Continuous P1 Lagrange elements on the gmsh tetrahedral mesh (20.7k tetrahedra, h = 2.4 mm, the
# paper's size; `--ci`: 688 tetrahedra, h = 7.5 mm); moduli, density and the l axis are DG0 fields; the
# nonlinear equations are solved by PETSc SNES Newton with the exact tangent, gravity applied in increments
# (halved automatically when an increment fails).
#
# ## The paper's numbers
#
# Fig. 6 caption: "isotropic, transverse isotropic in Z and Y direction with the colors blue, red and green
# respectively"; blue: real −48, simulated −47.2 mm; red (l along z): −24 / −22.2 mm; green (l along y):
# −23 / −19.1 mm. Nothing here is tuned to these numbers. The real measurements are the ground truth.
#
# *What holds today.* The beam scenes read the default foam table, the paper's foam (polyhedral walls one track
# wide with pores of 0.0045 E_s, a representative RVE, docs/foam.md). With the datasheet E_s = 12 MPa the beams sag
# 1.36–1.53× as much as the real ones (−73.3, −31.3, −32.9 mm at the paper's mesh: the printed solid's modulus is
# not the filament's datasheet value, and the table's voxel bracket leaves a bias; `demos/experiments.py`
# calibrates E_s on the isotropic beam), so the check below keeps that ratio in the band `SAG_RATIO_BAND` =
# [0.5, 3.0]: it documents the over-prediction plainly (it is not an agreement) and fails on a regression beyond
# it. What depends little on E_s is the foam's anisotropy: the l-along-y beam bends in the foam's stiff transverse
# plane, and tip(TI-y) / tip(iso) (0.426 here) is asserted within `ANISOTROPY_TOLERANCE` (15 %) of the real beams'
# 23 / 48 = 0.479. Fig. 6's ordering (the γ = 0.1 beams sag less than the isotropic one) is asserted too.
#
# The l-along-z beam bends in shear across its l axis (G_l = 0.00379 E_s = 45.5 kPa at 12 MPa): its compressed
# bottom fibres near the clamp can come close to σ_xx ≈ −2 G_l, where the corotational TI tangent loses strong
# ellipticity (kink-band micro-buckling, `fenicsfoam.stability`); with the paper's foam it carries its full weight
# at the datasheet E_s (with the void-pore wall foam's G_l of 12.8 kPa it stopped just before). A stop would be a
# result of the model, reported with the load factor reached and the diagnosis; an undiagnosed failure is an
# error. Its ratio is therefore not asserted here; with the calibrated E_s it is compared with the real beam
# (`demos/experiments.py`).
#
# Run: `python demos/beams.py --out out/beams [--ci]`, also under `mpirun -n 2`.

# %%
import sys
from pathlib import Path

from _demo import FIG6_MM as PAPER_MM
from _demo import load_scene_dict, parse_args, ratio_check, run_and_check
from mpi4py import MPI

from fenicsfoam.scene import run_scene
from fenicsfoam.solver import ConvergenceError

#: Our sag / the real beam's sag: measured 1.94 (iso), 1.86 (TI-y), 2.44 (TI-z) at the paper's mesh.
SAG_RATIO_BAND = (0.5, 3.0)
#: |tip(TI-y)/tip(iso) / (23/48) − 1| allowed: measured 4 % (P1, the paper's mesh) and 2 % (P2).
ANISOTROPY_TOLERANCE = 0.15
#: --ci mesh size (m): 688 tetrahedra instead of 20.7k.
CI_H = 0.0075


# %% [markdown]
# ## Run the three scenes


# %%
def run_beams(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Run every beam scene (coarse with ``ci``); returns ``{scene: SceneResult or ConvergenceError}``.

    A scene whose load step fails is reported (its outputs hold the steps done and the error), not fatal.
    """
    results = {}
    for name in PAPER_MM:
        scene = load_scene_dict(name, ci_h=CI_H if ci else None, png=True if ci else None)
        try:
            results[name] = run_scene(scene, out / name, comm=comm)
        except ConvergenceError as exc:
            results[name] = exc
    return results


def material_instability(r) -> bool:
    """A failed scene whose last converged state has lost strong ellipticity (a diagnosed stop, not a crash)."""
    return isinstance(r, ConvergenceError) and r.ellipticity is not None and r.ellipticity.lost


def table(results: dict) -> str:
    """Tip deflections (mm) beside the paper's; ratios are ours / the paper's."""
    lines = [f"{'scene':10s} {'tets':>6s} {'dofs':>7s} {'ours':>8s} {'real':>7s} {'paper sim':>10s} "
             f"{'ours/real':>10s} {'ours/sim':>9s} {'Newton':>6s} {'wall s':>7s}   (tip deflection, mm)"]
    for name, r in results.items():
        real, sim = PAPER_MM[name]
        if material_instability(r):
            lines.append(f"{name:10s} stopped at {100 * r.load_factor:.1f} % of gravity ({r.reason}): material "
                         f"instability, {r.ellipticity} (real {real}, paper sim {sim} mm)")
            continue
        if isinstance(r, ConvergenceError):
            lines.append(f"{name:10s} FAILED at {100 * r.load_factor:.1f} % of gravity: {r.reason} "
                         f"(real {real}, paper sim {sim} mm)")
            continue
        ours = 1e3 * r.steps[-1].probes["tip_deflection"]
        lines.append(f"{name:10s} {r.n_cells:6d} {r.n_dofs:7d} {ours:8.2f} {real:7.1f} {sim:10.1f} "
                     f"{ours / real:10.2f} {ours / sim:9.2f} {sum(s.newton_iterations for s in r.steps):6d} "
                     f"{r.wall_s:7.1f}")
    return "\n".join(lines)


# %% [markdown]
# ## Checks
# - every beam that reaches full gravity sags (a negative deflection, less than half its length);
# - the γ = 0.1 beams that reach full gravity, stiff across their l axis, sag less than the isotropic one, as
#   in Fig. 6;
# - our sag / the real beam's sag lies in `SAG_RATIO_BAND` (today's over-prediction, see above);
# - tip(TI-y) / tip(iso) is within `ANISOTROPY_TOLERANCE` of the real beams' ratio;
# - a beam may instead stop at a diagnosed material instability after carrying some load; any other failure,
#   and a failure of the isotropic beam, fails the demo.


# %%
def check(results: dict) -> list[str]:
    """Failed checks, as messages (empty if all pass)."""
    failures = [f"{name}: {r}" for name, r in results.items()
                if isinstance(r, ConvergenceError) and not material_instability(r)]
    failures += [f"{name}: stops at load factor 0 (no load carried): {r}" for name, r in results.items()
                 if material_instability(r) and not r.load_factor > 0]
    if isinstance(results["beam_iso"], ConvergenceError):
        failures.append(f"beam_iso (the reference) did not reach full gravity: {results['beam_iso']}")
    if failures:
        return failures
    tips = {name: 1e3 * r.steps[-1].probes["tip_deflection"] for name, r in results.items()
            if not isinstance(r, ConvergenceError)}
    failures += [f"{name}: tip deflection {tip:.4g} mm is not a sag of less than half the length"
                 for name, tip in tips.items() if not -125.0 < tip < 0]
    failures += [f"{name} sags more than beam_iso ({tips[name]:.4g} vs {tips['beam_iso']:.4g} mm)"
                 for name in ("beam_ti_y", "beam_ti_z") if name in tips and not tips[name] > tips["beam_iso"]]
    for name, tip in tips.items():
        failures += ratio_check(name, tip, PAPER_MM[name][0], SAG_RATIO_BAND, "tip deflection (mm) vs the real beam")
    if "beam_ti_y" in tips:
        real = PAPER_MM["beam_ti_y"][0] / PAPER_MM["beam_iso"][0]
        tolerance = (1 - ANISOTROPY_TOLERANCE, 1 + ANISOTROPY_TOLERANCE)
        failures += ratio_check("beam_ti_y", tips["beam_ti_y"] / tips["beam_iso"], real, tolerance,
                                "tip(TI-y) / tip(iso) vs the real beams'")
    return failures


if __name__ == "__main__":
    args = parse_args("Fig. 6 beams: tip deflections against the paper.", "out/beams",
                      f"coarse mesh (h = {CI_H * 1e3:g} mm) for a fast run")
    sys.exit(run_and_check(run_beams, check, table, args.out, args.ci))
