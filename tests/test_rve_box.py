"""Non-cubic periodic RVE boxes end to end: foam → voxels / conforming mesh → FFT and FEM homogenization.

Checks: exact closed forms in a box (FEM laminates and a homogeneous box on the box's voxel mesh), equivariance
(a foam and its axis-permuted image give the Voigt-permuted C, by FFT and by FEM on the conforming mesh), periodic
seams (shifting the seeds by whole voxels rolls the voxel image; the conforming mesh matches node for node on
opposite faces of the box) and the two-way FFT ↔ FEM agreement on a non-cubic box.
"""

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI
from test_fem_rve import C_ISO, C_TI, EXACT, laminate, rel_err

from homogenization.fem import homogenize_fem
from homogenization.fft import homogenize_fft
from homogenization.tensors import VOIGT_PAIRS, isotropic_voigt
from meshes.foam import FoamParameterError, VoronoiFoam, mesh_rve
from meshes.rve import FACE_TAGS
from meshes.rve import SOLID as RVE_SOLID
from meshes.rve import VOID as RVE_VOID
from meshes.voxel import voxel_mesh

SOLID_C = isotropic_voigt(1.0, 0.3)
VOID_C = np.zeros((6, 6))
BOX = (0.6, 1.0, 0.8)            # cubic voxels of 0.2 / 0.1 / … on grids (3, 5, 4) · k
PERM = (2, 0, 1)                 # new axis a is old axis PERM[a]


def _corners(box):
    return ((0.0, 0.0, 0.0), tuple(box))


def _voigt_permutation(perm) -> np.ndarray:
    """Matrix P with C_new = P C_old Pᵀ when new axis a is old axis perm[a] (Voigt, engineering shear)."""
    P = np.zeros((6, 6))
    for I, (i, j) in enumerate(VOIGT_PAIRS):
        pair = {perm[i], perm[j]}
        J = next(J for J, (k, m) in enumerate(VOIGT_PAIRS) if {k, m} == pair)
        P[I, J] = 1.0
    return P


# --------------------------------------------------------------------------------------------------
# Closed forms in a box (FEM on the box's structured voxel mesh)
# --------------------------------------------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_fem_laminate_in_a_box_matches_the_closed_form(axis):
    shape = (3, 5, 4)
    image = np.zeros(shape, dtype=np.int8)
    index = [slice(None)] * 3
    index[axis] = slice(0, 1)                      # one voxel layer of solid: fraction 1/N_axis
    image[tuple(index)] = 1
    msh, tags = voxel_mesh(image, MPI.COMM_WORLD, box=(0.6, 1.0, 0.8))
    r = homogenize_fem(msh, tags, {1: C_TI, 2: C_ISO}, box=_corners((0.6, 1.0, 0.8)))
    f = 1.0 / shape[axis]
    assert rel_err(r.C, laminate([C_TI, C_ISO], [f, 1 - f], axis)) < EXACT
    assert r.info["volume_fractions"] == {1: pytest.approx(f), 2: pytest.approx(1 - f)}


def test_fem_homogeneous_box_returns_the_material():
    msh, tags = voxel_mesh(np.ones((3, 5, 4), dtype=np.int8), MPI.COMM_WORLD, box=BOX)
    r = homogenize_fem(msh, tags, {1: C_TI}, box=_corners(BOX))
    assert rel_err(r.C, C_TI) < EXACT


def test_a_box_mesh_must_match_the_box_given_to_fem():
    msh, tags = voxel_mesh(np.ones((6, 5, 4), dtype=np.int8), MPI.COMM_WORLD, box=(1.2, 1.0, 0.8))
    with pytest.raises(ValueError, match="outside the periodic box"):
        homogenize_fem(msh, tags, {1: C_ISO})


# --------------------------------------------------------------------------------------------------
# Foams in a box
# --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def foam():
    """4 cells at 30 % in the box (0.6, 1, 0.8): thick struts, cheap to mesh and to homogenize."""
    return VoronoiFoam(4, 0.3, 1.0, seed=2, box=BOX)


@pytest.fixture(scope="module")
def permuted(foam):
    box = tuple(BOX[p] for p in PERM)
    return VoronoiFoam.from_seeds(foam.seeds[:, list(PERM)], 0.3, 1.0, box=box)


def test_box_foam_grid_and_density(foam):
    assert foam.grid_shape(10) == (6, 10, 8)
    img = foam.voxelize(40)
    assert img.shape == (24, 40, 32)
    assert abs(img.mean() - 0.3) < 0.002
    assert np.all(foam.seeds < np.array(BOX)) and np.all(foam.seeds >= 0)
    with pytest.raises(FoamParameterError, match=r"N=12 does not give cubic voxels in the box"):
        foam.voxelize(12)
    with pytest.raises(FoamParameterError, match=r"non-cubic voxels"):
        foam.voxelize((6, 10, 10))


