# %% [markdown]
# # Table I: the Tripod's centre height and torsion, silicone vs foam plates, against the paper
#
# This demo shows:
# - running `demos/scenes/tripod_silicone_flat.toml`, `tripod_case_a_flat.toml` and `tripod_case_b_flat.toml` with
#   `fenicsfoam.scene.run_scene`: the plate's weight at rest (horns at 0°), then all three horns at 19° (middle)
#   and 38° (top);
# - the changes from rest of the centre's height and of its rotation about the vertical axis, side by side with
#   Table I of the paper (real robot first, the paper's simulation second), and the pictures under `--out`;
# - the symmetry check: the isotropic silicone plate, driven identically by its three servos, does not twist (to
#   round-off: the mesh is invariant under the plate's symmetry group, see `meshes/tripod.py`).
#
# ## The problem
#
# *Continuous.* The Y-shaped plate Ω (5 mm thick, three 30 mm wide arms at 120°) carries its weight; the arm
# ends (r ≥ 45 mm) are moved rigidly by the servo horns, a rotation by the horn angle θ about each servo's
# tangential axis. Find u with
#
#     −Div P(F) = ρ g   in Ω,      u = R(θ, t_i)(X − p_i) + p_i − X on arm end i,      P N = 0 elsewhere,
#
# P from the corotational energy ψ = ½ ε_c : C(a) : ε_c (see `demos/beams.py`); the silicone plate is
# isotropic, case A has TI arms (l axis 30° counter-clockwise from each arm, seen from above: a chiral layout,
# see the scene file) around an isotropic centre, case B is TI everywhere with its l axis on a 45°
# counter-clockwise spiral.
#
# *Weak form.* Find u in the affine space of the prescribed arm-end motions such that
# ∫_Ω P(F(u)) : ∇v dX = ∫_Ω ρ g · v dX for every v vanishing on the arm ends.
#
# *Discrete.* P1 Lagrange on the D3-invariant tetrahedral mesh (2694 tetrahedra at h = 5.2 mm, the paper's
# 2684; `--ci`: 2202 at h = 6 mm), DG0 material and orientation fields, PETSc SNES Newton, each step applied in
# increments.
#
# ## The paper's numbers
#
# The paper gives absolute heights above its table and angles whose zero is the real robot's rest; our heights
# are those of the plate's mid-plane (0 when flat) and our rest is the flat plate with horizontal horns, so the
# comparison is in differences from rest. The paper's angle sign convention and the spiral's handedness are not
# stated: angles are compared in magnitude. Nothing is tuned to Table I, which `_demo.TABLE_I` holds (the
# paper has no silicone row).
#
# *What holds today* (asserted below, against the real robot): the rise of the centre of cases A and B is
# within `RATIO_BAND` = [0.7, 1.3] of the real one (measured 0.91–1.22); case B's twist magnitude is within the
# same band (measured 0.83–1.01). Case A twists, but far less than the real robot (about 1.6° and 4.8° against
# 4° and 20°): the check asserts only that it twists by more than a degree at the top; the reasons for the gap
# (the real robot's pre-bent servo kinematics, which in-plane axis the paper's "direction" is, the foam's
# anisotropy, P1 tetrahedra) are measured in the docs' validation pages.
#
# Run: `python demos/tripod.py --out out/tripod [--ci]`, also under `mpirun -n 2`.

# %%
import sys
from pathlib import Path

from _demo import TABLE_I, deltas, load_scene_dict, parse_args, ratio_check, run_and_check
from _demo import TABLE_I_RATIO_BAND as RATIO_BAND
from mpi4py import MPI

from fenicsfoam.scene import run_scene

CASES = ("tripod_silicone_flat", "tripod_case_a_flat", "tripod_case_b_flat")
#: Twist bound of the mirror-symmetric silicone plate, relative to case B's torsion at the top: zero
#: by symmetry, and the mesh is D3-invariant (``meshes.tripod``), so only round-off and the solver tolerance
#: remain (measured ≈ 1e-15 relative).
SYMMETRY_RTOL = 1e-9
#: --ci mesh size (m): 2202 tetrahedra.
CI_H = 0.006


# %% [markdown]
# ## Run the three plates


