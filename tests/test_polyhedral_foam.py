"""The polyhedral (gauge) Voronoi wall foam: polytope, exact wall distance, density, determinism, periodicity.

Cross-checks: the in-layer wall distance against a brute-force search along horizontal rays (the cell changes
where a wall is crossed), the compiled kernel against the numpy implementation, the sampled density against an
independent voxel count and the STL's enclosed volume, the foam of shifted seeds against the shifted foam, and
the printable-overhang property of the default polytope against every wall normal the foam actually has.
"""

import numpy as np
import pytest
from mpi4py import MPI

from meshes.foam import FoamParameterError, VoronoiFoam, mesh_rve
from meshes.gauge import GaugeWalls, Polytope, PolytopeError, default_polytope, pyramid

DENSITY_TOL = 0.002


@pytest.fixture(scope="module")
def foam():
    """6 cells at 25 % in the equiaxed box of γ = 0.5 (0.5, 1, 1)."""
    return VoronoiFoam(6, 0.25, 0.5, seed=1, box="equiaxed", distance="polyhedral")


# --------------------------------------------------------------------------------------------------
# The polytope
# --------------------------------------------------------------------------------------------------
def test_default_polytope_is_the_hexagonal_pyramid_with_unit_gauge_on_its_vertices():
    P = default_polytope()
    V = P.vertices()
    assert len(V) == 7
    assert np.allclose(P.gauge(V), 1.0)                       # the vertices are on the unit sphere of the gauge
    assert np.allclose(sorted(V[:, 2])[-1], 1.0) and np.allclose(sorted(V[:, 2])[0], -1.0)   # apex 1, base −1
    base = V[V[:, 2] < 0]
    assert np.allclose(np.linalg.norm(base[:, :2], axis=1), 2 / np.sqrt(3))   # inradius 1 hexagon
    assert base[:, 0].max() == pytest.approx(2 / np.sqrt(3))                # a vertex on +x, sides normal to ±y
    assert np.abs(base[:, 1]).max() == pytest.approx(1.0)


@pytest.mark.parametrize("gamma", [1.0, 0.5, 0.3, 0.1])
def test_every_wall_of_the_default_polytope_is_printable(gamma):
    """45° overhang bound: every wall normal ν_a − ν_b has |n_z| ≤ |n_xy|; shrinking along x only steepens."""
    P = default_polytope()
    assert P.max_overhang_deg(gamma) <= 45.0 + 1e-9
    assert P.max_overhang_deg(1.0) == pytest.approx(45.0)
    # a bipyramid has two downward faces: two sites on a vertical line meet on a horizontal wall
    bipyramid = Polytope(np.vstack([pyramid(6).normals[:6], np.array(pyramid(6).normals[:6]) * [1, 1, -1]]))
    assert bipyramid.max_overhang_deg() == pytest.approx(90.0)


def test_gauge_is_positively_homogeneous_and_asymmetric():
    P = default_polytope()
    v = np.random.default_rng(0).normal(size=(50, 3))
    assert np.allclose(P.gauge(3.0 * v), 3.0 * P.gauge(v))
    assert np.allclose(P.gauge(v * [0.5, 1, 1], gamma=0.5), P.gauge(v))      # shrunk by γ along x
    assert P.gauge(np.array([0.0, 0.0, 1.0])) == pytest.approx(1.0)         # apex 1 above the site
    assert P.gauge(np.array([0.0, 0.0, -0.5])) == pytest.approx(0.5)        # base 1 below


@pytest.mark.parametrize(("normals", "offsets", "match"), [
    (np.eye(3), None, r"K ≥ 4"),
    (np.vstack([np.eye(3), [[1.0, 1.0, 1.0]]]), None, r"unbounded along -x"),
    (np.vstack([np.eye(3), -np.eye(3)]), [1, 1, 1, 1, 1, -1], r"offsets must be 6 positive numbers"),
    (np.vstack([np.eye(3), -np.eye(3), [[0.0, 0.0, 0.0]]]), None, r"face normal 6 is the zero vector"),
])
def test_bad_polytopes_raise_clear_errors(normals, offsets, match):
    with pytest.raises(PolytopeError, match=match):
        Polytope(normals, offsets)


def test_polytope_errors_are_foam_parameter_errors():
    with pytest.raises(FoamParameterError, match=r"k must be an integer ≥ 3"):
        pyramid(2)