def test_equiaxed_box_follows_the_cells():
    f = VoronoiFoam(8, 0.18, 0.1, seed=0, box="equiaxed")
    assert tuple(f.box) == (0.1, 1.0, 1.0) and f.grid_shape(40) == (4, 40, 40)
    with pytest.raises(FoamParameterError, match=r"box must be None, 'equiaxed' or three positive lengths"):
        VoronoiFoam(8, 0.18, 0.1, box="cube")
    with pytest.raises(FoamParameterError, match=r"box must be three positive finite lengths.*-1"):
        VoronoiFoam(8, 0.18, 1.0, box=(1.0, -1.0, 1.0))


def test_shifting_the_seeds_by_whole_voxels_rolls_the_voxel_image(foam):
    """Periodic seams of the voxel image: no voxel row at a box face differs from the interior."""
    N = 20
    h = foam.box[0] / foam.grid_shape(N)[0]
    k = np.array([2, 5, 3])
    shifted = VoronoiFoam.from_seeds(np.mod(foam.seeds + k * h, foam.box), 0.3, 1.0, box=BOX)
    a, b = foam.voxelize(N), shifted.voxelize(N)
    assert np.count_nonzero(np.roll(a, tuple(k), axis=(0, 1, 2)) != b) <= 2   # ties at the level of round-off


def test_axis_permuted_foam_gives_the_transposed_image_and_permuted_fft_stiffness(foam, permuted):
    a, b = foam.voxelize(20), permuted.voxelize(20)
    assert b.shape == tuple(a.shape[p] for p in PERM)
    assert np.count_nonzero(np.transpose(a, PERM) != b) <= 2
    C = [homogenize_fft(img.astype(np.int8), [VOID_C, SOLID_C], tol=1e-8, threads=1, box=f.box).C
         for img, f in ((a, foam), (np.transpose(a, PERM), permuted))]
    P = _voigt_permutation(PERM)
    assert rel_err(C[1], P @ C[0] @ P.T) < 1e-6
    assert rel_err(C[0], C[0].T) < 1e-10


def _face_points(msh, axis: int, value: float) -> np.ndarray:
    x = msh.geometry.x
    local = x[np.abs(x[:, axis] - value) < 1e-12]
    points = np.concatenate(msh.comm.allgather(local))
    points[:, axis] = 0.0
    return np.unique(np.round(points, 12), axis=0)


@pytest.mark.mpi
def test_conforming_box_mesh_is_periodic_and_fills_the_box(foam):
    rve = mesh_rve(foam, 0.1, MPI.COMM_WORLD)
    assert rve.box == BOX
    for axis in range(3):
        lower, upper = _face_points(rve.mesh, axis, 0.0), _face_points(rve.mesh, axis, BOX[axis])
        assert len(lower) > 20 and np.array_equal(lower, upper)
    one = dolfinx.fem.Constant(rve.mesh, 1.0)
    total = rve.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ufl.dx)), op=MPI.SUM)
    assert total == pytest.approx(np.prod(BOX), rel=1e-12)
    ds = ufl.Measure("ds", domain=rve.mesh, subdomain_data=rve.facet_tags)
    for name, tag in FACE_TAGS.items():
        axis = "xyz".index(name[0])
        area = np.prod([BOX[a] for a in range(3) if a != axis])
        assert rve.mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(one * ds(tag))),
                                       op=MPI.SUM) == pytest.approx(area, rel=1e-12), name


def test_axis_permuted_foam_gives_the_permuted_fem_stiffness(foam, permuted):
    """The Kuhn background mesh is invariant under axis permutations, but the diagonals of the cut prisms and
    pyramids follow the periodic vertex ranks, which depend on the axis order: the two conforming meshes differ
    in those diagonals only, and the FEM stiffnesses by a discretization difference (measured 1.4e-3)."""
    materials = {RVE_SOLID: SOLID_C, RVE_VOID: VOID_C}
    C = []
    for f in (foam, permuted):
        rve = mesh_rve(f, 0.1, MPI.COMM_SELF)
        C.append(homogenize_fem(rve.mesh, rve.cell_tags, materials, comm=MPI.COMM_SELF,
                                box=_corners(f.box)).C)
    P = _voigt_permutation(PERM)
    assert rel_err(C[1], P @ C[0] @ P.T) < 5e-3
    assert rel_err(C[1], C[0]) > 0.05              # …while the unpermuted stiffnesses differ


