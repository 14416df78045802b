"""External loads and group probes: beam theory, equilibrium of the reactions, frame invariance of a follower
pressure, the cable's work, consistent tangents, validation, and the same answer on 1 and 2 ranks.

Materials are explicit isotropic constants (SI); the finger builder (``meshes.finger``) gives named facet groups.
"""

import csv
import json

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.scene import SceneError, parse_scene, run_scene

SELF = MPI.COMM_SELF
E, NU, RHO = 1.0e6, 0.3, 180.0
NO_FILES = {"xdmf": False, "png": False}


def material(**overrides):
    return {"tags": "finger", "material": "isotropic", "E": E, "nu": NU, "rho": RHO, **overrides}


# --------------------------------------------------------------------------------------------------
# Beam theory: a tip force and a uniform traction on a linear cantilever (P2)
# --------------------------------------------------------------------------------------------------
L, A, H_BEAM = 0.25, 0.015, 0.0075
F_TIP, T_TOP = 0.02, 20.0   # N (downwards on the tip face), Pa (downwards on the top face)


def beam_constants():
    inertia, area = A**4 / 12, A * A
    kappa, G = 10 * (1 + NU) / (12 + 11 * NU), E / (2 * (1 + NU))
    return inertia, area, kappa, G


def timoshenko_tip_force(F):
    """Euler–Bernoulli F L³/(3 E I) plus Timoshenko's shear F L/(κ G A)."""
    inertia, area, kappa, G = beam_constants()
    return F * L**3 / (3 * E * inertia) + F * L / (kappa * G * area)


def timoshenko_uniform(q):
    """Euler–Bernoulli q L⁴/(8 E I) plus Timoshenko's shear q L²/(2 κ G A), q per unit length."""
    inertia, area, kappa, G = beam_constants()
    return q * L**4 / (8 * E * inertia) + q * L**2 / (2 * kappa * G * area)


def beam_scene():
    return {
        "name": "cantilever",
        "geometry": {"builder": "finger", "h": H_BEAM, "length": L, "width": A, "height": A, "chamber": False},
        "fem": {"model": "linear", "degree": 2},
        "regions": {"beam": material(rho=0.0)},
        "loads": {"clamp": "base", "force": {"tip_load": {"group": "tip", "force": [0.0, 0.0, -F_TIP]}},
                  "traction": {"top_load": {"group": "top", "traction": [0.0, 0.0, -T_TOP]}}},
        "steps": [{"label": "force", "loads": {"tip_load": 1.0}},
                  {"label": "traction", "loads": {"tip_load": 0.0, "top_load": 1.0}}],
        "probes": ["displacement:tip", "reaction_force:base"],
    }