# --------------------------------------------------------------------------------------------------
# The wall distance
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("gamma", [1.0, 0.1])
def test_wall_distance_matches_a_brute_force_ray_search(gamma):
    """ψ(x) = the distance, within the horizontal layer of x, to the boundary of the cell containing x: along 360
    horizontal rays, the first step at which another site image becomes the gauge-nearest."""
    box = np.array([gamma, 1.0, 1.0])
    P = default_polytope()
    walls = GaugeWalls(np.random.default_rng(1).random((8, 3)) * box, box, P, gamma)
    x = np.random.default_rng(2).random((3000, 3)) * box
    upper = 0.02 * np.sqrt(gamma)
    psi, foot, _, normal = walls.evaluate(x, upper=upper, details=True)
    sel = np.flatnonzero(psi <= upper)[:20]
    assert len(sel) == 20
    nu, images = P.deformed(gamma), walls.images

    def nearest(points):
        """Index of the gauge-nearest site image (checked: no image beyond the 32 Euclidean nearest can win)."""
        e, idx = walls.tree.query(points * walls.stretch, k=32)
        d = np.max((points[:, None, :] - images[idx]) @ nu.T, axis=-1)
        assert np.all(e[:, -1] / walls.R >= d.min(axis=1))
        return idx[np.arange(len(points)), np.argmin(d, axis=1)]

    steps = 100
    step = 1.5 * upper / steps
    angles = np.linspace(0, 2 * np.pi, 361)[:-1]
    u = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    t = np.arange(1, steps + 1) * step
    for i in sel:
        start = nearest(x[i:i + 1])[0]
        rays = (x[i] + t[None, :, None] * u[:, None, :]).reshape(-1, 3)
        changed = (nearest(rays) != start).reshape(len(angles), steps)
        first = np.where(changed.any(axis=1), t[np.argmax(changed, axis=1)], np.inf)
        best = first.min()
        # within one step and the 1° direction sampling (chord error ψ (1/cos ½° − 1) = 4e-5 ψ at a plane wall, more
        # at a sharp corner of the in-layer polyline)
        assert -1e-12 < best - psi[i] < step + 1e-3 * psi[i], (i, best, psi[i], step)
    assert np.allclose(np.linalg.norm((x[sel] - foot[sel])[:, :2], axis=1), psi[sel])
    assert np.all(foot[sel][:, 2] == x[sel][:, 2])
    assert np.allclose(np.linalg.norm(normal[sel], axis=1), 1.0)
    # the foot is on the wall: the two nearest gauge distances are equal there
    d = np.sort(np.max((foot[sel][:, None, :] - images[None]) @ nu.T, axis=-1), axis=1)
    assert np.allclose(d[:, 0], d[:, 1], rtol=0, atol=1e-12)


def test_compiled_kernel_matches_numpy():
    box = np.array([0.5, 1.0, 1.0])
    walls = GaugeWalls(np.random.default_rng(3).random((8, 3)) * box, box, default_polytope(), 0.5)
    if walls._native is None:
        pytest.skip("no C compiler")
    x = np.random.default_rng(4).random((4000, 3)) * box
    a = walls.evaluate(x, upper=0.02, details=True)
    walls._native = None
    b = walls.evaluate(x, upper=0.02, details=True)
    inside = (a[0] <= 0.02) | (b[0] <= 0.02)
    assert np.array_equal(a[0] <= 0.02, b[0] <= 0.02)
    assert np.allclose(a[0][inside], b[0][inside], rtol=0, atol=1e-13)
    assert np.allclose(a[1][inside], b[1][inside], rtol=0, atol=1e-13)
    assert np.array_equal(a[2], b[2])


# --------------------------------------------------------------------------------------------------
# The foam
# --------------------------------------------------------------------------------------------------
def test_density_matches_an_independent_voxel_count(foam):
    assert foam.strut == "wall" and foam.polytope == default_polytope()
    assert abs(foam.measured_density - 0.25) < 1e-4 and 0 < foam.density_stderr < 5e-4
    img = foam.voxelize(120)
    assert img.shape == (60, 120, 120)
    assert abs(img.mean() - 0.25) < DENSITY_TOL


def test_same_seed_is_bitwise_identical_and_other_seeds_differ(foam):
    again = VoronoiFoam(6, 0.25, 0.5, seed=1, box="equiaxed", distance="polyhedral")
    assert again.radius == foam.radius
    assert np.array_equal(again.voxelize(40), foam.voxelize(40))
    other = VoronoiFoam(6, 0.25, 0.5, seed=2, box="equiaxed", distance="polyhedral")
    assert np.count_nonzero(other.voxelize(40) != foam.voxelize(40)) > 0.05 * 20 * 40 * 40


