"""Servo actuators in scenes (``[loads.servo.NAME]``): the Tripod as built, on coarse P1 meshes.

The shipped as-built scenes (``demos/scenes/tripod_*.toml``, servo layout of the SoftRobots Tripod tutorial) are read
and run at a coarser mesh. Checks: the clamp boxes carry exactly the nodes inside them, by the prescribed rigid motion
(set-up translation and horn angle, recomputed here from the scene's numbers) to round-off; the
mirror image of case A's fibre layout twists by the opposite angle (the D3-invariant mesh and the servo layout are
mirror symmetric); the as-built case A reaches its rest pose; a COMM_WORLD run equals a COMM_SELF one.
"""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.scene import SceneError, parse_scene, run_scene
from fenicsfoam.scene.build import build_model

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
#: Coarse mesh of these tests (P1, h = 10 mm).
H = 0.010
ONE_RANK_SKIP = pytest.mark.skipif(MPI.COMM_WORLD.size == 1, reason="compares a COMM_WORLD run with a COMM_SELF "
                                   "run: on one rank they are the same computation (runs under mpirun -n 2)")


def scene(name: str, h: float = H, steps: int | None = None) -> dict:
    data = tomllib.loads((SCENES / f"{name}.toml").read_text())
    data["geometry"]["h"] = h
    data["outputs"] = {"png": False, "xdmf": False}
    if steps is not None:
        data["steps"] = data["steps"][:steps]
    return data


def _rodrigues(axis, angle):
    n = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def test_the_as_built_servos_are_the_tutorials_converted():
    """Servo i of the tutorial, [60 sin(120°i + 180°), −1.35, 60 cos(120°i + 180°)] mm (y up, plate mid-plane at
    27.5 mm), axle its local x turned by 120°i about y: mapped by (x, y, z) = (−z, −x, y − 27.5 mm) it lies along arm
    i, and the horn turned by the set-up angle points outwards, 85.74° from the vertical (nearly horizontal)."""
    servos = parse_scene(scene("tripod_case_b")).servos
    for i, spec in enumerate(servos.values()):
        a = math.radians(120 * i)
        sofa = np.array([60 * math.sin(a + math.pi), -1.35, 60 * math.cos(a + math.pi)])
        axle_sofa = np.array([math.cos(a), 0.0, -math.sin(a)])
        to_here = lambda v: np.array([-v[2], -v[0], v[1]])  # noqa: E731
        np.testing.assert_allclose(spec["axle_point"], (to_here(sofa) - [0, 0, 27.5]) * 1e-3, atol=1e-15)
        np.testing.assert_allclose(spec["axle"], to_here(axle_sofa), atol=1e-15)
        e = np.array([math.cos(a), math.sin(a), 0.0])
        np.testing.assert_allclose(spec["setup_translation"], -0.035 * e, atol=1e-15)
        assert spec["setup_deg"] == pytest.approx(-math.degrees(1.4965), abs=1e-3)
        horn = _rodrigues(spec["axle"], math.radians(spec["setup_deg"])) @ spec["horn"]
        rest = math.radians(85.743)
        np.testing.assert_allclose(horn, math.sin(rest) * e + [0, 0, math.cos(rest)], atol=1e-12)


def _box_nodes(X: np.ndarray, spec) -> np.ndarray:
    """Indices of the points X inside a servo's clamp box, from the scene's numbers (the box centred on the horn's
    tip, edges along the axle, the horn and across)."""
    a, h = np.array(spec["axle"]), np.array(spec["horn"])
    local = (X - (np.array(spec["axle_point"]) + spec["horn_length"] * h)) @ np.array([a, h, np.cross(a, h)]).T
    return np.flatnonzero(np.all(np.abs(local) <= 0.5 * np.array(spec["box"]) + 1e-12, axis=1))


