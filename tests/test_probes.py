"""fenicsfoam.probes: exact values for uniform, quadratic and rigid displacements; invariances; gradients by their
Taylor remainders; error paths."""

import math

import dolfinx
import dolfinx.mesh
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from fenicsfoam.probes import (
    CenterHeight,
    CenterRotation,
    CenterTilt,
    TipDeflection,
    center_height,
    center_rotation,
    kabsch_rotation,
    kabsch_rotation_gradient,
    tilt_angle,
    tip_deflection,
    twist_angle,
)
from meshes.tripod import PAPER_H, RING, make_tripod

pytestmark = pytest.mark.mpi

CENTRE, OUTER = 1, 2  # cell tags of the box: the central block |x|, |y| < 0.5 and the rest
TIP, MIDPLANE = 12, 13  # facet tags: the face x = 1 and the interior plane x = 0


def rotation(axis, angle):
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


@pytest.fixture(scope="module")
def box():
    """[−1, 1]² × [−0.25, 0.25], 4 × 4 × 1 hexahedra split into tetrahedra; tags aligned with the hexahedra."""
    mesh = dolfinx.mesh.create_box(MPI.COMM_WORLD, [[-1, -1, -0.25], [1, 1, 0.25]], [4, 4, 1],
                                   dolfinx.mesh.CellType.tetrahedron)
    tdim = mesh.topology.dim
    n_cells = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    midpoints = dolfinx.mesh.compute_midpoints(mesh, tdim, np.arange(n_cells, dtype=np.int32))
    central = (np.abs(midpoints[:, 0]) < 0.5) & (np.abs(midpoints[:, 1]) < 0.5)
    cell_tags = dolfinx.mesh.meshtags(mesh, tdim, np.arange(n_cells, dtype=np.int32),
                                      np.where(central, CENTRE, OUTER).astype(np.int32))
    tip = dolfinx.mesh.locate_entities(mesh, tdim - 1, lambda x: np.isclose(x[0], 1.0))
    mid = dolfinx.mesh.locate_entities(mesh, tdim - 1, lambda x: np.isclose(x[0], 0.0))
    order = np.argsort(np.concatenate([tip, mid]))
    facet_tags = dolfinx.mesh.meshtags(mesh, tdim - 1, np.concatenate([tip, mid])[order],
                                       np.concatenate([np.full_like(tip, TIP), np.full_like(mid, MIDPLANE)])[order])
    return mesh, cell_tags, facet_tags


@pytest.fixture(scope="module", params=[1, 2], ids=["P1", "P2"])
def space(request, box):
    return dolfinx.fem.VectorFunctionSpace(box[0], ("CG", request.param))


def interpolate(V, f):
    u = dolfinx.fem.Function(V)
    u.interpolate(f)
    return u


def rigid(R, centre, translation):
    """u(X) = R (X − c) + c + t − X in the (3, n) layout of ``interpolate``."""
    c, t = np.asarray(centre)[:, None], np.asarray(translation)[:, None]
    return lambda x: R @ (x - c) + c + t - x


def test_tip_deflection_of_a_uniform_displacement_is_that_displacement(space, box):
    _, _, facet_tags = box
    u = interpolate(space, lambda x: np.vstack([np.full(x.shape[1], 0.3), np.zeros(x.shape[1]),
                                                np.full(x.shape[1], -0.048)]))
    assert TipDeflection(space, facet_tags, TIP, (0, 0, 1))(u) == pytest.approx(-0.048, rel=1e-13)
    assert TipDeflection(space, facet_tags, TIP, (0, 0, -9.81))(u) == pytest.approx(0.048, rel=1e-13)
    assert tip_deflection(u, facet_tags, TIP, (1, 0, 0)) == pytest.approx(0.3, rel=1e-13)


def test_tip_deflection_is_the_face_mean_of_a_quadratic_field(box):
    # u_z = a + b y² on the face y ∈ [−1, 1], z ∈ [−¼, ¼]: mean a + b/3 (exact in P2).
    V = dolfinx.fem.VectorFunctionSpace(box[0], ("CG", 2))
    u = interpolate(V, lambda x: np.vstack([np.zeros_like(x[0]), np.zeros_like(x[0]), 0.2 + 0.6 * x[1] ** 2]))
    probe = TipDeflection(V, box[2], TIP, (0, 0, 1))
    assert probe(u) == pytest.approx(0.2 + 0.6 / 3, rel=1e-13)
    u.x.array[:] *= -1  # the probe reads the field at each call
    assert probe(u) == pytest.approx(-(0.2 + 0.6 / 3), rel=1e-13)


