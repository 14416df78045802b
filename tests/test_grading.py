"""fenicsfoam.grading: the vectorised foam table against SciPy and foam_material, its exact derivatives (Taylor),
point–triangle distances, blend weights against the analytic distance to a plane, zero-width blends."""

from types import SimpleNamespace

import dolfinx
import numpy as np
import pytest
from mpi4py import MPI
from scipy.interpolate import PchipInterpolator

from fenicsfoam.constitutive import MaterialField
from fenicsfoam.grading import (
    CellMaterials,
    FoamCells,
    blend_weights,
    interface_triangles,
    pchip,
    point_triangle_distance,
    smoothstep,
)
from fenicsfoam.materials import Isotropic, foam_material
from fenicsfoam.orientation import cell_values

LEFT, RIGHT = 1, 2


def rates(remainders):
    r = np.asarray(remainders)
    return np.log2(r[:-1] / r[1:])


def test_pchip_equals_scipy_and_its_derivatives_are_exact():
    rng = np.random.default_rng(0)
    x = np.sort(rng.uniform(0, 1, 7))
    y = np.array([0.0, 0.3, 0.2, 0.9, 1.4, 1.3, 2.0])  # sign changes of the slopes: the limiter acts
    t = np.concatenate([rng.uniform(x[0], x[-1], 40), x])
    value, d_t, _ = pchip(x, y, t)
    reference = PchipInterpolator(x, y)
    np.testing.assert_allclose(value, reference(t), rtol=0, atol=1e-14)
    np.testing.assert_allclose(d_t, reference.derivative()(t), rtol=0, atol=1e-12)
    # data tangent: Taylor remainder of the value along dy, rate 2 (slopes are rational in the data)
    dy = rng.normal(size=y.size)
    _, _, tangent = pchip(x, y, t, dy)
    remainders = [np.max(np.abs(pchip(x, y + h * dy, t)[0] - value - h * tangent)) for h in 1e-3 / 2.0 ** np.arange(4)]
    assert rates(remainders).min() > 1.9


@pytest.mark.parametrize("fit", ["transverse", "isotropic", "paper"])
def test_foam_cells_equal_foam_material_with_exact_derivatives(fit):
    rng = np.random.default_rng(1)
    density = np.concatenate([rng.uniform(0.09, 0.34, 12), [0.15, 0.30, 0.09, 0.34]])
    gamma = np.concatenate([np.exp(rng.uniform(np.log(0.1), 0.0, 12)), [1.0, 0.1, 0.3, 1.0]])
    if fit == "paper":  # the paper's fit is isotropic exactly at γ = 1: keep to one kind per call
        gamma[gamma == 1.0] = 0.5
    n = density.size
    cells = FoamCells("r", np.arange(n), density, gamma, 12e6, 0.3, 1190.0, fit)
    values, d_density, d_gamma = cells.moduli(isotropic=False, with_derivatives=True)
    for i in range(n):
        expected = foam_material(density[i], gamma[i], 12e6, 0.3, rho_solid=1190.0, fit=fit).spencer_moduli()
        for name, v in expected.items():
            assert values[name][i] == pytest.approx(v, rel=1e-11, abs=1e-6), (name, i)
    for derivative, key in ((d_density, "density"), (d_gamma, "gamma")):
        direction = np.where(rng.uniform(size=n) > 0.5, 1.0, -1.0) * (1e-3 if key == "density" else 1e-3 * gamma)
        inside = (density + direction > 0.09) & (density + direction < 0.34) if key == "density" else \
            (gamma + direction > 0.1) & (gamma + direction <= 1.0)
        direction = np.where(inside, direction, -direction)
        remainders = []
        for h in 1.0 / 2.0 ** np.arange(4):
            shifted = {"density": density, "gamma": gamma}
            shifted[key] = shifted[key] + h * direction
            moved = FoamCells("r", np.arange(n), shifted["density"], shifted["gamma"], 12e6, 0.3, 1190.0, fit)
            v, _, _ = moved.moduli(isotropic=False)
            remainders.append(max(np.max(np.abs(v[m] - values[m] - h * derivative[m] * direction)) for m in v))
        assert rates(remainders).min() > 1.8, (key, remainders)


def test_point_triangle_distance_in_every_region():
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    points = np.array([[0.2, 0.2, 0.5],     # above the face
                       [-1.0, -1.0, 0.0],   # vertex a
                       [2.0, -0.5, 1.0],    # vertex b
                       [-0.3, 2.0, 0.0],    # vertex c
                       [0.5, -2.0, 0.0],    # edge ab
                       [-2.0, 0.5, 0.0],    # edge ac
                       [1.0, 1.0, 1.0]])    # edge bc
    expected = [0.5, np.sqrt(2), np.sqrt(1 + 0.25 + 1), np.sqrt(0.09 + 1), 2.0, 2.0, np.sqrt(0.5 + 1)]
    np.testing.assert_allclose(point_triangle_distance(points, tri), expected, rtol=1e-14)
    assert np.all(np.isinf(point_triangle_distance(points, np.zeros((0, 3, 3)))))