@pytest.mark.parametrize("mesh", [{}, {"layers": 2, "arm_end_cut": "straight"}], ids=["shipped", "layered_straight"])
def test_clamp_boxes_carry_exactly_their_nodes_by_the_set_up_motion(mesh):
    """After the rest step the nodes in each clamp box (the tutorial's [45, 15, 30] mm on the horn's tip: the arm's
    last 10 mm) are at R(θ)(X − p) + p + t (θ the set-up angle, t the set-up translation), recomputed from the
    scene's numbers, to round-off; those are exactly the nodes prescribed; the plate bent (centimetres). On a
    layered plate with the straight arm-end cut the box's inner face is a node line: the box carries exactly the
    nodes of the arm-end cells, no node of a cell that it cuts."""
    data = scene("tripod_silicone", steps=1)
    data["geometry"].update(mesh)
    data["steps"][0].update(increments=4, gravity=0.0)
    parsed = parse_scene(data)
    model = build_model(parsed, MPI.COMM_SELF)
    model.problem.solve_step(model.steps[0])
    V, u = model.problem.V, model.problem.u
    X = V.tabulate_dof_coordinates()
    values = u.x.array.reshape(-1, 3)
    for i, (name, spec) in enumerate(parsed.servos.items()):
        nodes = _box_nodes(X, spec)
        phi = math.radians(120 * i)
        along = X[nodes] @ [math.cos(phi), math.sin(phi), 0.0]
        assert len(nodes) > 10 and along.min() >= 0.045 - 1e-12 and along.max() <= 0.055 + 1e-12
        np.testing.assert_array_equal(np.sort(model.problem.motions[name].dofs), nodes)
        if mesh:
            np.testing.assert_array_equal(np.sort(model.tagged.arm_end_dofs(V, i)), nodes)
        R = _rodrigues(spec["axle"], math.radians(spec["setup_deg"]))
        p, t = np.array(spec["axle_point"]), np.array(spec["setup_translation"])
        expected = (X[nodes] - p) @ R.T + p + t - X[nodes]
        assert np.abs(values[nodes] - expected).max() < 1e-12 * np.abs(expected).max(), name
    assert np.abs(values).max() > 0.02


def test_servo_keys_are_checked_before_any_work():
    data = scene("tripod_case_b")
    bad = copy.deepcopy(data)
    bad["loads"]["servo"]["servo0"]["horn"] = [0.0, 1.0, 0.0]  # along servo0's axle
    with pytest.raises(SceneError, match=r"loads\.servo\.servo0\.horn: .* perpendicular to the axle"):
        parse_scene(bad)
    bad = copy.deepcopy(data)
    bad["steps"][2]["servos"] = 40.0  # -85.743 + 40 = -45.7, within the range; 90 is not
    parse_scene(bad)
    bad["steps"][2]["servos"] = {"servo1": 90.0}
    with pytest.raises(SceneError, match=r"steps\[2\]\.servos: servo 'servo1' at 90° from rest reaches 4\.257°, "
                                         r"outside its range_deg"):
        parse_scene(bad)
    bad["steps"][2]["servos"] = {"servo7": 1.0}
    with pytest.raises(SceneError, match=r"steps\[2\]\.servos\.servo7: no servo named 'servo7'"):
        parse_scene(bad)
    bad = copy.deepcopy(data)
    bad["loads"]["servos"] = True
    with pytest.raises(SceneError, match=r"loads\.servos: give either servos = true .* not both"):
        parse_scene(bad)


def test_the_sofa_element_takes_the_options_of_its_krylov_solver():
    """``corotational_sofa`` solves with GMRES (an approximate tangent): its scenes may set Krylov options, which a
    scene with the LU solver of an exact tangent refuses before any work."""
    from fenicsfoam.scene.run import check_solver_options
    data = scene("tripod_case_b")
    data["fem"]["petsc"] = {"ksp_max_it": 1000}
    data["fem"]["model"] = "corotational_sofa"
    check_solver_options(parse_scene(data))
    data["fem"]["model"] = "corotational"
    with pytest.raises(SceneError, match=r"^fem\.petsc\.ksp_max_it: PETSc does not use this option"):
        check_solver_options(parse_scene(data))


def _case_a(offset_deg: float) -> dict:
    """Case A as built with each arm's l axis at ``offset_deg`` from the arm (counter-clockwise seen from above)."""
    data = scene("tripod_case_a")
    data["steps"][0]["increments"] = 8  # the set-up in 8 increments (halved where one fails)
    data["steps"][2]["increments"] = 2
    del data["steps"][1]  # rest and top
    for i in range(3):
        phi = math.radians(120 * i + offset_deg)
        data["orientation"]["directions"][f"arm{i}"] = [math.cos(phi), math.sin(phi), 0.0]
    return data


@pytest.fixture(scope="module")
def case_a_twist():
    return {offset: run_scene(parse_scene(_case_a(offset)), comm=MPI.COMM_SELF).probe("center_rotation")
            for offset in (30.0, -30.0)}


