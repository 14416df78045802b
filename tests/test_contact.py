"""Frictionless contact with rigid obstacles (Nitsche): equilibrium, the gap closing at the method's rate, beam
theory for a propped cantilever, Hertz for a sphere, no effect while the gap is open, validation, and 1 = 2 ranks.
"""

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.scene import SceneError, parse_scene, run_scene

SELF = MPI.COMM_SELF
E_BLOCK, NU_BLOCK, L_BLOCK = 1.0e5, 0.3, 0.01
BOTTOM, TOP = 2, 1


def block(comm, n, model="corotational", loads=(), motions=(), graded=None):
    """A cube [0, L]³ (n³ boxes of 6 tets): facet tags TOP (z = L) and BOTTOM (z = 0); ``loads(mesh, tags)``."""
    from dolfinx import mesh as dmesh

    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.materials import Isotropic
    from fenicsfoam.solver import ElasticityProblem

    mesh = dmesh.create_box(comm, [[0.0, 0.0, 0.0], [L_BLOCK] * 3], [n, n, n])
    faces = {TOP: lambda x: np.isclose(x[2], L_BLOCK), BOTTOM: lambda x: np.isclose(x[2], 0.0)}
    found = {tag: dmesh.locate_entities_boundary(mesh, 2, where) for tag, where in faces.items()}
    entities = np.concatenate(list(found.values()))
    values = np.concatenate([np.full(len(e), tag) for tag, e in found.items()]).astype(np.int32)
    order = np.argsort(entities)
    tags = dmesh.meshtags(mesh, 2, entities[order].astype(np.int32), values[order])
    field = MaterialField.uniform(mesh, Isotropic(E=E_BLOCK, nu=NU_BLOCK))
    problem = ElasticityProblem(mesh, field, model=model, gravity=(0.0, 0.0, 0.0),
                                motions=[m(mesh, tags, found) for m in motions],
                                loads=[load(mesh, tags) for load in loads], prefix="contact_test_")
    return problem


def press(force):
    def build(mesh, tags):
        from fenicsfoam.loads import SurfaceTraction
        return SurfaceTraction("press", mesh, tags, TOP, force=(0.0, 0.0, -force))
    return build


def plane(z=0.0, motion=(0.0, 0.0, 0.0)):
    def build(mesh, tags):
        from fenicsfoam.contact import Contact, Obstacle
        return Contact("table", mesh, tags, BOTTOM, Obstacle("plane", point=(0.0, 0.0, z), normal=(0.0, 0.0, 1.0),
                                                             motion=motion))
    return build


def guide(mesh, tags, found):
    """The top face held in x and y only: the block may only move vertically, as on a press."""
    from fenicsfoam.bcs import RigidMotion
    return RigidMotion("guide", found[TOP], components=(0, 1))


def clamp(mesh, tags, found):
    from fenicsfoam.bcs import RigidMotion
    return RigidMotion("clamp", found[TOP])


# --------------------------------------------------------------------------------------------------
# A block pressed onto a plane
# --------------------------------------------------------------------------------------------------
def pressed_block(comm, n, force=0.1):
    from fenicsfoam.solver import LoadStep
    problem = block(comm, n, loads=[press(force), plane()], motions=[guide])
    problem.solve_step(LoadStep("press", factors={"press": 1.0}, increments=2))
    contact = problem.external["table"]
    compression = -problem.u.x.array.reshape(-1, 3)[:, 2].min()
    compression = comm.allreduce(compression, op=MPI.MAX)
    return contact, compression


