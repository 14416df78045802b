"""meshes.tripod: exact plate and region volumes, tag placement, the paper-size preset, D3 invariance of the mesh,
servo kinematics."""

import math

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from scipy.spatial import cKDTree

from meshes.tripod import (
    ARM,
    ARM_END,
    CENTRE,
    PAPER_H,
    REGIONS,
    RING,
    TripodGeometry,
    make_tripod,
    symmetry_group,
)

GEOMETRY = TripodGeometry()


@pytest.fixture(scope="module")
def tripod():
    return make_tripod(MPI.COMM_WORLD, PAPER_H)


@pytest.fixture(scope="module")
def tripod_p2():
    return make_tripod(MPI.COMM_WORLD, PAPER_H, order=2)


def region_volumes(tripod):
    dx = ufl.Measure("dx", domain=tripod.mesh, subdomain_data=tripod.cell_tags)
    one = dolfinx.fem.Constant(tripod.mesh, 1.0)
    local = np.array([dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * dx(tag))) for tag in REGIONS["plate"]])
    total = np.empty_like(local)
    tripod.mesh.comm.Allreduce(local, total, op=MPI.SUM)
    return dict(zip(REGIONS["plate"], total))


def global_extremes(comm, values):
    """(min, max) over all ranks of a 1D array (empty on some ranks allowed)."""
    local = np.array([-np.min(values, initial=np.inf), np.max(values, initial=-np.inf)])
    out = np.empty_like(local)
    comm.Allreduce(local, out, op=MPI.MAX)
    return -out[0], out[1]


def test_analytic_area_of_the_default_plate():
    # Hub triangle (side 30 mm) + three 30 × (55 − 8.66) mm arms − hole r = 5 mm, by hand.
    hub = math.sqrt(3) / 4 * 30**2
    arms = 3 * 30 * (55 - 15 / math.sqrt(3))
    assert GEOMETRY.area == pytest.approx((hub + arms - math.pi * 25) * 1e-6, rel=1e-14)
    assert GEOMETRY.reentrant_radius == pytest.approx(0.015 / math.sin(math.pi / 3))


@pytest.mark.mpi
def test_plate_volume_matches_the_analytic_volume(tripod, tripod_p2):
    # Order 1: the arcs of the hole become inscribed polygons, so the mesh holds slightly more material.
    excess = sum(region_volumes(tripod).values()) / GEOMETRY.volume - 1
    assert 0 < excess < 3e-3
    # Order 2: curved arcs, the error falls to the quadrature of the curved edges.
    assert sum(region_volumes(tripod_p2).values()) == pytest.approx(GEOMETRY.volume, rel=5e-5)


@pytest.mark.mpi
def test_region_volumes_ring_and_arm_ends_are_exact_up_to_chords(tripod_p2):
    volumes = region_volumes(tripod_p2)
    t = GEOMETRY.thickness
    assert volumes[RING] == pytest.approx(GEOMETRY.ring_area * t, rel=5e-4)
    for tag in ARM_END:
        assert volumes[tag] == pytest.approx(GEOMETRY.arm_end_area * t, rel=1e-5)
    # The three arms are congruent (rotations by 120°), the centre holds what is left.
    arm = [volumes[tag] for tag in ARM]
    assert max(arm) == pytest.approx(min(arm), rel=1e-4)
    assert volumes[CENTRE] > 0


@pytest.mark.mpi
def test_all_tags_present_and_the_preset_gives_about_2684_tetrahedra(tripod):
    """PAPER_H gives 2694 tetrahedra; the mesh is six copies of the wedge's, so the count is a multiple of 6."""
    comm = tripod.mesh.comm
    present = set().union(*comm.allgather(set(np.unique(tripod.cell_tags.values).tolist())))
    assert present == set(REGIONS["plate"])
    assert abs(tripod.n_cells - 2684) <= 0.15 * 2684
    assert tripod.n_cells % 6 == 0
    n_local = tripod.mesh.topology.index_map(3).size_local
    tagged = np.unique(tripod.region_cells("plate"))
    assert np.count_nonzero(tagged < n_local) == n_local  # every owned cell carries a tag


def test_symmetry_group_is_the_dihedral_group_of_the_plate():
    group = symmetry_group()
    for g in group:
        np.testing.assert_allclose(g @ g.T, np.eye(3), atol=1e-15)
        np.testing.assert_allclose(g[2], [0, 0, 1], atol=0)  # keeps e_z: no flip of the plate
    # Closed under composition: each product is one of the six, and the six are distinct.
    products = np.einsum("aij,bjk->abik", group, group).reshape(-1, 1, 3, 3)
    assert np.all(np.sum(np.abs(products - group).sum(axis=(2, 3)) < 1e-14, axis=1) == 1)
    assert np.linalg.det(group).round(14).tolist() == [1, 1, 1, -1, -1, -1]
    # Every element permutes the arm directions, so it maps the plate onto itself.
    e = GEOMETRY.arm_directions()
    for g in group:
        match = np.abs(e @ g.T @ e.T - 1) < 1e-14  # match[i, j]: g e_i = e_j
        assert np.all(match.sum(axis=0) == 1) and np.all(match.sum(axis=1) == 1)