@pytest.mark.parametrize("angle_deg", [30.0, -30.0, 135.0, -150.0, 179.0])
def test_rigid_motion_gives_exact_height_and_rotation(space, box, angle_deg):
    _, cell_tags, _ = box
    theta = math.radians(angle_deg)
    # Twist by θ about e_z, then a 20° tilt about a horizontal axis, about a centre c, then a translation t.
    R = rotation([math.cos(0.7), math.sin(0.7), 0.0], math.radians(20.0)) @ rotation([0, 0, 1], theta)
    c, t = np.array([0.3, -0.2, 0.1]), np.array([0.05, 0.1, 0.7])
    u = interpolate(space, rigid(R, c, t))
    # The central block's centroid is the origin, and a rigid motion moves the centroid rigidly.
    assert CenterHeight(space, cell_tags, CENTRE)(u) == pytest.approx((c + t - R @ c)[2], abs=1e-13)
    rotation_probe = CenterRotation(space, cell_tags, CENTRE)
    assert rotation_probe(u) == pytest.approx(angle_deg, abs=1e-10)
    np.testing.assert_allclose(rotation_probe.rotation_matrix(u), R, atol=1e-12)
    # The same for the outer region and for both regions together (a tag or a sequence of tags).
    assert center_rotation(u, cell_tags, [CENTRE, OUTER]) == pytest.approx(angle_deg, abs=1e-10)
    assert center_height(u, cell_tags, (CENTRE, OUTER)) == pytest.approx((c + t - R @ c)[2], abs=1e-13)


def test_distributed_fit_equals_a_fit_of_the_gathered_nodes(box):
    # A non-rigid field: the distributed sums must see every node of the region exactly once, whatever the
    # partition. Reference: gather (global index, X, u) of the region's nodes from all ranks, fit in numpy.
    _, cell_tags, _ = box
    V = dolfinx.fem.VectorFunctionSpace(box[0], ("CG", 2))
    u = interpolate(V, lambda x: np.vstack([-0.4 * x[1] * (1 + x[0] ** 2), 0.4 * x[0] + 0.1 * x[2], 0.2 * x[0] * x[1]]))
    probe = CenterRotation(V, cell_tags, CENTRE)
    dofs = dolfinx.fem.locate_dofs_topological(V, 3, cell_tags.find(CENTRE))
    local = (V.dofmap.index_map.local_to_global(dofs), V.tabulate_dof_coordinates()[dofs],
             u.x.array.reshape(-1, 3)[dofs])
    gathered = [np.concatenate(parts) for parts in zip(*MPI.COMM_WORLD.allgather(local))]
    _, first = np.unique(gathered[0], return_index=True)
    X, x = gathered[1][first], gathered[1][first] + gathered[2][first]
    # P2 on 2 × 2 × 1 hexahedra split into tetrahedra: the 5 × 5 × 3 lattice of vertices and edge midpoints.
    assert probe.n_nodes == len(first) == 5 * 5 * 3
    H = (X - X.mean(axis=0)).T @ (x - x.mean(axis=0))
    expected = math.degrees(twist_angle(kabsch_rotation(H)))
    assert probe(u) == pytest.approx(expected, abs=1e-12)
    assert abs(expected) > 5


def test_twist_ignores_swings_about_horizontal_axes():
    # R_swing R_z(θ) and R_z(θ) R_swing (= R'_swing R_z(θ)) both twist by θ; a pure swing does not twist;
    # a rotation about a tilted axis does not twist by its angle.
    theta, swing = math.radians(50.0), rotation([1.0, 2.0, 0.0], math.radians(35.0))
    assert twist_angle(swing @ rotation([0, 0, 1], theta)) == pytest.approx(theta, abs=1e-14)
    assert twist_angle(rotation([0, 0, 1], theta) @ swing) == pytest.approx(theta, abs=1e-14)
    assert twist_angle(swing) == pytest.approx(0.0, abs=1e-14)
    # About a = (0, sin β, cos β) by φ: quaternion (cos φ/2, sin φ/2 a), twist 2 atan(tan(φ/2) cos β).
    beta, phi = math.radians(40.0), math.radians(60.0)
    expected = 2 * math.atan(math.tan(phi / 2) * math.cos(beta))
    assert twist_angle(rotation([0, math.sin(beta), math.cos(beta)], phi)) == pytest.approx(expected, abs=1e-14)
    with pytest.raises(ValueError, match="upside down"):
        twist_angle(rotation([1, 0, 0], math.pi))