def test_a_block_pressed_onto_a_plane_carries_the_load_and_closes_the_gap_at_second_order():
    force = 0.1  # N on 1 cm²: 1 kPa, 1 % strain
    gaps = {}
    for n in (2, 4):
        contact, compression = pressed_block(SELF, n, force)
        # the plane carries exactly the applied load, over the whole bottom face
        assert contact.force() == pytest.approx([0.0, 0.0, force], abs=1e-9 * force)
        assert contact.contact_area() == pytest.approx(L_BLOCK**2, rel=1e-12)
        gaps[n] = contact.penetration()
    # penetration below 0.5 % of the block's compression at n = 4 (h = 2.5 mm) ...
    assert 0 < gaps[4] < 5e-3 * compression
    # ... and it falls as h² (a penalty of the same stiffness γ = θ M / h falls as h: ratio 2)
    assert gaps[2] / gaps[4] > 3.0


def test_a_box_obstacle_acts_as_its_top_face():
    """A block pressed on a wide box whose top face is the plane z = 0: the same state as on that plane."""
    from fenicsfoam.solver import LoadStep

    def box(mesh, tags):
        from fenicsfoam.contact import Contact, Obstacle
        return Contact("table", mesh, tags, BOTTOM, Obstacle("box", min=(-0.05, -0.05, -0.02), max=(0.06, 0.06, 0.0)))
    states = []
    for obstacle in (plane(), box):
        problem = block(SELF, 2, loads=[press(0.1), obstacle], motions=[guide])
        problem.solve_step(LoadStep("press", factors={"press": 1.0}, increments=2))
        states.append((problem.u.x.array.copy(), problem.external["table"].force()))
    np.testing.assert_allclose(states[1][0], states[0][0], rtol=0, atol=1e-12 * np.abs(states[0][0]).max())
    np.testing.assert_allclose(states[1][1], [0.0, 0.0, 0.1], rtol=0, atol=1e-9)


def test_a_moving_plane_against_a_clamped_block_matches_a_frictionless_support():
    """The plane moved up by δ (the load factor) against a block clamped on top, and the same block with its bottom
    face moved by δ in z only (a frictionless support): the same force to the discretisation error."""
    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.solver import LoadStep
    delta = 2e-4
    with_plane = block(SELF, 3, loads=[plane(motion=(0.0, 0.0, 1.0))], motions=[clamp])
    with_plane.solve_step(LoadStep("lift", factors={"table": delta}, increments=2))
    contact = with_plane.external["table"]

    def support(mesh, tags, found):
        return RigidMotion("support", found[BOTTOM], components=(2,))
    with_support = block(SELF, 3, motions=[clamp, support])
    with_support.solve_step(LoadStep("lift", translations={"support": (0.0, 0.0, delta)}, increments=2))
    reaction = _reaction(with_support, BOTTOM)
    assert contact.force()[2] == pytest.approx(reaction, rel=0.01)
    assert contact.penetration() < 0.01 * delta


def _reaction(problem, tag):
    from dolfinx import mesh as dmesh

    from fenicsfoam.probes import ReactionForce
    mesh = problem.V.mesh
    found = dmesh.locate_entities_boundary(mesh, 2, lambda x: np.isclose(x[2], 0.0))
    tags = dmesh.meshtags(mesh, 2, np.sort(found).astype(np.int32), np.full(len(found), tag, dtype=np.int32))
    return ReactionForce(problem, tags, (tag,))()[2]


def test_no_contact_while_the_gap_stays_open_is_the_run_without_the_obstacle():
    from fenicsfoam.solver import LoadStep

    def hang(mesh, tags):
        from fenicsfoam.loads import SurfaceTraction
        return SurfaceTraction("pull", mesh, tags, BOTTOM, force=(0.02, 0.0, -0.05))
    free = block(SELF, 3, loads=[hang], motions=[clamp])
    obstacle = block(SELF, 3, loads=[hang, plane(z=-0.002)], motions=[clamp])
    for problem in (free, obstacle):
        problem.solve_step(LoadStep("pull", factors={"pull": 1.0}, increments=2))
    sag = np.abs(free.u.x.array).max()
    assert 0 < sag < 0.5 * 0.002  # the gap stays open
    np.testing.assert_allclose(obstacle.u.x.array, free.u.x.array, rtol=0, atol=1e-12 * sag)
    contact = obstacle.external["table"]
    assert contact.force().tolist() == [0.0, 0.0, 0.0] and contact.contact_area() == 0.0