def gathered_mesh(tripod):
    """Every rank: all owned geometry nodes (N, 3), owned cells' node coordinates (n, nodes per cell, 3), tags."""
    comm, mesh = tripod.mesh.comm, tripod.mesh
    n_cells = mesh.topology.index_map(3).size_local
    x = mesh.geometry.x
    cells = mesh.geometry.dofmap.array.reshape(-1, mesh.geometry.dofmap.links(0).size)[:n_cells]
    tags = np.full(n_cells, -1)
    owned = tripod.cell_tags.indices < n_cells
    tags[tripod.cell_tags.indices[owned]] = tripod.cell_tags.values[owned]
    nodes = np.concatenate(comm.allgather(x[: mesh.geometry.index_map().size_local]))
    return nodes, np.concatenate(comm.allgather(x[cells])), np.concatenate(comm.allgather(tags))


def image_tags(g, tags):
    """Cell tags after the map g: arm i's tags become those of the arm g e_i points along."""
    e = GEOMETRY.arm_directions()
    arm_of = [int(np.argmax(e @ (g @ e[i]))) for i in range(3)]
    mapping = {RING: RING, CENTRE: CENTRE} | {ARM[i]: ARM[arm_of[i]] for i in range(3)}
    mapping |= {ARM_END[i]: ARM_END[arm_of[i]] for i in range(3)}
    return np.vectorize(mapping.get)(tags)


@pytest.mark.mpi
@pytest.mark.parametrize("order", [1, 2])
def test_nodes_cells_and_tags_are_invariant_under_the_symmetry_group(tripod, tripod_p2, order):
    """Each of the six maps sends the node set onto itself (to 1e-12 of the plate's size) and the cell set onto
    itself, each cell onto a cell with the image tag: the mesh is D3-invariant, not only the geometry."""
    nodes, cell_x, tags = gathered_mesh(tripod if order == 1 else tripod_p2)
    assert np.all(tags > 0)
    tol = 1e-12 * GEOMETRY.arm_length
    tree = cKDTree(nodes)
    distance, _ = tree.query(nodes, k=2)
    assert distance[:, 1].min() > 1e3 * tol  # nodes are distinct, so matching to tol is unambiguous

    def cell_rows(points):
        distance, index = tree.query(points.reshape(-1, 3))
        assert distance.max() <= tol
        return np.sort(index.reshape(len(points), -1), axis=1)

    def canonical(rows, values):
        order = np.lexsort(rows.T[::-1])
        return rows[order], values[order]

    reference = canonical(cell_rows(cell_x), tags)
    assert len(np.unique(reference[0], axis=0)) == len(tags)
    for g in symmetry_group():
        distance, index = tree.query(nodes @ g.T)
        assert distance.max() <= tol and np.unique(index).size == len(nodes)  # a permutation of the nodes
        image = canonical(cell_rows(cell_x @ g.T), image_tags(g, tags))
        np.testing.assert_array_equal(image[0], reference[0])
        np.testing.assert_array_equal(image[1], reference[1])


def cell_node_coordinates(tripod, tags):
    """Coordinates of the geometry nodes of the cells with the given tags (local, ghosts included)."""
    cells = np.concatenate([tripod.cell_tags.find(tag) for tag in tags])
    dofmap = tripod.mesh.geometry.dofmap
    nodes = np.unique(np.concatenate([dofmap.links(c) for c in cells])) if cells.size else np.array([], int)
    return tripod.mesh.geometry.x[nodes]


@pytest.mark.mpi
def test_regions_lie_in_their_radial_bands_and_angular_sectors(tripod):
    comm, eps = tripod.mesh.comm, 1e-9
    g = GEOMETRY
    bands = {RING: (g.hole_radius, g.ring_radius), CENTRE: (g.ring_radius, g.centre_radius)}
    bands |= {tag: (g.centre_radius, g.arm_end_radius) for tag in ARM}
    bands |= {tag: (g.arm_end_radius, math.hypot(g.arm_length, g.arm_width / 2)) for tag in ARM_END}
    for tag, (r_min, r_max) in bands.items():
        x = cell_node_coordinates(tripod, [tag])
        lo, hi = global_extremes(comm, np.hypot(x[:, 0], x[:, 1]))
        assert r_min - eps <= lo and hi <= r_max + eps, (tag, lo, hi)
    for i, e in enumerate(g.arm_directions()):
        for tag in (ARM[i], ARM_END[i]):
            x = cell_node_coordinates(tripod, [tag])
            # Across the arm: |x · n_i| ≤ w/2 with n_i the in-plane normal; along it: x · e_i > 0.
            lo, hi = global_extremes(comm, np.abs(x @ np.array([-e[1], e[0], 0.0])))
            assert hi <= g.arm_width / 2 + eps
            lo, hi = global_extremes(comm, x @ e)
            assert lo > 0 and hi <= g.arm_length + eps
    z_lo, z_hi = global_extremes(comm, tripod.mesh.geometry.x[:, 2])
    assert (z_lo, z_hi) == pytest.approx((-g.thickness / 2, g.thickness / 2), abs=eps)


