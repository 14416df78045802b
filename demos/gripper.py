# %% [markdown]
# # A soft gripper: pneumatic foam fingers closing on a rigid ball
#
# This demo shows:
# - contact with a rigid obstacle (`[contacts.NAME]`, a sphere) on a named facet group of the robot, enforced by
#   Nitsche's method, and the probes `contact_force:NAME` (the force the ball exerts on the finger) and
#   `contact_area:NAME`;
# - the grasp force against the actuation pressure;
# - inverse actuation (`fenicsfoam.control.control_servos` with `unknowns`, or `fenicsfoam control --unknown`): the
#   chamber pressure that gives a prescribed grasp force.
#
# ## The gripper
#
# Two pneumatic foam fingers (the finger builder: 100 × 20 × 15 mm TPU foam, 18 %, a chamber under a 2 mm top wall)
# hang from a palm, their bending planes facing each other, over a table on which a rigid ball of radius 20 mm rests
# between them. Inflating a chamber bends its finger towards the ball (the thin top wall stretches more than the
# bottom wall). The gripper is symmetric about the plane half-way between the fingers, and the ball is rigid and held
# by the table and the symmetric finger: one finger against a fixed ball is modelled. The finger's axis is x (the
# palm at x = 0, gravity along +x: down), it closes along −z; the ball's centre is 20 mm from the fingertip and 2 mm
# below the finger's bottom face at rest.
#
# The grasp force is the normal force the ball exerts on one finger, `contact_force:ball[2]` (along +z, N). Friction
# is not modelled, so the force that holds the ball against gravity is not computed here: with a friction
# coefficient μ, two fingers could hold a ball of weight up to about 2 μ × the grasp force.
#
# Run: `python demos/gripper.py --out out/gripper [--ci]`, also under `mpirun -n 2`.

# %%
import copy
import sys
from pathlib import Path

import numpy as np
from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _demo import finish, load_scene_dict, parse_args, print0  # noqa: E402

from fenicsfoam.control import control_servos  # noqa: E402
from fenicsfoam.scene import parse_scene, run_scene  # noqa: E402

BALL_RADIUS, BALL_X, BALL_GAP = 0.020, 0.080, 0.002
FACTORS = (0.25, 0.5, 0.75, 1.0)  # of 20 kPa
TARGET_FRACTION = 0.5             # the prescribed grasp force: half the force at 20 kPa


def gripper_scene(ci: bool) -> dict:
    scene = load_scene_dict("finger_pneumatic", ci_h=0.004 if ci else None, png=False if ci else ["p20kPa"])
    scene["name"] = "gripper"
    scene["description"] = "One of two pneumatic foam fingers closing on a rigid ball (mirror symmetry)"
    if ci:
        scene["fem"]["degree"] = 1
    scene["loads"]["gravity"] = [9.81, 0.0, 0.0]  # hanging from the palm: down is +x
    scene["contacts"] = {"ball": {"group": "bottom", "obstacle": "sphere", "radius": BALL_RADIUS,
                                  "center": [BALL_X, 0.0, -0.0075 - BALL_GAP - BALL_RADIUS]}}
    scene["probes"] = ["displacement:tip", "volume:chamber", "contact_force:ball", "contact_area:ball"]
    scene["steps"] = [{"label": "rest", "gravity": 1.0}] + [
        {"label": f"p{20 * f:g}kPa", "loads": {"chamber": f}} for f in FACTORS]
    return scene


