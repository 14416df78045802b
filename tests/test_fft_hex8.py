"""FFT homogenization with fully integrated trilinear voxels (``discretization="hex8"``): closed forms, the
assembled stiffness and its Green operator, cross-checks with the rotated scheme and the voxel FEM, MPI."""

import numpy as np
import pytest
from test_fft import C_SOFT, TI, laminate, layered_image, rel, sphere_image, world

from foambase.errors import InputError
from homogenization import _nodal
from homogenization.fft import homogenize_fft
from homogenization.tensors import isotropic_voigt, voigt_to_mandel

VOID = np.zeros((6, 6))


@pytest.fixture(autouse=True)
def one_thread(monkeypatch):
    monkeypatch.setattr("homogenization.fft.cpu_count", lambda: 1)


def gauss_b_matrices(h):
    """6×24 Mandel strain matrices at the 2×2×2 Gauss points, written out independently of ``_nodal``."""
    g = 0.5 / np.sqrt(3.0)
    out = []
    for point in np.ndindex(2, 2, 2):
        t = [0.5 + (g if s else -g) for s in point]
        B = np.zeros((6, 24))
        for n, corner in enumerate(np.ndindex(2, 2, 2)):
            shape = [t[d] if corner[d] else 1 - t[d] for d in range(3)]
            grad = [(1 if corner[d] else -1) / h[d] * np.prod([shape[e] for e in range(3) if e != d])
                    for d in range(3)]
            for c in range(3):
                G = np.zeros((3, 3))
                G[c] = grad
                B[:, 3 * n + c] = [G[a, a] if a == d else (G[a, d] + G[d, a]) / np.sqrt(2)
                                   for a, d in [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]]
        out.append(B)
    return out


def assembled(img, materials, h):
    """The periodic hex8 stiffness (sparse, 3 dofs per node, node index = voxel index of its lower corner)."""
    import scipy.sparse as sparse

    shape = img.shape
    Bs = gauss_b_matrices(h)
    index = np.arange(img.size).reshape(shape)
    rows, cols, vals = [], [], []
    for v in np.ndindex(*shape):
        dofs = [3 * index[tuple((np.array(v) + corner) % shape)] + c for corner in np.ndindex(2, 2, 2)
                for c in range(3)]
        ke = h.prod() * sum(B.T @ materials[img[v]] @ B for B in Bs) / 8
        rows += np.repeat(dofs, 24).tolist()
        cols += np.tile(dofs, 24).tolist()
        vals += ke.ravel().tolist()
    return sparse.coo_matrix((vals, (rows, cols)), shape=(3 * img.size,) * 2).tocsr()


# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("n,stiff", [(8, isotropic_voigt(10.0, 0.2)), (7, isotropic_voigt(1000.0, 0.2)), (8, TI)],
                         ids=["contrast10", "contrast1000-odd", "rotated-TI"])
def test_laminate_is_exact(axis, n, stiff):
    """Layers of voxels: the exact solution is piecewise linear across the layers, which trilinear voxels hold."""
    r = homogenize_fft(layered_image(n, axis, 3), [C_SOFT, stiff], discretization="hex8", tol=1e-10)
    assert rel(r.C, laminate([C_SOFT, stiff], [1 - 3 / n, 3 / n], axis)) < 1e-10  # measured 3e-16 … 8e-16
    assert r.asymmetry < 1e-10


@pytest.mark.parametrize("axis", [0, 2])
def test_void_laminate_limit(axis):
    """Solid plates separated by void layers: only the in-plane plane-stress stiffness, times the solid fraction,
    survives; the finite-contrast laminate tends to it (contrast 1e-8 here) and the zero void gives it."""
    img = layered_image(8, axis, 5)  # 5 solid layers, 3 void
    solid = TI
    r = homogenize_fft(img, [VOID, solid], discretization="hex8", tol=1e-10, allow_singular=True)  # no stiffness across
    near = laminate([1e-8 * C_SOFT, solid], [3 / 8, 5 / 8], axis)
    assert rel(r.C, near) < 1e-6
    from test_fft import NORMAL_COMPONENTS

    normal = NORMAL_COMPONENTS[axis]
    assert np.abs(r.C[normal]).max() < 1e-12  # no stiffness across the void layers
    plane = [i for i in range(6) if i not in normal]
    S = np.linalg.inv(solid)[np.ix_(plane, plane)]  # plane stress: the in-plane compliance of the solid
    assert rel(r.C[np.ix_(plane, plane)], 5 / 8 * np.linalg.inv(S)) < 1e-10