@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_arm_end_dofs_are_the_nodes_beyond_the_cut(tripod, degree):
    V = dolfinx.fem.VectorFunctionSpace(tripod.mesh, ("CG", degree))
    x = V.tabulate_dof_coordinates()
    n_owned = V.dofmap.index_map.size_local
    R = GEOMETRY.arm_end_radius
    # Vertices lie on or beyond the cut; P2 edge midpoints of the cut's chords (length ≲ 2h) lie inside by at
    # most the sagitta (2h)²/(8R).
    r_min = R * (1 - 1e-9) if degree == 1 else R - (2 * PAPER_H) ** 2 / (8 * R)
    for i, e in enumerate(GEOMETRY.arm_directions()):
        dofs = tripod.arm_end_dofs(V, i)
        r = np.hypot(x[dofs, 0], x[dofs, 1])
        lo, _ = global_extremes(tripod.mesh.comm, r)
        assert lo >= r_min
        # All owned P2 nodes of the plate outside the circle r = 45 mm (+ margin) on arm i are carried.
        owned = np.arange(n_owned)
        beyond = owned[(np.hypot(x[owned, 0], x[owned, 1]) > GEOMETRY.arm_end_radius + 1e-4) & (x[owned] @ e > 0)]
        assert np.isin(beyond, dofs).all()


def test_fillets_add_their_analytic_area():
    g = TripodGeometry(fillet_radius=4e-3)
    assert g.area - GEOMETRY.area == pytest.approx(3 * 16e-6 * (1 / math.sqrt(3) - math.pi / 6), rel=1e-12)
    tripod = make_tripod(MPI.COMM_WORLD, PAPER_H, g, order=2)
    assert sum(region_volumes(tripod).values()) == pytest.approx(g.volume, rel=5e-5)


def test_servo_frames_lift_the_arm_ends_for_positive_angles():
    theta = math.radians(25.0)
    for frame, e in zip(GEOMETRY.servo_frames(), GEOMETRY.arm_directions()):
        np.testing.assert_allclose(frame.pivot, 0.06 * e, atol=1e-15)
        np.testing.assert_allclose(np.cross(e, frame.axis), [0, 0, 1], atol=1e-15)  # counter-clockwise tangent
        R = frame.rotation(theta)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
        np.testing.assert_allclose(R @ frame.axis, frame.axis, atol=1e-15)
        # X = p − s e_i (inside the servo circle) goes to p + s (−cos θ e_i + sin θ e_z).
        s = 0.01
        X = (frame.pivot - s * e)[:, None]
        x = X[:, 0] + frame.displacement(X, theta)[:, 0]
        np.testing.assert_allclose(x, frame.pivot + s * (-math.cos(theta) * e + math.sin(theta) * np.array([0, 0, 1])),
                                   atol=1e-15)
        assert frame.displacement(X, -theta)[2, 0] < 0 < frame.displacement(X, theta)[2, 0]
        np.testing.assert_allclose(frame.displacement(frame.pivot[:, None], theta), 0.0, atol=1e-15)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(thickness=-5e-3), "thickness must be a positive length"),
        (dict(ring_radius=18e-3), "ring_radius = 0.018 m is not < re-entrant corner radius"),
        (dict(hole_radius=12e-3), "hole_radius = 0.012 m is not < ring_radius"),
        (dict(arm_end_radius=60e-3), "arm_end_radius = 0.06 m is not < arm_length"),
        (dict(fillet_radius=9e-3), "fillet_radius = 0.009 m reaches r = "),
        (dict(fillet_radius=-1.0), "fillet_radius must be ≥ 0"),
    ],
)
def test_bad_geometry_is_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TripodGeometry(**kwargs)


def test_bad_mesh_arguments_are_rejected(tripod):
    with pytest.raises(ValueError, match="h = 0.02 m must be positive and at most twice the thickness"):
        make_tripod(MPI.COMM_WORLD, 0.02)
    with pytest.raises(ValueError, match="order must be"):
        make_tripod(MPI.COMM_WORLD, order=0)
    with pytest.raises(ValueError, match="unknown Tripod region 'hub'; valid regions: .*'centre'"):
        tripod.region_cells("hub")
    V = dolfinx.fem.VectorFunctionSpace(tripod.mesh, ("CG", 1))
    with pytest.raises(ValueError, match="servo must be 0, 1 or 2, got 3"):
        tripod.arm_end_dofs(V, 3)