def test_fem_and_fft_approach_each_other_in_a_non_cubic_box():
    """FEM P1 on the conforming mesh (stiff, softens as h → 0) and FFT on voxels (soft, stiffens as N grows) of a
    γ = 0.5 foam in its equiaxed box (0.5, 1, 1) (4 cells, 30 %, strut radius 0.074). Measured diagonal of C:
    FEM h = 1/12: 0.0530, 0.131, 0.173, 0.0487, 0.0334, 0.0243; h = 1/20: 0.0416, 0.122, 0.161, 0.0432, 0.0292,
    0.0207; FFT N = 24: 0.0234, 0.0902, 0.117, 0.0272, 0.0179, 0.0122; N = 48: 0.0256, 0.0990, 0.125, 0.0309,
    0.0197, 0.0143 — the two discretizations bracket the foam and close in (relative gap 0.36 → 0.27)."""
    foam = VoronoiFoam(4, 0.3, 0.5, seed=1, box="equiaxed")
    fem = []
    for h in (1 / 12, 1 / 20):
        rve = mesh_rve(foam, h, MPI.COMM_SELF)
        fem.append(homogenize_fem(rve.mesh, rve.cell_tags, {RVE_SOLID: SOLID_C, RVE_VOID: VOID_C},
                                  comm=MPI.COMM_SELF, box=_corners(foam.box)).C)
    fft = [homogenize_fft(foam.voxelize(n).astype(np.int8), [VOID_C, SOLID_C], tol=1e-5, threads=1, maxiter=4000,
                          box=foam.box).C for n in (24, 48)]
    d_fem, d_fft = [np.diag(C) for C in fem], [np.diag(C) for C in fft]
    assert np.all(d_fem[1] < d_fem[0]) and np.all(d_fft[1] > d_fft[0])
    assert np.all(d_fft[1] < d_fem[1])
    gap = [np.linalg.norm(fem[i] - fft[i]) / np.linalg.norm(fem[i]) for i in (0, 1)]
    assert gap[1] < gap[0] < 0.5
    # the same image read as a unit cube (non-cubic voxels) is another material
    wrong = homogenize_fft(foam.voxelize(24).astype(np.int8), [VOID_C, SOLID_C], tol=1e-5, threads=1,
                           maxiter=4000).C
    assert rel_err(wrong, fft[0]) > 0.2


# --------------------------------------------------------------------------------------------------
# Non-cubic voxels (an explicit opt-in: voxelize(shape, cubic=False))
# --------------------------------------------------------------------------------------------------
def test_non_cubic_grid_samples_the_cubic_grid_at_its_voxel_centres(foam):
    """Voxels three times as long along z as the cubic grid (18, 30, 24) have their centres at every third cubic
    centre along z, starting at the second: the two images agree there exactly."""
    cubic = foam.voxelize(30)
    assert cubic.shape == (18, 30, 24)
    coarse = foam.voxelize((18, 30, 8), cubic=False)
    assert coarse.shape == (18, 30, 8) and foam.grid_shape((18, 30, 8), cubic=False) == (18, 30, 8)
    assert np.array_equal(coarse, cubic[:, :, 1::3])
    assert not np.array_equal(coarse, cubic[:, :, 0::3])  # the test can fail: the centres matter


def test_non_cubic_grid_holds_the_density_and_is_deterministic(foam):
    shape = (48, 80, 32)                   # voxels 0.0125 × 0.0125 × 0.025
    img = foam.voxelize(shape, cubic=False)
    assert abs(img.mean() - 0.3) < 0.002
    again = VoronoiFoam(4, 0.3, 1.0, seed=2, box=BOX).voxelize(shape, cubic=False)
    assert np.array_equal(img, again)


def test_non_cubic_grid_is_an_explicit_opt_in(foam):
    with pytest.raises(FoamParameterError, match=r"N = \(48, 80, 32\) gives non-cubic voxels .* cubic=False"):
        foam.voxelize((48, 80, 32))
    with pytest.raises(FoamParameterError, match=r"cubic=False needs the grid as three integers .* N=40"):
        foam.voxelize(40, cubic=False)
    with pytest.raises(FoamParameterError, match=r"N must be an integer or three integers .*\(6, 10\)"):
        foam.voxelize((6, 10), cubic=False)
    with pytest.raises(FoamParameterError, match=r"N must be an integer ≥ 2, got 1"):
        foam.voxelize((6, 1, 10), cubic=False)