def main() -> int:
    args = parse_args("Soft gripper: grasp force against pressure, and the pressure for a given grasp force",
                      "out/gripper", "coarse P1 mesh (h = 4 mm), a few seconds")
    comm = MPI.COMM_WORLD
    scene = gripper_scene(args.ci)
    sweep = run_scene(parse_scene(scene), args.out / "sweep", comm=comm)
    rows = [{"step": s.label, "pressure_kPa": 20.0 * f, "grasp_force_N": s.probes["contact_force:ball"][2],
             "contact_area_mm2": 1e6 * s.probes["contact_area:ball"],
             "tip_mm": 1e3 * np.array(s.probes["displacement:tip"])} for s, f in zip(sweep.steps[1:], FACTORS)]
    print0("pressure (kPa)  grasp force (mN)  contact area (mm²)")
    for row in rows:
        print0(f"{row['pressure_kPa']:14.1f}  {1e3 * row['grasp_force_N']:16.3f}  {row['contact_area_mm2']:18.2f}")

    # %% [markdown]
    # ## The pressure for a prescribed grasp force
    # The controller starts from the scene's last pressure (20 kPa) and solves for the chamber's factor in [0, 1].

    # %%
    target = TARGET_FRACTION * rows[-1]["grasp_force_N"]
    control_scene = copy.deepcopy(scene)
    # rest, then the pressure in four increments (as the sweep's steps: the contact closes during the step; one
    # increment also converges, after cut-backs)
    control_scene["steps"] = [scene["steps"][0], {**scene["steps"][-1], "increments": 4}]
    control_scene["outputs"] = {"png": False, "xdmf": False}
    result = control_servos(parse_scene(control_scene), {"contact_force:ball[2]": target},
                            unknowns={"chamber": (0.0, 1.0)}, comm=comm, out_dir=args.out / "control")
    pressure = 20.0 * result.unknowns["chamber"]
    print0(f"grasp force {1e3 * target:.3f} mN needs {pressure:.4f} kPa ({result.iterations} iterations, "
           f"{result.scene_solves} scene solves)")

    # A forward run at that pressure, which the controller did not make, gives the prescribed force.
    check = copy.deepcopy(control_scene)
    check["steps"][-1]["loads"] = {"chamber": result.unknowns["chamber"]}
    force = run_scene(parse_scene(check), comm=comm).steps[-1].probes["contact_force:ball"][2]

    failures = []
    forces = [r["grasp_force_N"] for r in rows]
    # the ball can only push (force >= 0); zero until the finger touches it, then growing with the pressure (a
    # higher pressure bends the finger further into the ball), and touching at the highest pressure
    touch = next((i for i, F in enumerate(forces) if F > 0), len(forces))
    if (touch == len(forces) or any(F != 0 for F in forces[:touch])
            or not all(b > a for a, b in zip(forces[touch:], forces[touch + 1:]))):
        failures.append(f"the grasp force should be zero until the finger touches the ball, then grow with the "
                        f"pressure: {forces}")
    if not abs(force - target) <= 1e-6 * abs(target):
        failures.append(f"a forward run at the controlled pressure gives {force} N, not the target {target} N")
    below = [20.0 * f for f, F in zip(FACTORS, forces) if F <= target]
    above = [20.0 * f for f, F in zip(FACTORS, forces) if F >= target]
    if below and above and not max(below) <= pressure <= min(above):
        failures.append(f"the controlled pressure {pressure} kPa is not between the swept pressures that bracket "
                        f"the target ({max(below)}, {min(above)} kPa)")
    summary = {"sweep": [{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in r.items()} for r in rows],
               "target_grasp_force_N": target, "pressure_kPa": pressure, "forward_check_N": force,
               "iterations": result.iterations, "scene_solves": result.scene_solves}

    def picture(path: Path) -> None:
        if comm.rank == 0:
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
            fig, ax = plt.subplots(figsize=(5, 3.5))
            ax.plot([r["pressure_kPa"] for r in rows], [1e3 * F for F in forces], "o-", label="sweep")
            ax.plot([pressure], [1e3 * target], "r*", markersize=12, label="control: prescribed force")
            ax.set_xlabel("chamber pressure (kPa)")
            ax.set_ylabel("grasp force on one finger (mN)")
            ax.legend()
            fig.tight_layout()
            fig.savefig(path, dpi=120)
            plt.close(fig)

    return finish(args.out, "summary.json", summary, {"grasp_force.png": picture}, failures, comm)


if __name__ == "__main__":
    sys.exit(main())
