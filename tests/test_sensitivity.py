"""Adjoint sensitivities (fenicsfoam.sensitivity through fenicsfoam.design): second-order Taylor remainders for every
parameter kind on the Tripod (cases A and B) and the Fig. 6 beam, the exact tangent at a converged Tripod state, and
lazy building (a plain scene run compiles no adjoint form)."""

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.design import SceneDesign
from fenicsfoam.scene import parse_scene

pytestmark = pytest.mark.mpi

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
STEPS = 0.4 / 2.0 ** np.arange(4)


def scene(name, h, table=None, **changes):
    data = tomllib.loads((SCENES / f"{name}.toml").read_text())
    data["geometry"]["h"] = h
    for region in data["regions"].values():
        if table is not None and region["material"] == "foam":
            region["table"] = table
    data["fem"]["petsc"] = {"snes_rtol": 1e-12}
    data["outputs"] = {"png": False, "xdmf": False}
    for key, value in changes.items():
        section, _, name = key.partition(".")
        data[section][name] = value
    return parse_scene(data)


def taylor(design, base, gradients, parameter, direction):
    """Remainders |J(p + h dp) − J(p) − h dJ·dp| for every probe, for the steps ``STEPS``, and the slopes."""
    comm = MPI.COMM_WORLD
    x0 = design.get(parameter)
    if isinstance(x0, np.ndarray):
        direction = np.where(np.isnan(x0), 0.0, direction)
        slopes = {k: comm.allreduce(float(np.sum(np.nan_to_num(g[parameter]) * direction)))
                  for k, g in gradients.items()}
    else:
        slopes = {k: g[parameter] * direction for k, g in gradients.items()}
    remainders = {k: [] for k in gradients}
    for h in STEPS:
        design.set({parameter: x0 + h * direction})
        values = design.solve()
        for k in gradients:
            remainders[k].append(abs(values[k] - base[k] - h * slopes[k]))
    design.set({parameter: x0})
    design.solve()  # back to the base equilibrium for the next gradient
    return slopes, {k: np.array(r) for k, r in remainders.items()}


def assert_second_order(slopes, remainders, significant, label=""):
    """Rate → 2 (the last ≥ 1.9, every one ≥ 1.5) for every probe whose first-order change is ``significant``;
    a gradient error δ would show as a remainder ~ h δ, i.e. a rate falling towards 1. The rates are printed
    (``pytest -s``: the measured rates of the docs)."""
    checked = 0
    for k, r in remainders.items():
        if abs(slopes[k]) * STEPS[-1] < significant[k]:
            if MPI.COMM_WORLD.rank == 0:
                print(f"taylor {label} {k}: not significant (slope {slopes[k]:.3g})")
            continue
        rates = np.log2(r[:-1] / r[1:])
        if MPI.COMM_WORLD.rank == 0:
            print(f"taylor {label} {k}: rates {', '.join(f'{v:.2f}' for v in rates)}")
        assert rates[-1] > 1.9 and rates.min() > 1.5, (k, slopes[k], r, rates)
        checked += 1
    assert checked, f"no probe changes to first order: {slopes}"


SIGNIFICANT = {"center_height": 1e-7, "center_rotation": 1e-4, "center_tilt_x": 1e-4, "center_tilt_y": 1e-4,
               "tip_deflection": 1e-8}


@pytest.fixture(scope="module")
def case_a():
    # The arms' l axes are 30° off the arms and the servo angles differ: no symmetry, so the centre twists and
    # tilts and every probe depends on every parameter to first order.
    design = SceneDesign(scene("tripod_case_a_flat", 0.008), probes=["center_tilt_x", "center_tilt_y"])
    design.set_servo_deg([38.0, 30.0, 20.0])
    base = design.solve()
    return design, base


@pytest.fixture(scope="module")
def case_b():
    design = SceneDesign(scene("tripod_case_b_flat", 0.008), probes=["center_tilt_x", "center_tilt_y"])
    design.set_servo_deg([30.0, 38.0, 25.0])
    base = design.solve()
    return design, base


@pytest.mark.parametrize("parameter, direction", [
    ("servo0", 2.0), ("servo2", -2.0), ("E_solid", 2e6), ("density:arms", 0.02), ("density:centre", -0.02),
    ("gamma:arms", 0.02), ("orientation.offset_deg", 8.0), ("density", None), ("orientation", None)])
def test_taylor_case_a(case_a, parameter, direction):
    design, base = case_a
    if direction is None:  # per-cell fields: a smooth direction of the cell midpoints (partition-independent)
        x = design.orientation._midpoints
        direction = (0.01 if parameter == "density" else 4.0) * np.sin(60 * x[:, 0] + 40 * x[:, 1])
    gradients = design.gradient(list(base), [parameter])
    slopes, remainders = taylor(design, base, gradients, parameter, direction)
    assert_second_order(slopes, remainders, SIGNIFICANT, f"case A {parameter}")


@pytest.mark.parametrize("parameter, direction", [
    ("servo1", 3.0), ("orientation.pitch_deg", 6.0), ("density:plate", -0.02), ("gamma:plate", 0.01)])