def test_tip_force_and_uniform_traction_match_timoshenko(tmp_path):
    result = run_scene(beam_scene(), tmp_path, comm=SELF)
    force, traction = result.steps
    # linear P2 at h = 7.5 mm: within 1 % of the beam theories (the clamped face, held fully, is a little stiffer)
    assert -force.probes["displacement:tip"][2] == pytest.approx(timoshenko_tip_force(F_TIP), rel=0.01)
    assert -traction.probes["displacement:tip"][2] == pytest.approx(timoshenko_uniform(T_TOP * A), rel=0.01)
    # the supports carry exactly the applied loads
    assert force.probes["reaction_force:base"] == pytest.approx([0.0, 0.0, F_TIP], abs=1e-8 * F_TIP)
    assert traction.probes["reaction_force:base"] == pytest.approx([0.0, 0.0, T_TOP * L * A], abs=1e-8 * F_TIP)

    # vectors are lists in summary.json and x/y/z columns in probes.csv
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["probe_units"] == {"displacement:tip": "m", "reaction_force:base": "N"}
    assert summary["steps"][0]["probes"]["displacement:tip"] == force.probes["displacement:tip"]
    with (tmp_path / "probes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert float(rows[1]["reaction_force:base_z_N"]) == traction.probes["reaction_force:base"][2]
    assert float(rows[0]["displacement:tip_x_m"]) == force.probes["displacement:tip"][0]


# --------------------------------------------------------------------------------------------------
# Equilibrium: the reactions balance gravity and every applied load
# --------------------------------------------------------------------------------------------------
PRESSURE = 2.0e3
#: A small pneumatic finger (80 × 20 × 15 mm, walls ≥ 2.5 mm) meshed coarsely, to keep the tests fast.
FINGER = {"length": 0.08, "width": 0.02, "height": 0.015, "top_wall": 0.0025, "bottom_wall": 0.005,
          "side_wall": 0.0035, "end_wall": 0.005}
FINGER_H = 0.005
CABLE = [[0.075, 0.0, -0.0055], [0.04, 0.0, -0.0055], [0.01, 0.0, -0.0055]]


def finger_geometry(**overrides):
    from meshes.finger import FingerGeometry
    return FingerGeometry(**{**FINGER, **overrides})


def finger_scene(model, **loads):
    return {
        "name": "finger",
        "geometry": {"builder": "finger", "h": FINGER_H, **FINGER},
        "fem": {"model": model},
        "regions": {"finger": material(E=0.3e6)},
        "loads": {"clamp": "base", **loads},
        "steps": [],
        "outputs": dict(NO_FILES),
    }


@pytest.mark.parametrize("model", ["linear", "corotational"])
def test_reaction_balances_gravity_and_applied_loads(model):
    """A pressurised chamber and a tendon with both ends on the body apply no net force; gravity, a tip force and
    a top traction do, and the clamp's reaction (from the residual) cancels them to 1e-8."""
    scene = finger_scene(model, gravity=[0.0, 0.0, -9.81],
                         pressure={"chamber": {"group": "chamber", "pressure": PRESSURE}},
                         force={"push": {"group": "tip", "force": [0.01, 0.02, 0.05]}},
                         traction={"wind": {"group": "top", "traction": [5.0, 0.0, -2.0]}},
                         cable={"tendon": {"points": CABLE, "tension": 0.2}})
    scene["steps"] = [{"label": "loaded", "gravity": 1.0, "increments": 2,
                       "loads": {"chamber": 1.0, "push": 1.0, "wind": 1.0, "tendon": 1.0}}]
    scene["probes"] = ["reaction_force:base", "displacement:tip"]
    result = run_scene(scene, comm=SELF)
    g = finger_geometry()
    weight = np.array([0.0, 0.0, -9.81 * RHO * g.volume])
    applied = weight + np.array([0.01, 0.02, 0.05]) + np.array([5.0, 0.0, -2.0]) * g.length * g.width
    reaction = np.array(result.steps[-1].probes["reaction_force:base"])
    assert np.linalg.norm(reaction + applied) <= 1e-8 * np.linalg.norm(applied), (reaction, applied)
    assert np.linalg.norm(result.steps[-1].probes["displacement:tip"]) > 1e-3  # the finger did move


# --------------------------------------------------------------------------------------------------
# Follower pressure: frame invariance
# --------------------------------------------------------------------------------------------------
def test_follower_pressure_on_a_rotated_body_gives_the_rotated_response():
    """Clamp turned rigidly by 90° about y, then the chamber inflated: the same chamber volume and the tip's
    position rotated (SVK is frame invariant and the pressure follows the surface); the pressure's net force on
    the closed chamber vanishes, so the clamp carries nothing."""
    from fenicsfoam.bcs import rotation_matrix

    probes = ["volume:chamber", "displacement:tip", "reaction_force:base"]
    base = finger_scene("svk", pressure={"chamber": {"group": "chamber", "pressure": PRESSURE}})
    base["loads"]["motion"] = {"turn": {"group": "base", "axis": [0.0, 1.0, 0.0], "point": [0.0, 0.0, 0.0]}}
    del base["loads"]["clamp"]
    base["probes"] = probes
    still = dict(base, steps=[{"label": "inflate", "loads": {"chamber": 1.0}, "increments": 2}])
    turned = dict(base, steps=[{"label": "turn", "motions": {"turn": {"angle_deg": 90.0}}, "increments": 6},
                               {"label": "inflate", "loads": {"chamber": 1.0}, "increments": 2}])
    a = run_scene(still, comm=SELF).steps[-1].probes
    b = run_scene(turned, comm=SELF).steps[-1].probes
    R = rotation_matrix((0.0, 1.0, 0.0), np.pi / 2)
    g = finger_geometry()
    tip = np.array([g.length, 0.0, 0.0])  # the tip face's centroid
    x_a, x_b = tip + np.array(a["displacement:tip"]), tip + np.array(b["displacement:tip"])
    assert np.linalg.norm(x_b - R @ x_a) < 1e-8 * g.length
    assert b["volume:chamber"] == pytest.approx(a["volume:chamber"], rel=1e-9)
    assert a["volume:chamber"] > 1.02 * g.chamber_volume  # inflated
    lo, hi = g.chamber_box
    scale = PRESSURE * (hi[0] - lo[0]) * (hi[1] - lo[1])  # the pressure's force on the top wall
    for probes_ in (a, b):
        assert np.linalg.norm(probes_["reaction_force:base"]) < 1e-9 * scale


# --------------------------------------------------------------------------------------------------
# Cables
# --------------------------------------------------------------------------------------------------
def test_a_cable_without_tension_does_nothing():
    plain = finger_scene("corotational", gravity=[0.0, 0.0, -9.81])
    plain["steps"] = [{"label": "gravity", "gravity": 1.0}]
    plain["probes"] = ["displacement:tip", "reaction_force:base"]
    slack = finger_scene("corotational", gravity=[0.0, 0.0, -9.81], cable={"tendon": {"points": CABLE,
                                                                                       "tension": 1.0}})
    slack["steps"] = [{"label": "gravity", "gravity": 1.0, "loads": {"tendon": 0.0}}]
    slack["probes"] = plain["probes"]
    a, b = (run_scene(s, comm=SELF).steps[-1].probes for s in (plain, slack))
    for name in a:
        assert b[name] == pytest.approx(a[name], abs=1e-12 * np.max(np.abs(a[name]))), name


def solved_cable_problem(comm, pull_point=(-0.02, 0.0, -0.0055)):
    """A finger (no chamber) clamped at its base, pulled by a tendon along its bottom: the problem, solved."""
    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.loads import Cable, Facets
    from fenicsfoam.materials import Isotropic
    from fenicsfoam.solver import ElasticityProblem, LoadStep
    from meshes.finger import FACET_TAGS, make_finger

    finger = make_finger(comm, FINGER_H, finger_geometry(chamber=False))
    field = MaterialField.uniform(finger.mesh, Isotropic(E=0.3e6, nu=0.3))
    cable = Cable("tendon", [CABLE[0], Facets(FACET_TAGS["bottom"]), CABLE[2]], 0.3, pull_point=pull_point,
                  facet_tags=finger.facet_tags)
    problem = ElasticityProblem(finger.mesh, field, model="svk", degree=2, gravity=(0.0, 0.0, 0.0),
                                motions=[RigidMotion("clamp", finger.facet_tags.find(FACET_TAGS["base"]))],
                                loads=[cable], prefix="cable_test_")
    problem.solve_step(LoadStep("pull", factors={"tendon": 1.0}, increments=2))
    return problem, cable


def test_cable_work_equals_tension_times_shortening():
    """Along the straight path s ↦ s u* (0 ≤ s ≤ 1) the cable's nodal forces f(s u*) do the work
    ∫ f · u* ds = T (L(0) − L(u*)) (Gauss–Legendre, 12 points), L measured from the deformed via points."""
    import dolfinx

    problem, cable = solved_cable_problem(SELF)
    u_star = problem.u.x.array.copy()
    shortening = cable.length(None) - cable.length(problem.u)
    assert shortening > 1e-4  # the tendon shortened by pulling the finger
    u = dolfinx.fem.Function(problem.V)
    b = problem.u.vector.duplicate()
    nodes, weights = np.polynomial.legendre.leggauss(12)
    work = 0.0
    for s, w in zip(0.5 * (nodes + 1), 0.5 * weights):
        u.x.array[:] = s * u_star
        with b.localForm() as local:
            local.set(0.0)
        cable.add_residual(b, u, 1.0, follow=True)   # + T ∂L/∂u = − the cable's nodal forces
        work -= w * b.dot(problem.u.vector)
    assert work == pytest.approx(cable.tension * shortening, rel=1e-9)


def loaded_finger():
    """A soft finger with a pressurised chamber and a tendon pulled by a motor, solved (corotational)."""
    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.loads import Cable, Facets, FollowerPressure
    from fenicsfoam.materials import Isotropic
    from fenicsfoam.solver import ElasticityProblem, LoadStep
    from meshes.finger import FACET_TAGS, make_finger

    finger = make_finger(SELF, FINGER_H, finger_geometry())
    field = MaterialField.uniform(finger.mesh, Isotropic(E=0.1e6, nu=0.3))
    loads = [FollowerPressure("chamber", finger.mesh, finger.facet_tags, FACET_TAGS["chamber"], 4e3),
             Cable("tendon", [CABLE[0], Facets(FACET_TAGS["tip"]), CABLE[1]], 0.5, pull_point=(-0.02, 0.0, -0.0055),
                   facet_tags=finger.facet_tags)]
    problem = ElasticityProblem(finger.mesh, field, model="corotational", degree=2, gravity=(0.0, 0.0, 0.0),
                                motions=[RigidMotion("clamp", finger.facet_tags.find(FACET_TAGS["base"]))],
                                loads=loads, prefix="taylor_test_")
    problem.solve_step(LoadStep("load", factors={"chamber": 1.0, "tendon": 1.0}, increments=3))
    return problem


def tangent_error(problem, eps: float = 1e-4) -> float:
    """|J δ − (r(x + ε δ) − r(x − ε δ)) / 2ε| / |J δ| for a random δ (max 1 mm, 0 on the clamps), from the SNES
    callbacks (the assembled residual and Jacobian the solver uses)."""
    snes, x = problem.snes, problem.u.vector.copy()
    rng = np.random.default_rng(0)
    direction = x.duplicate()
    direction.array[:] = rng.uniform(-1e-3, 1e-3, direction.array.size)
    for motion in problem.motions.values():
        direction.array.reshape(-1, 3)[motion.dofs] = 0.0
    plus, minus, Jd = x.duplicate(), x.duplicate(), x.duplicate()
    J = snes.getJacobian()[0]
    snes.computeJacobian(x, J)
    J.mult(direction, Jd)
    for sign, r in ((1.0, plus), (-1.0, minus)):
        xe = x.copy()
        xe.axpy(sign * eps, direction)
        snes.computeFunction(xe, r)
    plus.axpy(-1.0, minus)
    plus.scale(1.0 / (2 * eps))
    plus.axpy(-1.0, Jd)
    return plus.norm() / Jd.norm()


def test_consistent_tangent_with_pressure_and_cable():
    """The assembled Jacobian is the derivative of the assembled residual at a loaded state (central differences:
    the error falls as ε², 4e-7 at ε = 1e-3, 4e-9 at 1e-4, measured), where the follower pressure and the cable
    carry part of the tangent: with the cable's tangent left out the error is 1.2e-3, with the pressure's 4.3e-3
    (measured), so the check sees both."""
    assert tangent_error(loaded_finger()) < 1e-7


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------
def chamber_scene(**loads):
    scene = finger_scene("corotational", pressure={"chamber": {"group": "chamber", "pressure": 1e3}},
                         cable={"tendon": {"points": CABLE, "tension": 1.0}},
                         motion={"wall": {"group": "tip"}}, **loads)
    scene["steps"] = [{"label": "inflate", "loads": {"chamber": 1.0}}]
    return scene


@pytest.mark.parametrize("edit, message", [
    (lambda s: s["loads"]["pressure"]["chamber"].update(group="lid"),
     r"^loads\.pressure\.chamber\.group: unknown facet group 'lid'; valid names: base, bottom, chamber"),
    (lambda s: s["loads"]["pressure"]["chamber"].pop("pressure"), r"^loads\.pressure\.chamber\.pressure: missing"),
    (lambda s: s["loads"]["pressure"]["chamber"].update(value=3), r"pressure\.chamber\.value: unknown key"),
    (lambda s: s["loads"]["cable"]["tendon"].update(tension=-1.0), r"tendon\.tension: -1\.0 is out of range"),
    (lambda s: s["loads"]["cable"]["tendon"].update(points=[[0, 0, 0]]), r"at least two points, or one and a"),
    (lambda s: s["loads"]["cable"]["tendon"].update(points=[[0, 0], "tip"]), r"points\[0\]: expected an array of 3"),
    (lambda s: s["loads"].update(force={"chamber": {"group": "tip", "force": [0, 0, 1]}}),
     r"^loads\.pressure\.chamber: the name 'chamber' is already used by loads\.force\.chamber"),
    (lambda s: s["loads"]["motion"].update(clamp={"group": "tip"}), r"^loads\.motion\.clamp: the name 'clamp' is"),
    (lambda s: s["steps"][0].update(loads={"balloon": 1.0}),
     r"^steps\[0\]\.loads\.balloon: no load named 'balloon'; declared loads: chamber, tendon"),
    (lambda s: s["steps"][0].update(loads={"tendon": -0.5}), r"tendon: -0\.5 is out of range; valid: a factor >= 0"),
    (lambda s: s["steps"][0].update(motions={"wall": {}}), r"motions\.wall: give angle_deg .* and/or translation"),
    (lambda s: s["steps"][0].update(motions={"door": {"angle_deg": 3}}), r"no motion named 'door'; declared"),
    (lambda s: s.update(probes=["reaction_force:top"]), r"'reaction_force:top': the group 'top' is not clamped"),
    (lambda s: s.update(probes=["volume:finger"]), r"'volume:finger': unknown facet group 'finger'"),
    (lambda s: s.update(probes=["stress:tip"]), r"unknown probe kind 'stress' in 'stress:tip'"),
    (lambda s: s["loads"]["motion"]["wall"].update(components=["z", "w"]),
     r"^loads\.motion\.wall\.components: expected a non-empty array of distinct \"x\", \"y\", \"z\""),
])
def test_invalid_loads_and_probes_name_the_key(edit, message):
    scene = chamber_scene()
    edit(scene)
    with pytest.raises(SceneError, match=message):
        parse_scene(scene)


def test_valid_group_probes_and_open_surfaces():
    """A reaction on a moved group and on the clamp validate; a volume needs a closed surface (checked when built)."""
    scene = chamber_scene()
    scene["probes"] = ["reaction_force:tip", "reaction_force:base", "rotation:finger", "volume:chamber"]
    parsed = parse_scene(scene)
    assert parsed.probes == tuple(scene["probes"])
    assert parsed.probe_groups["rotation:finger"].cells and not parsed.probe_groups["volume:chamber"].cells
    scene["loads"]["motion"]["wall"]["group"] = "finger"  # a region: every node of the body is moved
    scene["probes"] = ["reaction_force:finger"]
    assert parse_scene(scene).loads["motion"]["wall"]["group"].cells
    scene["probes"] = ["volume:top"]
    with pytest.raises(SceneError, match=r"'volume:top'.*do not form a closed surface"):
        run_scene(scene, comm=SELF)


# --------------------------------------------------------------------------------------------------
# Parallel: the same answer on 1 and 2 ranks
# --------------------------------------------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.skipif(MPI.COMM_WORLD.size < 2,
                    reason="compares a COMM_WORLD run with a COMM_SELF run: on one rank they are the same computation "
                           "(runs under mpirun -n 2)")