def test_smoothstep():
    t = np.linspace(-1, 2, 31)
    s = smoothstep(t)
    assert s.min() == 0.0 and s.max() == 1.0 and np.all(np.diff(s) >= 0)
    assert smoothstep(np.array([0.5]))[0] == 0.5


@pytest.fixture(scope="module")
def split_box():
    """[−1, 1] × [0, 1] × [0, 0.5] in tetrahedra, tagged LEFT (x < 0) and RIGHT (x > 0): the interface is x = 0."""
    mesh = dolfinx.mesh.create_box(MPI.COMM_WORLD, [[-1, 0, 0], [1, 1, 0.5]], [8, 3, 2],
                                   dolfinx.mesh.CellType.tetrahedron)
    tdim = mesh.topology.dim
    n = mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts
    midpoints = dolfinx.mesh.compute_midpoints(mesh, tdim, np.arange(n, dtype=np.int32))
    tags = dolfinx.mesh.meshtags(mesh, tdim, np.arange(n, dtype=np.int32),
                                 np.where(midpoints[:, 0] < 0, LEFT, RIGHT).astype(np.int32))
    return mesh, tags


@pytest.mark.mpi
def test_blend_weights_follow_the_distance_to_the_interface(split_box):
    mesh, tags = split_box
    triangles = interface_triangles(mesh, tags, [LEFT], [RIGHT])
    # the plane x = 0 of 3 × 2 squares, two triangles each, found whole on every rank
    assert triangles.shape == (12, 3, 3) and np.allclose(triangles[:, :, 0], 0.0)
    n = mesh.topology.index_map(3).size_local
    x = dolfinx.mesh.compute_midpoints(mesh, 3, np.arange(n, dtype=np.int32))[:, 0]
    for width in (0.3, 0.8):
        np.testing.assert_allclose(blend_weights(mesh, tags, [LEFT], [RIGHT], width), smoothstep(0.5 + x / width),
                                   atol=1e-14)
    np.testing.assert_array_equal(blend_weights(mesh, tags, [LEFT], [RIGHT], 0.0), (x > 0).astype(float))
    with pytest.raises(ValueError, match="width"):
        blend_weights(mesh, tags, [LEFT], [RIGHT], -1.0)


def foam_region(name, tag, density, gamma, fit):
    return SimpleNamespace(name=name, tags=(tag,), material="foam",
                           parameters={"density": density, "gamma": gamma, "E_solid": 12e6, "nu_solid": 0.3,
                                       "rho_solid": 1190.0, "fit": fit, "table": None})


@pytest.mark.mpi
def test_a_zero_width_blend_is_the_sharp_field_and_a_wide_one_is_between(split_box):
    mesh, tags = split_box
    regions = [foam_region("left", LEFT, 0.30, 0.1, "transverse"), foam_region("right", RIGHT, 0.15, 1.0, "transverse")]
    sharp = MaterialField.from_regions(mesh, tags, {
        LEFT: foam_material(0.30, 0.1, 12e6, 0.3, rho_solid=1190.0), RIGHT: foam_material(0.15, 1.0, 12e6, 0.3,
                                                                                          rho_solid=1190.0)})
    zero = CellMaterials.from_regions(mesh, tags, regions, blends=[{"regions": ("left", "right"), "width": 0.0}])
    field = zero.material_field(mesh)
    for name in sharp.moduli:
        np.testing.assert_allclose(cell_values(field.moduli[name]), cell_values(sharp.moduli[name]), rtol=1e-11)
    np.testing.assert_allclose(cell_values(field.rho), cell_values(sharp.rho), rtol=1e-14)
    wide = CellMaterials.from_regions(mesh, tags, regions, blends=[{"regions": ("left", "right"), "width": 0.8}])
    density = np.full(mesh.topology.index_map(3).size_local, np.nan)
    for foam in wide.foams.values():
        density[foam.cells] = foam.density
    assert np.all((density >= 0.15) & (density <= 0.30)) and np.any((density > 0.16) & (density < 0.29))
    # region-value derivatives: the shares (1 − β, β) sum to one on every cell
    np.testing.assert_allclose(wide.region_derivative("density", "left") + wide.region_derivative("density", "right"),
                               1.0, rtol=1e-14)


def test_blends_are_refused_between_non_foam_or_field_regions(split_box):
    mesh, tags = split_box
    solid = SimpleNamespace(name="solid", tags=(RIGHT,), material="isotropic", parameters={"E": 1e6, "nu": 0.3})
    foam = foam_region("left", LEFT, 0.3, 0.1, "transverse")
    with pytest.raises(ValueError, match="'solid' is not a foam region"):
        CellMaterials.from_regions(mesh, tags, [foam, solid], blends=[{"regions": ("left", "solid"), "width": 0.1}])
    cells = CellMaterials.from_regions(mesh, tags, [foam, solid])
    assert not cells.isotropic and isinstance(cells.fixed["solid"][1], Isotropic)
    with pytest.raises(ValueError, match="density:solid"):
        cells.region_derivative("density", "solid")