def test_taylor_case_b(case_b, parameter, direction):
    design, base = case_b
    gradients = design.gradient(list(base), [parameter])
    slopes, remainders = taylor(design, base, gradients, parameter, direction)
    assert_second_order(slopes, remainders, SIGNIFICANT, f"case B {parameter}")


def test_taylor_beam():
    # Fig. 6 beam with l along y (TI, corotational, gravity, clamp): E_solid, density and the l-axis angle field.
    design = SceneDesign(scene("beam_ti_y", 0.0075))  # per-cell densities: the default table, a full grid
    base = design.solve()
    x = design.orientation._midpoints
    for parameter, direction in (("E_solid", 2e6), ("density", 0.03 * np.cos(30 * x[:, 0])),
                                 ("orientation", 15.0 * np.sin(20 * x[:, 0])), ("density:beam", 0.005)):
        gradients = design.gradient(list(base), [parameter])
        slopes, remainders = taylor(design, base, gradients, parameter, direction)
        assert_second_order(slopes, remainders, SIGNIFICANT, f"beam {parameter}")


def test_tangent_is_exact_at_a_converged_tripod_state(case_b):
    # The matrix of the adjoint equations: R(u + h du) − R(u) − h A du = O(h²) on the free rows (case B: TI,
    # corotational, large rotations of the arms), A = assemble_tangent() at the converged state.
    design, _ = case_b
    problem = design.problem
    design.solve()
    A = problem.assemble_tangent()
    x0 = problem.u.vector.copy()
    du = x0.duplicate()
    rng = np.random.default_rng(MPI.COMM_WORLD.rank)
    du.array[:] = rng.uniform(-1, 1, du.array.size) * 1e-3
    for motion in problem.motions.values():  # keep the constrained dofs (the direction is free-only)
        owned = motion.dofs[motion.dofs < problem.V.dofmap.index_map.size_local]
        du.array.reshape(-1, 3)[owned] = 0.0
    Adu = du.duplicate()
    A.mult(du, Adu)
    r0 = x0.duplicate()
    problem.snes.computeFunction(x0, r0)
    remainders = []
    for h in (1.0, 0.5, 0.25, 0.125):
        x = x0.copy()
        x.axpy(h, du)
        r = x.duplicate()
        problem.snes.computeFunction(x, r)
        r.axpy(-1.0, r0)
        r.axpy(-h, Adu)
        remainders.append(r.norm())
    problem.snes.computeFunction(x0, r0)  # back to the converged state
    rates = np.log2(np.array(remainders[:-1]) / remainders[1:])
    assert rates.min() > 1.9, (remainders, rates)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="starts a serial Python process (no nested MPI)")
def test_a_plain_run_builds_no_adjoint(tmp_path):
    # A scene run imports neither the adjoint nor the design modules and compiles no probe gradient form.
    import subprocess
    import sys
    code = (
        "import sys, tomllib\n"
        "from fenicsfoam.scene import parse_scene, run_scene\n"
        f"data = tomllib.loads(open({str(SCENES / 'tripod_case_b_flat.toml')!r}).read())\n"
        "data['geometry']['h'] = 0.01\n"
        "data['outputs'] = {'png': False, 'xdmf': False}\n"
        "result = run_scene(parse_scene(data))\n"
        "print(sorted(m for m in ('fenicsfoam.sensitivity', 'fenicsfoam.design', 'fenicsfoam.control') "
        "if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path,
                         env={**__import__("os").environ, "PYTHONPATH": str(SCENES.parents[1])})
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout
    design = SceneDesign(scene("tripod_case_b_flat", 0.01))
    design.solve()
    assert design._adjoint is None
    assert all(getattr(p, "_gradient_form", None) is None for p in design.probes.values())


def test_servo_gradient_in_degrees_matches_the_motion_gradient_in_radians(case_b):
    design, base = case_b
    design.solve()
    g = design.gradient(["center_rotation"], ["servo0"])["center_rotation"]["servo0"]
    adjoint = design.adjoint
    adjoint.factor()
    raw = adjoint.gradient(design.probes["center_rotation"], motions=["servo0"]).motions["servo0"]
    assert g == pytest.approx(raw * math.pi / 180.0, rel=1e-12)


def test_group_probes_are_values_without_gradients():
    # a scene with KIND:GROUP probes (vectors, the chamber's volume) solves as a design; asking their gradient is
    # refused, naming the differentiable probes
    from foambase.errors import InputError

    data = tomllib.loads((SCENES / "finger_pneumatic.toml").read_text())
    data["geometry"]["h"] = 0.004
    data["fem"]["degree"] = 1
    data["outputs"] = {"png": False, "xdmf": False}
    data["steps"] = data["steps"][:2]
    design = SceneDesign(parse_scene(data))
    values = design.solve()
    assert values["displacement:tip"].shape == (3,) and values["volume:chamber"] > 0
    with pytest.raises(InputError, match="'volume:chamber' has no gradient"):
        design.gradient(["volume:chamber"], ["E_solid"])