def test_as_built_case_a_reaches_rest_and_its_mirror_image_twists_the_other_way(case_a_twist):
    """The as-built case A (corotational, P1) reaches its rest pose and the top; the mirror image of the layout
    (l axes 30° clockwise from the arms) twists by exactly the opposite angle: the mesh, the servos and the set-up
    are mirror symmetric about the vertical plane through arm 0 (to round-off)."""
    plus, minus = case_a_twist[30.0], case_a_twist[-30.0]
    assert list(plus) == ["rest", "top"]
    scale = abs(plus["top"] - plus["rest"])
    assert scale > 1.0
    for label, angle in plus.items():
        assert minus[label] == pytest.approx(-angle, abs=1e-8 * scale), label


@ONE_RANK_SKIP
@pytest.mark.mpi
def test_as_built_probes_do_not_depend_on_the_partition():
    data = scene("tripod_case_a", steps=1)
    data["steps"][0]["increments"] = 8
    parallel = run_scene(parse_scene(data), comm=MPI.COMM_WORLD)
    serial = run_scene(parse_scene(data), comm=MPI.COMM_SELF)
    for a, b in zip(parallel.steps, serial.steps):
        for name, value in b.probes.items():
            assert a.probes[name] == pytest.approx(value, rel=1e-7, abs=1e-10), (a.label, name)


@pytest.mark.slow
def test_design_gradients_of_the_servo_angles_as_built():
    """``SceneDesign`` on the as-built case A: its parameters are the servos' names, its angles are from rest, and
    the adjoint derivative of the centre's height and tilt in servo0's angle equals a central difference (h = 0.2°,
    second order: to 1e-4 of the derivative, against a first-order one-sided error of ≈ 1e-3)."""
    from fenicsfoam.design import SceneDesign
    data = scene("tripod_case_a", steps=2)
    data["fem"]["petsc"] = {"snes_rtol": 1e-12, "snes_atol": 1e-14}
    design = SceneDesign(parse_scene(data), MPI.COMM_SELF, probes=["center_height", "center_tilt_x"])
    assert design.servos == ("servo0", "servo1", "servo2") and design.servo_deg() == (19.0, 19.0, 19.0)
    names = ["center_height", "center_tilt_x"]
    design.solve()
    gradient = design.gradient(names, ["servo0"])
    theta = np.array(design.servo_deg())
    plus = design.solve_last(theta + [0.2, 0.0, 0.0], increment_deg=1.0)
    minus = design.solve_last(theta - [0.2, 0.0, 0.0], increment_deg=1.0)
    for name in names:
        central = (plus[name] - minus[name]) / 0.4
        assert central == pytest.approx(gradient[name]["servo0"], rel=1e-4), name


@pytest.mark.mpi
def test_a_layered_as_built_case_b_reaches_rest():
    """Case B as built on a layered plate (P1, h = 10 mm in-plane, 2 layers through the 5 mm plate, straight arm-end
    cut; the scene's own foam) reaches its rest pose with every cell upright, twisting clockwise seen from above (the
    shipped spiral's sense at rest); under ``mpirun -n 2`` its probes equal a COMM_SELF run's."""
    data = scene("tripod_case_b", steps=1)
    data["geometry"].update(layers=2, arm_end_cut="straight")
    data["steps"][0]["increments"] = 8
    serial = run_scene(parse_scene(data), comm=MPI.COMM_SELF)
    (rest,) = serial.steps
    assert rest.label == "rest" and rest.min_det_F > 0.1
    assert -30.0 < rest.probes["center_rotation"] < -10.0
    if MPI.COMM_WORLD.size > 1:
        parallel = run_scene(parse_scene(data), comm=MPI.COMM_WORLD)
        for name, value in rest.probes.items():
            assert parallel.steps[0].probes[name] == pytest.approx(value, rel=1e-7, abs=1e-10), name


@pytest.mark.parametrize(("key", "value", "match"), [
    ("layers", -1, r"geometry\.layers: -1 is out of range; valid: an integer >= 0"),
    ("layers", 2.0, r"geometry\.layers: expected an integer, got"),
    ("arm_end_cut", "round", r"geometry\.arm_end_cut: 'round' is not valid; valid: 'arc', 'straight'"),
])
def test_bad_layer_and_cut_keys_are_refused_before_any_work(key, value, match):
    data = scene("tripod_case_b")
    data["geometry"][key] = value
    with pytest.raises(SceneError, match=match):
        parse_scene(data)