# %%
def run_tripods(out: Path, ci: bool, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Run every Tripod scene (coarser with ``ci``); returns ``{scene: SceneResult}``."""
    results = {}
    for name in CASES:
        # --ci: pictures (≈1 s each) only of case B's last step
        png = (True if name == "tripod_case_b_flat" else False) if ci else None
        scene = load_scene_dict(name, ci_h=CI_H if ci else None, png=png)
        results[name] = run_scene(scene, out / name, comm=comm)
    return results


def changes(result) -> dict[str, tuple[float, float]]:
    """Our changes from rest at middle and top: height (mm) and angle (deg)."""
    return {"height": deltas(1e3 * v for v in result.probe("center_height").values()),
            "angle": deltas(result.probe("center_rotation").values())}


def table(results: dict) -> str:
    """Δ from rest at middle and top: ours, the real robot and the paper's simulation (Table I)."""
    lines = [f"{'scene':16s} {'quantity':14s} | {'Δmiddle: ours':>13s} {'real':>6s} {'paper':>6s} | "
             f"{'Δtop: ours':>10s} {'real':>6s} {'paper':>6s}"]
    for name, r in results.items():
        ours = changes(r)
        for quantity, unit in (("height", "mm"), ("angle", "deg")):
            if name in TABLE_I:
                sim, real = (deltas(v) for v in TABLE_I[name][quantity])
                paper = [f"{real[0]:6.2f}", f"{sim[0]:6.2f}", f"{real[1]:6.2f}", f"{sim[1]:6.2f}"]
            else:
                paper = ["     -"] * 4
            lines.append(f"{name:16s} {quantity + ' (' + unit + ')':14s} | {ours[quantity][0]:13.2f} {paper[0]} "
                         f"{paper[1]} | {ours[quantity][1]:10.2f} {paper[2]} {paper[3]}")
    lines.append("sizes: " + ", ".join(f"{n} {r.n_cells} tets / {r.n_dofs} dofs / {r.wall_s:.1f} s"
                                       for n, r in results.items()))
    return "\n".join(lines)


# %% [markdown]
# ## Checks
# - every plate rises from rest to middle to top (the horns lift the arm ends);
# - the silicone plate does not twist (mirror symmetry of the plate and of its mesh):
#   |twist| < 1e-9 × case B's torsion at the top;
# - the two chiral foam plates (case A: l axes 30° from the arms; case B: the spiral) twist by more than a degree
#   at the top;
# - cases A and B: the rise of the centre at middle and top is within `RATIO_BAND` of the real robot's;
#   case B: the magnitude of the twist at middle and top is within `RATIO_BAND` of the real robot's.


# %%
def check(results: dict) -> list[str]:
    """Failed checks, as messages (empty if all pass)."""
    failures = []
    for name, r in results.items():
        heights = list(r.probe("center_height").values())
        if not heights[0] < heights[1] < heights[2]:
            failures.append(f"{name}: centre heights {heights} m do not rise from rest to middle to top")
    twist = abs(changes(results["tripod_case_b_flat"])["angle"][1])
    bound = SYMMETRY_RTOL * twist
    angles = results["tripod_silicone_flat"].probe("center_rotation")
    if not max(abs(v) for v in angles.values()) < bound:
        failures.append(f"tripod_silicone_flat twists: {angles} deg (symmetry bound {bound:.3g} deg = "
                        f"{SYMMETRY_RTOL:g} × case B's torsion at top)")
    for name in ("tripod_case_a_flat", "tripod_case_b_flat"):
        torsion = changes(results[name])["angle"][1]
        if not abs(torsion) > 1.0:
            failures.append(f"{name}: torsion at top {torsion:.3g} deg, expected more than 1 deg")
    for name in ("tripod_case_a_flat", "tripod_case_b_flat"):
        ours = changes(results[name])
        real = {q: deltas(TABLE_I[name][q][1]) for q in ("height", "angle")}
        for k, label in enumerate(("middle", "top")):
            failures += ratio_check(name, ours["height"][k], real["height"][k], RATIO_BAND,
                                    f"rise of the centre at {label} (mm) vs the real robot")
            if name == "tripod_case_b_flat":
                failures += ratio_check(name, abs(ours["angle"][k]), abs(real["angle"][k]), RATIO_BAND,
                                        f"|twist| at {label} (deg) vs the real robot")
    return failures


if __name__ == "__main__":
    args = parse_args("Table I Tripod: centre height and torsion against the paper.", "out/tripod",
                      f"coarser mesh (h = {CI_H * 1e3:g} mm) for a fast run")
    sys.exit(run_and_check(run_tripods, check, table, args.out, args.ci))