def test_loads_and_probes_do_not_depend_on_the_partition():
    scene = finger_scene("corotational", gravity=[0.0, 0.0, -9.81],
                         pressure={"chamber": {"group": "chamber", "pressure": PRESSURE}},
                         force={"push": {"group": "tip", "force": [0.0, 0.01, 0.02]}},
                         cable={"tendon": {"points": [CABLE[0], "bottom", CABLE[2]], "tension": 0.2,
                                           "pull_point": [-0.02, 0.0, -0.0055]}},
                         motion={"lift": {"group": "tip"}})
    scene["steps"] = [{"label": "inflate", "gravity": 1.0, "loads": {"chamber": 1.0, "push": 1.0, "tendon": 1.0},
                       "increments": 2},
                      {"label": "lift", "motions": {"lift": {"translation": [0.0, 0.0, 0.003]}}}]
    scene["probes"] = ["reaction_force:base", "reaction_force:tip", "displacement:chamber", "rotation:top",
                       "volume:chamber"]
    parallel = run_scene(scene, comm=MPI.COMM_WORLD)
    serial = run_scene(scene, comm=SELF)
    assert parallel.n_dofs == serial.n_dofs
    for a, b in zip(parallel.steps, serial.steps):
        for name, value in b.probes.items():
            assert a.probes[name] == pytest.approx(value, rel=1e-7, abs=1e-12), (a.label, name)