def test_stencil_and_green_operator_are_the_assembled_hexahedron_stiffness():
    """``K p`` of the C kernel (and of the numpy kernel) equals the assembled 2×2×2-Gauss stiffness on a non-cubic
    box with a void, an isotropic and a rotated TI phase, odd and even axes; constants (rigid translations) are in
    its kernel; and the Fourier preconditioner inverts the same assembly for the Mandel identity as material."""
    shape, box = (5, 6, 4), (0.5, 0.9, 0.3)
    h = np.array(box) / np.array(shape)
    img = np.random.default_rng(4).integers(0, 3, shape)
    materials = {0: VOID, 1: voigt_to_mandel(C_SOFT), 2: voigt_to_mandel(TI)}
    K = assembled(img, materials, h)
    u = np.random.default_rng(5).random((3,) + shape)
    expected = (K @ u.transpose(1, 2, 3, 0).ravel()).reshape(shape + (3,)).transpose(3, 0, 1, 2) / h.prod()

    for native in (True, False):
        ws = _nodal.Hex8Workspace(img, _nodal.stiffness_tables(materials), shape, box, 1, False)
        if not native:
            ws.native = None
        elif ws.native is None:
            continue
        ws.p[:, 1:-1] = u
        ws.fill_ghosts(ws.p)
        energy, _ = ws.apply(True, None)
        assert np.abs(ws.q - expected).max() < 1e-12 * np.abs(expected).max()
        assert energy == pytest.approx(float(np.vdot(u, expected)), rel=1e-12)
        ws.p[...] = 0.7  # a rigid translation: no force, no energy
        e0, _ = ws.apply(True, None)
        assert np.abs(ws.q).max() < 1e-12 * np.abs(expected).max() and abs(e0) < 1e-10 * energy
        # the Green operator: K_I (identity material) applied to K_I⁻¹ r gives r back, for r of zero mean
        KI = assembled(np.zeros(shape, int), {0: np.eye(6)}, h) / h.prod()
        r = np.random.default_rng(6).random((3,) + shape)
        r -= r.mean(axis=(1, 2, 3), keepdims=True)
        ws.r[...] = r
        rz = ws.precondition()
        z = ws.q.copy()
        back = (KI @ z.transpose(1, 2, 3, 0).ravel()).reshape(shape + (3,)).transpose(3, 0, 1, 2)
        assert np.abs(back - r).max() < 1e-11 * np.abs(r).max()
        assert rz == pytest.approx(float(np.vdot(r, z)), rel=1e-12)
        assert np.abs(z.mean(axis=(1, 2, 3))).max() < 1e-12 * np.abs(z).max()
        ws.close()


def test_native_and_numpy_kernels_agree(monkeypatch):
    from homogenization import _native

    if _native.load() is None:
        pytest.skip("no C compiler: only the numpy kernels exist here")
    img = sphere_image(6, 0.3)[:, :5, :]
    img[:, :, :2] = 2
    materials = [4.0 * C_SOFT, VOID, TI]  # the sphere is a pore
    kwargs = dict(discretization="hex8", tol=1e-6, threads=2, macro_strains=np.eye(6)[[4]])
    native = homogenize_fft(img, materials, **kwargs)
    monkeypatch.setattr(_native, "load", lambda: None)
    numpy = homogenize_fft(img, materials, **kwargs)
    assert native.iterations == numpy.iterations
    assert rel(native.C_raw[:, 4], numpy.C_raw[:, 4]) < 1e-10


def test_c_is_symmetric_positive_definite_and_translation_invariant_with_a_void():
    """A porous image with floating void-enclosed islands: C symmetric, positive definite, below the Voigt bound,
    above the rotated scheme's (full integration is stiffer), and unchanged by a periodic shift of the image."""
    rng = np.random.default_rng(2)
    img = (1 - sphere_image(12, 0.42)).astype(np.int8)  # a solid matrix around a large spherical pore
    img[5:7, 5:7, 5:7] = 1  # a floating island inside the pore
    assert rng is not None
    materials = [VOID, C_SOFT]
    r = homogenize_fft(img, materials, discretization="hex8", tol=1e-9)
    assert r.asymmetry < 1e-7
    eig = np.linalg.eigvalsh(voigt_to_mandel(r.C))
    assert eig.min() > 0.05 * eig.max()
    assert r.C[0, 0] < img.mean() * C_SOFT[0, 0]
    rot = homogenize_fft(img, materials, discretization="rotated", tol=1e-9)
    assert np.all(np.diag(r.C) > np.diag(rot.C))
    shifted = homogenize_fft(np.roll(img, (3, -5, 7), axis=(0, 1, 2)), materials, discretization="hex8", tol=1e-9)
    assert rel(shifted.C, r.C) < 1e-7


def test_same_limit_as_the_rotated_scheme_on_a_smooth_inclusion():
    """A stiff sphere (contrast 20): the two discretizations of the voxel image approach each other as N grows
    (largest relative gap of C11 … C44 columns measured 0.036, 0.024, 0.0094 at N = 8, 16, 32), hex8 above."""
    gaps = []
    for n in (8, 16, 32):
        img = sphere_image(n, 0.3)
        C = [homogenize_fft(img, [C_SOFT, isotropic_voigt(20.0, 0.3)], discretization=d, tol=1e-8,
                            macro_strains=np.eye(6)[[0, 3]]).C_raw[:, [0, 3]] for d in ("rotated", "hex8")]
        gaps.append(rel(C[1], C[0]))
        assert C[1][0, 0] > C[0][0, 0]  # full integration is stiffer
    assert gaps[2] < 0.5 * gaps[1] and gaps[1] < 0.8 * gaps[0]