# Layered plates (``layers = n``): the wedge's outline triangulated with size h and extruded in n layers of prisms,
# each split into three tetrahedra; and the straight arm-end cut (``arm_end_cut = "straight"``).
LAYERED_H = 0.010
STRAIGHT = TripodGeometry(arm_end_cut="straight")


@pytest.fixture(scope="module")
def layered():
    """n = 1 and n = 3 layers on the same outline (h = 10 mm), P1 and P2 geometry, and a straight-cut P2 plate."""
    return {(n, order): make_tripod(MPI.COMM_WORLD, LAYERED_H, order=order, layers=n)
            for n, order in ((1, 1), (3, 1), (3, 2))} | {
        ("straight", 2): make_tripod(MPI.COMM_WORLD, LAYERED_H, STRAIGHT, order=2, layers=2)}


@pytest.mark.mpi
@pytest.mark.parametrize("key", [(3, 1), (3, 2), ("straight", 2)])
def test_a_layered_plate_is_invariant_under_the_symmetry_group(layered, key):
    """The layered mesh is D3-invariant node for node and cell for cell (the mirror sides of the extruded wedge
    conform), for P1 and P2 geometry and for the straight arm-end cut."""
    test_nodes_cells_and_tags_are_invariant_under_the_symmetry_group(layered[key], layered[key], 1)


@pytest.mark.mpi
def test_a_layered_plate_has_its_layers_and_the_volume_of_its_outline(layered):
    """n layers: the nodes lie on the n + 1 planes z = −t/2 + k t/n, every tetrahedron spans exactly one layer, there
    are 3 n tetrahedra per outline triangle; the volume is the outline's area times the thickness whatever n (to
    round-off), and with curved (P2) arcs it is the plate's analytic volume to the quadrature of the arcs."""
    t = GEOMETRY.thickness
    one, three = layered[(1, 1)], layered[(3, 1)]
    assert three.n_cells == 3 * one.n_cells and one.n_cells % 18 == 0
    nodes, cell_x, _ = gathered_mesh(three)
    planes = -t / 2 + t * np.arange(4) / 3
    assert np.abs(nodes[:, 2][:, None] - planes).min(axis=1).max() < 1e-15
    span = np.ptp(cell_x[:, :, 2], axis=1)
    np.testing.assert_allclose(span, t / 3, rtol=1e-12)
    v1, v3 = sum(region_volumes(one).values()), sum(region_volumes(three).values())
    assert v3 == pytest.approx(v1, rel=1e-13)
    assert 0 < v1 / GEOMETRY.volume - 1 < 5e-3  # P1: the hole's and the cuts' arcs are chords
    assert sum(region_volumes(layered[(3, 2)]).values()) == pytest.approx(GEOMETRY.volume, rel=5e-5)


@pytest.mark.mpi
def test_a_straight_arm_end_cut_gives_exact_rectangular_arm_ends(layered):
    """``arm_end_cut = "straight"``: each arm end is the rectangle w × (L − R) × t, exactly (straight edges only), and
    lies beyond the line x · e_i = R; the whole plate keeps its analytic volume."""
    tripod = layered[("straight", 2)]
    volumes = region_volumes(tripod)
    assert STRAIGHT.arm_end_area == pytest.approx(0.030 * 0.010, rel=1e-15)
    for i, e in enumerate(STRAIGHT.arm_directions()):
        assert volumes[ARM_END[i]] == pytest.approx(STRAIGHT.arm_end_area * STRAIGHT.thickness, rel=1e-13)
        lo, _ = global_extremes(tripod.mesh.comm, cell_node_coordinates(tripod, [ARM_END[i]]) @ e)
        assert lo == pytest.approx(STRAIGHT.arm_end_radius, abs=1e-15)
    assert sum(volumes.values()) == pytest.approx(STRAIGHT.volume, rel=5e-5)


def test_bad_layers_and_cuts_are_rejected():
    with pytest.raises(ValueError, match=r"Tripod layers = -1 must be an integer ≥ 0"):
        make_tripod(MPI.COMM_WORLD, LAYERED_H, layers=-1)
    with pytest.raises(ValueError, match=r"Tripod layers = 1.5 must be an integer"):
        make_tripod(MPI.COMM_WORLD, LAYERED_H, layers=1.5)
    with pytest.raises(ValueError, match=r"arm_end_cut must be one of 'arc', 'straight', got 'square'"):
        TripodGeometry(arm_end_cut="square")