# --------------------------------------------------------------------------------------------------
# A cantilever whose tip stops on a plane (scene): beam theory for the propped cantilever
# --------------------------------------------------------------------------------------------------
L_BEAM, A_BEAM, E_BEAM, NU_BEAM, Q_TOP = 0.25, 0.015, 1.0e6, 0.3, 20.0


def timoshenko():
    """Tip deflection of the cantilever under the uniform top traction, and its tip compliance (m/N)."""
    inertia, area = A_BEAM**4 / 12, A_BEAM**2
    kappa, G = 10 * (1 + NU_BEAM) / (12 + 11 * NU_BEAM), E_BEAM / (2 * (1 + NU_BEAM))
    q = Q_TOP * A_BEAM
    w_free = q * L_BEAM**4 / (8 * E_BEAM * inertia) + q * L_BEAM**2 / (2 * kappa * G * area)
    compliance = L_BEAM**3 / (3 * E_BEAM * inertia) + L_BEAM / (kappa * G * area)
    return w_free, compliance


def propped_scene(gap, h=0.015):
    return {
        "name": "propped",
        "geometry": {"builder": "finger", "h": h, "length": L_BEAM, "width": A_BEAM, "height": A_BEAM,
                     "chamber": False},
        "fem": {"model": "linear", "degree": 2},
        "regions": {"beam": {"tags": "finger", "material": "isotropic", "E": E_BEAM, "nu": NU_BEAM, "rho": 0.0}},
        "loads": {"clamp": "base", "traction": {"top_load": {"group": "top", "traction": [0.0, 0.0, -Q_TOP]}}},
        "contacts": {"floor": {"group": "bottom", "obstacle": "plane", "point": [0.0, 0.0, -A_BEAM / 2 - gap],
                               "normal": [0.0, 0.0, 1.0]}},
        "steps": [{"label": "load", "loads": {"top_load": 1.0}}],
        "probes": ["displacement:tip", "reaction_force:base", "contact_force:floor", "contact_area:floor"],
        "outputs": {"xdmf": False, "png": False},
    }


def test_a_cantilever_tip_stopped_by_a_plane_matches_the_propped_cantilever(tmp_path):
    w_free, compliance = timoshenko()
    gap = 0.5 * w_free
    probes = run_scene(propped_scene(gap), tmp_path, comm=SELF).steps[0].probes
    # the tip stops on the plane: its mean deflection is the gap (the tip face's bottom edge touches)
    assert -probes["displacement:tip"][2] == pytest.approx(gap, rel=5e-3)
    # the plane pushes up with the force that brings the free tip back to the gap (beam theory, within 2 %)
    force = probes["contact_force:floor"]
    assert force[2] == pytest.approx((w_free - gap) / compliance, rel=0.02)
    assert force[0] == pytest.approx(0.0, abs=1e-12) and force[1] == pytest.approx(0.0, abs=1e-12)
    # the clamp and the plane carry the load together
    assert force[2] + probes["reaction_force:base"][2] == pytest.approx(Q_TOP * A_BEAM * L_BEAM, rel=1e-9)
    assert 0 < probes["contact_area:floor"] < 0.1 * L_BEAM * A_BEAM