def test_a_support_blocking_one_component_carries_only_that_component():
    """A pad under the tip blocks z only: pushed along x, the finger slides over it (the pad carries no x force,
    the clamp all of it); the weight is shared between the pad and the clamp, and together they carry all of it."""
    scene = finger_scene("corotational", gravity=[0.0, 0.0, -9.81],
                         force={"push": {"group": "tip", "force": [0.05, 0.0, 0.0]}},
                         motion={"load_cell": {"group": "pad", "components": ["z"]}})
    scene["geometry"]["pad"] = 0.005
    scene["steps"] = [{"label": "push", "gravity": 1.0, "loads": {"push": 1.0}}]
    scene["probes"] = ["reaction_force:pad", "reaction_force:base", "displacement:pad"]
    probes = run_scene(scene, comm=SELF).steps[-1].probes
    weight = 9.81 * RHO * finger_geometry().volume
    pad, base = np.array(probes["reaction_force:pad"]), np.array(probes["reaction_force:base"])
    assert np.abs(pad[:2]).max() < 1e-9 * weight and pad[2] > 0.1 * weight
    assert np.linalg.norm(pad + base - [-0.05, 0.0, weight]) < 1e-8 * weight
    assert abs(probes["displacement:pad"][2]) < 1e-12 and probes["displacement:pad"][0] > 1e-5  # slid, not lifted