def test_kabsch_recovers_a_rotation_from_noisy_free_point_clouds():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(40, 3))
    X -= X.mean(axis=0)
    R = rotation(rng.normal(size=3), 2.5)
    H = X.T @ (X @ R.T + [1.0, 2.0, 3.0])
    np.testing.assert_allclose(kabsch_rotation(H), R, atol=1e-12)
    # A reflection in the data never gives an improper matrix.
    assert np.linalg.det(kabsch_rotation(X.T @ (X * [1, 1, -1]))) == pytest.approx(1.0)


def test_probes_on_the_tripod_ring():
    tripod = make_tripod(MPI.COMM_WORLD, PAPER_H)
    V = dolfinx.fem.VectorFunctionSpace(tripod.mesh, ("CG", 1))
    R = rotation([1.0, -1.0, 0.0], math.radians(10.0)) @ rotation([0, 0, 1], math.radians(-13.0))
    u = interpolate(V, rigid(R, [0.0, 0.0, -0.06], [0.001, 0.0, 0.07]))
    assert CenterRotation(V, tripod.cell_tags, RING)(u) == pytest.approx(-13.0, abs=1e-10)
    # The ring's reference centroid X̄ (near the origin, up to the chords of its arcs) moves rigidly.
    dx = ufl.Measure("dx", domain=tripod.mesh, subdomain_data=tripod.cell_tags)(RING)
    X = ufl.SpatialCoordinate(tripod.mesh)
    moments = [tripod.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(f * dx)), op=MPI.SUM)
               for f in (X[0], X[1], X[2], dolfinx.fem.Constant(tripod.mesh, 1.0))]
    X_mean = np.array(moments[:3]) / moments[3]
    assert np.linalg.norm(X_mean) < 1e-5
    expected = R @ (X_mean - [0, 0, -0.06]) + [0, 0, -0.06] + [0.001, 0.0, 0.07]
    assert CenterHeight(V, tripod.cell_tags, RING)(u) == pytest.approx(expected[2], abs=1e-14)


def test_errors_name_the_problem(box, space):
    mesh, cell_tags, facet_tags = box
    with pytest.raises(ValueError, match=r"^cell tag\(s\) \[7\] mark no entity .* available cell tags: \[1, 2\]"):
        CenterHeight(space, cell_tags, 7)
    with pytest.raises(ValueError, match=r"facet tag\(s\) \[11\] mark no entity .* available facet tags: \[12, 13\]"):
        TipDeflection(space, facet_tags, 11, (0, 0, 1))
    with pytest.raises(ValueError, match="facet tags must mark entities of dimension 2, got tags of dimension 3"):
        TipDeflection(space, cell_tags, CENTRE, (0, 0, 1))
    with pytest.raises(ValueError, match="facet tag 13 has zero area on the exterior boundary"):
        TipDeflection(space, facet_tags, MIDPLANE, (0, 0, 1))
    with pytest.raises(ValueError, match="direction must be a non-zero finite 3-vector"):
        TipDeflection(space, facet_tags, TIP, (0, 0, 0))
    with pytest.raises(ValueError, match="tags must be an int or a non-empty sequence of ints"):
        CenterRotation(space, cell_tags, [])
    with pytest.raises(ValueError, match="probes need a 3D vector Lagrange displacement space"):
        CenterHeight(dolfinx.fem.FunctionSpace(mesh, ("CG", 1)), cell_tags, CENTRE)
    other = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 1, 1, 1)
    with pytest.raises(ValueError, match="the cell tags belong to another mesh"):
        CenterHeight(dolfinx.fem.VectorFunctionSpace(other, ("CG", 1)), cell_tags, CENTRE)
    probe = CenterRotation(space, cell_tags, CENTRE)
    wrong = dolfinx.fem.Function(dolfinx.fem.VectorFunctionSpace(mesh, ("CG", 3)))
    with pytest.raises(ValueError, match="another mesh or element than the probe's"):
        probe(wrong)