# --------------------------------------------------------------------------------------------------
# A rigid sphere pressed into a flat block: Hertz
# --------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_sphere_pressed_into_a_block_follows_hertz():
    """Quarter of a 10 mm block (symmetry planes x = 0, y = 0, a roller base), P2, nodes graded towards the contact
    (x = L ξ³): a sphere of radius 10 mm pressed by δ. Hertz: F = 4/3 E* √R δ^{3/2}, contact radius a = √(R δ).
    Measured (8³ boxes): F 7.7 % above Hertz at δ = R/400 (a = L/20; the finite block and the mesh stiffen it),
    the exponent 3/2 to 0.1 %, the area π a² to 1 %."""
    from dolfinx import mesh as dmesh

    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.contact import Contact, Obstacle
    from fenicsfoam.materials import Isotropic
    from fenicsfoam.solver import ElasticityProblem, LoadStep
    n, L, R, delta = 8, 0.01, 0.01, 2.5e-5
    mesh = dmesh.create_box(SELF, [[0.0, 0.0, -1.0], [1.0, 1.0, 0.0]], [n, n, n])
    x = mesh.geometry.x
    x[:, 0], x[:, 1], x[:, 2] = L * x[:, 0] ** 3, L * x[:, 1] ** 3, -L * (-x[:, 2]) ** 3
    faces = {1: lambda x: np.isclose(x[2], 0.0), 2: lambda x: np.isclose(x[2], -L),
             3: lambda x: np.isclose(x[0], 0.0), 4: lambda x: np.isclose(x[1], 0.0)}
    found = {tag: dmesh.locate_entities_boundary(mesh, 2, where) for tag, where in faces.items()}
    entities, first = np.unique(np.concatenate(list(found.values())), return_index=True)
    values = np.concatenate([np.full(len(e), tag) for tag, e in found.items()]).astype(np.int32)[first]
    tags = dmesh.meshtags(mesh, 2, entities.astype(np.int32), values)
    ball = Contact("ball", mesh, tags, 1, Obstacle("sphere", center=(0.0, 0.0, R), radius=R, motion=(0, 0, -1.0)))
    motions = [RigidMotion("base", found[2], components=(2,)), RigidMotion("x0", found[3], components=(0,)),
               RigidMotion("y0", found[4], components=(1,))]
    problem = ElasticityProblem(mesh, MaterialField.uniform(mesh, Isotropic(E=E_BLOCK, nu=NU_BLOCK)), model="linear",
                                degree=2, gravity=(0.0, 0.0, 0.0), motions=motions, loads=[ball], prefix="hertz_")
    e_star = E_BLOCK / (1 - NU_BLOCK**2)
    forces = []
    for depth in (delta / 2, delta):
        problem.solve_step(LoadStep(f"{depth}", factors={"ball": depth}, increments=2))
        forces.append(-4 * ball.force()[2])  # four quarters; the sphere pushes down
        assert forces[-1] == pytest.approx(4 / 3 * e_star * np.sqrt(R) * depth**1.5, rel=0.1)
        assert 4 * ball.contact_area() == pytest.approx(np.pi * R * depth, rel=0.05)
        assert ball.penetration() < 0.01 * depth
    assert np.log2(forces[1] / forces[0]) == pytest.approx(1.5, rel=0.01)


# --------------------------------------------------------------------------------------------------
# Scenes: validation, and 1 = 2 ranks
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("edit, message", [
    (lambda s: s["contacts"]["floor"].update(obstacle="cone"), "contacts.floor.obstacle: 'cone' is not valid"),
    (lambda s: s["contacts"]["floor"].update(group="nowhere"), "contacts.floor.group: unknown facet group"),
    (lambda s: s["contacts"]["floor"].pop("normal"), "contacts.floor.normal: missing value"),
    (lambda s: s["contacts"]["floor"].update(normal=[0, 0, 0]), "contacts.floor.normal: the plane's normal"),
    (lambda s: s["contacts"]["floor"].update(nitsche=0), "contacts.floor.nitsche: 0 is out of range"),
    (lambda s: s["contacts"]["floor"].update(radius=1.0), "contacts.floor.radius: unknown key"),
    (lambda s: s["contacts"].update(top_load={"group": "tip", "obstacle": "sphere", "center": [0, 0, 0],
                                              "radius": -1}), "contacts.top_load.radius: -1 is out of range"),
    (lambda s: s["contacts"].update(top_load={"group": "tip", "obstacle": "box", "min": [0, 0, 0],
                                              "max": [1, 1, 1], "center": [0, 0, 0]}), "one pair"),
    (lambda s: s["contacts"].update(top_load={"group": "tip", "obstacle": "box", "min": [0, 0, 0],
                                              "max": [1, 1, 1]}), "contacts.top_load: the name 'top_load' is already"),
    (lambda s: s["steps"][0].update(contacts={"floorr": 1.0}), "steps[0].contacts.floorr: no contact named"),
    (lambda s: s["steps"][0]["loads"].update(floor=1.0), "steps[0].loads.floor: no load named"),
    (lambda s: s.update(probes=["contact_force:tip"]), "no contact named 'tip'"),
])
def test_invalid_contacts_name_the_key(edit, message):
    scene = propped_scene(0.01)
    edit(scene)
    with pytest.raises(SceneError, match=message.replace("[", r"\[").replace("(", r"\(")):
        parse_scene(scene)