def test_reactions_on_cell_regions_carry_the_tripod():
    """The Tripod's three servo horns (cell regions arm_end0..2) together carry the plate's weight (the meshed
    volume's: straight edges along the hole), a third each (the plate, its silicone and its mesh are invariant under
    the plate's symmetry group)."""
    import tomllib
    from pathlib import Path

    import dolfinx
    import ufl

    scenes = Path(__file__).resolve().parents[1] / "demos" / "scenes"
    scene = tomllib.loads((scenes / "tripod_silicone_flat.toml").read_text())
    scene["geometry"]["h"] = 0.006
    scene["steps"] = scene["steps"][:1]
    scene["outputs"] = dict(NO_FILES)
    scene["probes"] = [f"reaction_force:arm_end{i}" for i in range(3)]
    result = run_scene(scene, comm=SELF)
    probes = result.steps[-1].probes
    mesh = result.displacement.function_space.mesh
    volume = dolfinx.fem.assemble_scalar(dolfinx.fem.form(dolfinx.fem.Constant(mesh, 1.0) * ufl.dx(domain=mesh)))
    weight = 9.81 * scene["regions"]["plate"]["rho"] * volume
    total = np.sum([probes[f"reaction_force:arm_end{i}"] for i in range(3)], axis=0)
    assert np.linalg.norm(total - [0.0, 0.0, weight]) < 1e-8 * weight
    for i in range(3):
        assert probes[f"reaction_force:arm_end{i}"][2] == pytest.approx(weight / 3, rel=1e-9)