def test_shifted_seeds_give_the_shifted_wall_field(foam):
    shift = np.array([0.17, 0.61, 0.33])
    shifted = VoronoiFoam.from_seeds(np.mod(foam.seeds + shift, foam.box), 0.25, 0.5, box="equiaxed",
                                     distance="polyhedral")
    x = np.random.default_rng(0).random((3000, 3)) * foam.box
    a, b = foam.distance(x, upper=0.05), shifted.distance(x + shift, upper=0.05)
    near = (a <= 0.05) | (b <= 0.05)
    assert np.array_equal(a <= 0.05, b <= 0.05)
    assert np.allclose(a[near], b[near], rtol=0, atol=1e-12)


def test_wall_statistics_follow_gamma_and_stay_printable(foam):
    s = foam.summary
    assert s.n_struts == 0 and np.isnan(s.mean_strut_length)
    assert s.max_overhang_deg <= 45.0 + 1e-9
    assert np.trace(np.array(s.fabric)) == pytest.approx(1.0)
    # γ = 0.5 flattens the cells along x: walls turn their normals to x, so less material runs along x
    assert s.mean_abs_cos[0] > max(s.mean_abs_cos[1:]) and s.fabric[0][0] < 1 / 3
    edges, weights = foam.orientation_histogram(90)
    centres = np.radians(0.5 * (edges[1:] + edges[:-1]))
    assert weights.sum() == pytest.approx(1.0)
    assert np.sum(weights * np.cos(centres)) == pytest.approx(s.mean_abs_cos[0], abs=0.01)   # same statistic
    # the measured wall normals are among the polytope's: no wall is steeper than the polytope allows
    x = np.random.default_rng(1).random((20000, 3)) * foam.box
    psi, _, _, n = foam._distance.evaluate(x, upper=foam.radius, details=True)
    n = n[psi <= foam.radius]
    assert np.all(np.abs(n[:, 2]) <= np.linalg.norm(n[:, :2], axis=1) + 1e-12)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"distance": "manhattan"}, r"distance must be one of \('euclidean', 'polyhedral'\) or a meshes.gauge.Polytope"),
    ({"distance": "polyhedral", "strut": "cylinder"}, r"strut='cylinder' with distance='polyhedral' is not "
                                                       r"implemented"),
    ({"strut": "wall"}, r"strut='wall' with distance='euclidean' is not implemented"),
    ({"distance": "polyhedral", "density": 0.7}, r"density 0\.7 is outside the valid range \[0\.\d+, 0\.5000\]"),
    ({"distance": "polyhedral", "density": 0.001}, r"density 0\.001 is outside the valid range"),
    ({"distance": "polyhedral", "gamma": 0.0}, r"gamma must be in \(0, 1\].*0\.0"),
])
def test_invalid_parameters_raise_clear_errors(kwargs, match):
    args = {"n_cells": 4, "density": 0.25, "gamma": 1.0, "seed": 0} | kwargs
    with pytest.raises(FoamParameterError, match=match):
        VoronoiFoam(**args)


def test_stl_encloses_the_wall_volume(foam, tmp_path):
    meshio = pytest.importorskip("meshio")
    path = foam.to_stl(tmp_path / "walls.stl", 60)
    mesh = meshio.read(path)
    tri = mesh.points[mesh.cells_dict["triangle"]]
    _, ids = np.unique(np.round(tri.reshape(-1, 3), 9), axis=0, return_inverse=True)
    ids = ids.reshape(-1, 3)
    edges = np.sort(np.concatenate([ids[:, [0, 1]], ids[:, [1, 2]], ids[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert np.all(count == 2)
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    assert volume / np.prod(foam.box) == pytest.approx(0.25, abs=0.02)


@pytest.mark.slow
def test_conforming_mesh_of_the_walls_holds_the_density(foam):
    import dolfinx
    import ufl

    rve = mesh_rve(foam, foam.radius, MPI.COMM_WORLD)
    dx = ufl.Measure("dx", domain=rve.mesh, subdomain_data=rve.cell_tags)
    one = dolfinx.fem.Constant(rve.mesh, 1.0)
    solid = rve.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * dx(1))), op=MPI.SUM)
    assert solid / np.prod(foam.box) == pytest.approx(0.25, abs=0.02)