def test_valid_contacts_parse():
    scene = propped_scene(0.01)
    scene["contacts"]["ball"] = {"group": "tip", "obstacle": "sphere", "center": [0.3, 0, 0], "radius": 0.04,
                                 "motion": [-1.0, 0.0, 0.0], "nitsche": 20}
    scene["contacts"]["wall"] = {"group": "top", "obstacle": "box", "center": [0.1, 0, 0.1],
                                 "half_sizes": [0.05, 0.05, 0.05]}
    scene["steps"][0]["contacts"] = {"ball": 0.01}
    parsed = parse_scene(scene)
    assert parsed.steps[0].loads == {"top_load": 1.0, "ball": 0.01}
    assert parsed.loads["contact"]["wall"]["min"] == (0.05, -0.05, 0.05)
    assert parsed.loads["contact"]["ball"]["nitsche"] == 20


@pytest.mark.mpi
def test_contact_on_two_ranks_equals_one():
    comm = MPI.COMM_WORLD
    parallel, _ = pressed_block(comm, 3)
    serial, _ = pressed_block(SELF, 3)
    forces = parallel.force(), serial.force()
    np.testing.assert_allclose(forces[0], forces[1], rtol=1e-10, atol=1e-14)
    assert parallel.penetration() == pytest.approx(serial.penetration(), rel=1e-8)
    assert parallel.contact_area() == pytest.approx(serial.contact_area(), rel=1e-12)


@pytest.mark.slow  # ≈ 13 s wall (5 s CPU) on the shared 2-core box
def test_a_failed_factorization_is_not_reused_by_the_cut_back():
    """The pneumatic finger inflated to 20 kPa onto a ball in one increment: the full increment's Newton iterates run
    deep into the ball and the LU factorization fails; the halved increments factor afresh and reach the state of
    a run in four increments."""
    import tomllib
    from pathlib import Path

    scenes = Path(__file__).resolve().parents[1] / "demos" / "scenes"
    data = tomllib.loads((scenes / "finger_pneumatic.toml").read_text())
    data["geometry"]["h"] = 0.004
    data["fem"]["degree"] = 1
    data["outputs"] = {"png": False, "xdmf": False}
    data["loads"]["gravity"] = [9.81, 0.0, 0.0]
    data["contacts"] = {"ball": {"group": "bottom", "obstacle": "sphere", "radius": 0.02,
                                 "center": [0.08, 0.0, -0.0295]}}
    data["probes"] = ["contact_force:ball"]
    forces, cutbacks = [], []
    for increments in (1, 4):
        data["steps"] = [{"label": "rest", "gravity": 1.0},
                         {"label": "p20kPa", "loads": {"chamber": 1.0}, "increments": increments}]
        last = run_scene(parse_scene(data), comm=SELF).steps[-1]
        forces.append(last.probes["contact_force:ball"])
        cutbacks.append(last.cutbacks)
    assert cutbacks[0] >= 1  # the failed full increment was cut back
    np.testing.assert_allclose(forces[0], forces[1], rtol=1e-6, atol=1e-9)
    assert forces[1][2] > 0.05