@pytest.mark.parametrize("angle_deg", [25.0, -40.0, 80.0])
def test_tilts_of_rigid_rotations_about_x_and_y(space, box, angle_deg):
    # A rotation by α about x tilts by α about x and not about y (and vice versa), whatever twist follows or
    # precedes it about e_z (the normal R e_z does not see the twist), and whatever translation.
    _, cell_tags, _ = box
    alpha, twist = math.radians(angle_deg), rotation([0, 0, 1], math.radians(70.0))
    cases = (("x", "y", rotation([1, 0, 0], alpha) @ twist), ("y", "x", rotation([0, 1, 0], alpha) @ twist))
    for axis, other, R in cases:
        u = interpolate(space, rigid(R, [0.2, 0.1, 0.0], [0.3, -0.1, 0.5]))
        assert CenterTilt(space, cell_tags, CENTRE, axis)(u) == pytest.approx(angle_deg, abs=1e-10)
        assert CenterTilt(space, cell_tags, CENTRE, other)(u) == pytest.approx(0.0, abs=1e-10)
    # tilt_angle directly: the twist on either side leaves the normal's tilts unchanged
    swing = rotation([math.cos(0.4), math.sin(0.4), 0.0], math.radians(30.0))
    for axis in ("x", "y"):
        assert tilt_angle(swing @ twist, axis) == pytest.approx(tilt_angle(swing, axis), abs=1e-14)
    # small swings: the tilts are the swing's rotation-vector components (to second order)
    eps = 1e-4
    small = rotation([0.6, 0.8, 0.0], eps)
    assert tilt_angle(small, "x") == pytest.approx(0.6 * eps, rel=1e-7)
    assert tilt_angle(small, "y") == pytest.approx(0.8 * eps, rel=1e-7)
    with pytest.raises(ValueError, match="tilt axis"):
        tilt_angle(small, "z")


def test_kabsch_rotation_gradient_taylor():
    # f(R) = sum(W * R) for a fixed W: the remainder of f(R(H + h dH)) − f(R(H)) − h ∂f/∂H : dH is O(h²).
    rng = np.random.default_rng(7)
    X = rng.normal(size=(30, 3))
    X -= X.mean(axis=0)
    x = X @ rotation([0.3, -0.5, 0.8], 1.1).T + 0.2 * rng.normal(size=(30, 3))
    H, dH, W = X.T @ x, rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    G = kabsch_rotation_gradient(H, W)
    f0 = np.sum(W * kabsch_rotation(H))
    steps = 1e-2 / 2.0 ** np.arange(5)
    remainders = [abs(np.sum(W * kabsch_rotation(H + h * dH)) - f0 - h * np.sum(G * dH)) for h in steps]
    rates = np.log2(np.array(remainders[:-1]) / remainders[1:])
    assert rates.min() > 1.95, rates


def test_probe_gradients_have_second_order_taylor_remainders(space, box):
    # At a non-rigid displacement (large rotation + stretch), along a smooth direction: the rotation and tilt
    # probes' remainders fall as h² (rate 2); the linear probes' (height, tip) are at round-off.
    mesh, cell_tags, facet_tags = box
    R = rotation([0.3, 0.4, 0.85], 0.8)
    u0 = interpolate(space, lambda x: (R - np.eye(3)) @ x + 0.05 * np.vstack([x[1] ** 2, x[0] * x[2], x[0] ** 2]))
    du = interpolate(space, lambda x: np.vstack([np.sin(2 * x[1]), x[0] * x[1], np.cos(x[0]) * x[2] + x[1]]))
    u = dolfinx.fem.Function(space)
    n = space.dofmap.index_map.size_local * 3
    probes = {"height": CenterHeight(space, cell_tags, CENTRE), "tip": TipDeflection(space, facet_tags, TIP, (1, 2, 3)),
              "rotation": CenterRotation(space, cell_tags, CENTRE),
              "tilt_x": CenterTilt(space, cell_tags, [CENTRE, OUTER], "x"),
              "tilt_y": CenterTilt(space, cell_tags, CENTRE, "y")}
    steps = 1e-2 / 2.0 ** np.arange(4)
    for name, probe in probes.items():
        j0 = probe(u0)
        slope = MPI.COMM_WORLD.allreduce(float(np.dot(probe.gradient(u0), du.x.array[:n])))
        remainders = []
        for h in steps:
            u.x.array[:] = u0.x.array + h * du.x.array
            remainders.append(abs(probe(u) - j0 - h * slope))
        if name in ("height", "tip"):
            assert max(remainders) < 1e-13 * max(1.0, abs(slope)), (name, remainders)
        else:
            rates = np.log2(np.array(remainders[:-1]) / remainders[1:])
            assert abs(slope) > 1.0 and rates.min() > 1.9, (name, slope, rates)