@pytest.mark.slow
def test_hex8_equals_the_voxel_finite_element_model():
    """The same discretization as Q1 hexahedra (full quadrature) on the voxel mesh: the FFT solve and the FEM
    RVE (dolfinx, direct solver) give the same C on a small porous foam image with a zero void."""
    from mpi4py import MPI

    from homogenization.fem import homogenize_fem
    from meshes.foam import VoronoiFoam
    from meshes.voxel import SOLID, voxel_mesh
    from meshes.voxel import VOID as VOID_TAG

    image = VoronoiFoam(3, 0.3, 1.0, seed=1).voxelize(8)
    fft = homogenize_fft(image.astype(np.int8), [VOID, C_SOFT], discretization="hex8", tol=1e-11).C
    msh, tags = voxel_mesh(image, MPI.COMM_SELF)
    fem = homogenize_fem(msh, tags, {SOLID: C_SOFT, VOID_TAG: VOID}, degree=1, comm=MPI.COMM_SELF).C
    assert rel(fft, fem) < 1e-8


def test_hex8_input_errors():
    with pytest.raises(InputError, match="hex8.*pcg' only"):
        homogenize_fft(np.zeros((4, 4, 4), int), [C_SOFT], scheme="cg", discretization="hex8")


@pytest.mark.mpi
@pytest.mark.parametrize("shape", [(15, 13, 11), (16, 12, 10)])
def test_distributed_result_equals_serial(shape):
    """Under ``mpirun -n 2``: uneven slabs, void + two solids, full image and local slabs give the serial C."""
    from test_fft import three_phase_image

    from homogenization.fft import slab_planes

    comm = world()
    img = three_phase_image(shape)
    materials = [VOID, C_SOFT, TI]
    kwargs = dict(discretization="hex8", tol=1e-10, threads=1, macro_strains=np.eye(6)[[0, 2, 3]])
    serial = homogenize_fft(img, materials, **kwargs)
    full = homogenize_fft(img, materials, comm=comm, **kwargs)
    a, b = slab_planes(shape[0], comm)
    part = homogenize_fft(img[a:b], materials, comm=comm, slab=True, **kwargs)
    assert rel(full.C_raw[:, [0, 2, 3]], serial.C_raw[:, [0, 2, 3]]) < 1e-10
    assert rel(part.C_raw[:, [0, 2, 3]], serial.C_raw[:, [0, 2, 3]]) < 1e-10
    assert full.iterations == serial.iterations


# --------------------------------------------------------------------------------------------------
# The table pipeline and the command line
# --------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_sweep_with_hex8_has_its_own_table_cache_entries_and_rows(tmp_path):
    """A hex8 sweep computes its own samples (never a rotated entry), records its discretization, resumes from its
    cache, and its stiffness lies above the rotated one of the same foam (full integration is stiffer)."""
    from mpi4py import MPI

    from homogenization import tables

    sample = tables.Sample(0.3, 1.0, 1)
    rotated = tables.SweepSettings(n_cells=3, resolution=12, tol=1e-5, discretization="rotated")
    hex8 = tables.SweepSettings(n_cells=3, resolution=12, tol=1e-5)  # the default
    assert (rotated.name, hex8.name) == ("cube", "cube_hex8")
    assert tables.cache_name(sample, rotated) != tables.cache_name(sample, hex8)
    [a] = tables.run_sweep([sample], rotated, tmp_path, MPI.COMM_SELF, progress=False, threads=1)
    [b] = tables.run_sweep([sample], hex8, tmp_path, MPI.COMM_SELF, progress=False, threads=1)
    assert "discretization" not in a and b["discretization"] == "hex8"
    assert b["C11"] > a["C11"] and b["C44"] > a["C44"]
    [again] = tables.run_sweep([sample], hex8, tmp_path, MPI.COMM_SELF, progress=False, threads=1)
    assert again == b  # read back from the cache, not recomputed
    assert tables.settings_dict(hex8)["discretization"] == "hex8"
    with pytest.raises(InputError, match="discretization must be one of"):
        tables.SweepSettings(discretization="spectral")


def test_homogenize_command_with_hex8(tmp_path):
    import json

    from homogenization.cli import main

    img = (1 - sphere_image(8, 0.35)).astype(bool)
    np.save(tmp_path / "img.npy", img)
    out = tmp_path / "r.json"
    assert main(["--image", str(tmp_path / "img.npy"), "--discretization", "hex8", "--tol", "1e-8", "--threads", "1",
                 "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    expected = homogenize_fft(img.astype(np.int8), [VOID, C_SOFT], discretization="hex8", tol=1e-8).C
    assert rel(np.array(result["C"]), expected) < 1e-12
