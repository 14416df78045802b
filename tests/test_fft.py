"""FFT homogenization: closed forms (homogeneous, laminates), bounds, invariances, cross-checks, errors."""

import numpy as np
import pytest

from foambase.errors import InputError
from homogenization.fft import (
    FFTConvergenceError,
    homogenize_fft,
    reference_medium,
    wave_directions,
)
from homogenization.tensors import (
    closest_isotropic,
    isotropic_voigt,
    rotate_voigt,
    rotation_from_axis,
    transverse_isotropic_voigt,
    voigt_to_mandel,
)

C_SOFT = isotropic_voigt(1.0, 0.3)


@pytest.fixture(autouse=True)
def one_thread(monkeypatch):
    """Default to one thread: on a shared 2-core machine FFTW threads waiting for a descheduled sibling make
    runs up to 30× slower. ``test_threads_give_the_same_result`` exercises the threaded path explicitly."""
    monkeypatch.setattr("homogenization.fft.cpu_count", lambda: 1)

TI = rotate_voigt(transverse_isotropic_voigt(E_t=3.0, E_l=0.4, nu_t=0.35, nu_tl=0.15, G_l=0.25),
                  rotation_from_axis([1.0, 2.0, 2.0]))
#: Voigt components that involve the layer normal (continuous stress) for layers normal to x, y, z.
NORMAL_COMPONENTS = {0: [0, 4, 5], 1: [1, 3, 5], 2: [2, 3, 4]}


def laminate(stiffnesses, fractions, axis):
    """Exact rank-one laminate: stress components N (involving the normal) and strains T (the others) continuous.

    With A = ⟨C_NN⁻¹⟩: C*_NN = A⁻¹, C*_NT = A⁻¹⟨C_NN⁻¹C_NT⟩, C*_TN = C*_NTᵀ,
    C*_TT = ⟨C_TT − C_TN C_NN⁻¹ C_NT⟩ + ⟨C_TN C_NN⁻¹⟩ A⁻¹ ⟨C_NN⁻¹ C_NT⟩.
    """
    N = NORMAL_COMPONENTS[axis]
    T = [i for i in range(6) if i not in N]
    avg = lambda f: sum(w * f(C) for C, w in zip(stiffnesses, fractions))  # noqa: E731
    inv_nn = lambda C: np.linalg.inv(C[np.ix_(N, N)])  # noqa: E731
    A_inv = np.linalg.inv(avg(inv_nn))
    B = avg(lambda C: inv_nn(C) @ C[np.ix_(N, T)])
    D = avg(lambda C: C[np.ix_(T, T)] - C[np.ix_(T, N)] @ inv_nn(C) @ C[np.ix_(N, T)])
    out = np.empty((6, 6))
    out[np.ix_(N, N)] = A_inv
    out[np.ix_(N, T)] = A_inv @ B
    out[np.ix_(T, N)] = (A_inv @ B).T
    out[np.ix_(T, T)] = D + B.T @ A_inv @ B
    return out


def layered_image(n, axis, n_stiff):
    img = np.zeros((n, n, n), dtype=np.int8)
    index = [slice(None)] * 3
    index[axis] = slice(1, 1 + n_stiff)
    img[tuple(index)] = 1
    return img


def sphere_image(n, radius, centre=(0.5, 0.5, 0.5)):
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    d2 = sum(np.minimum(np.abs(c - x0), 1 - np.abs(c - x0)) ** 2 for c, x0 in zip((X, Y, Z), centre))
    return (d2 < radius**2).astype(np.int8)


def rel(A, B):
    return np.abs(A - B).max() / np.abs(B).max()


# --------------------------------------------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.parametrize("C", [C_SOFT, TI], ids=["isotropic", "rotated-TI"])
@pytest.mark.parametrize("scheme,discretization", [("cg", "rotated"), ("cg", "spectral"), ("basic", "spectral"),
                                                   ("pcg", "rotated")])
def test_homogeneous_returns_itself(C, scheme, discretization):
    r = homogenize_fft(np.zeros((6, 7, 8), dtype=int), [C], scheme=scheme, discretization=discretization)
    assert rel(r.C, C) < 1e-12
    assert r.iterations == [0] * 6 and r.converged and r.method == "fft"


LAMINATE_CASES = [("cg", "rotated", 8, 10.0), ("cg", "rotated", 8, 1000.0), ("cg", "spectral", 9, 10.0),
                  ("cg", "spectral", 9, 1000.0), ("basic", "spectral", 9, 10.0), ("basic", "rotated", 8, 10.0),
                  ("pcg", "rotated", 8, 10.0), ("pcg", "rotated", 7, 1000.0)]


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("scheme,discretization,n,contrast", LAMINATE_CASES)
def test_laminate_matches_closed_form(axis, contrast, scheme, discretization, n):
    n_stiff = 3
    stiff = isotropic_voigt(contrast, 0.2)
    r = homogenize_fft(layered_image(n, axis, n_stiff), [C_SOFT, stiff], scheme=scheme,
                       discretization=discretization, tol=1e-10)
    expected = laminate([C_SOFT, stiff], [1 - n_stiff / n, n_stiff / n], axis)
    assert rel(r.C, expected) < (1e-10 if scheme == "pcg" else 1e-6)
    assert r.asymmetry < 1e-8


@pytest.mark.mpi
@pytest.mark.parametrize("scheme", ["cg", "pcg"])
@pytest.mark.parametrize("axis", [0, 2])
def test_laminate_of_rotated_ti_layers(axis, scheme):
    r = homogenize_fft(layered_image(8, axis, 5), [C_SOFT, TI], scheme=scheme, tol=1e-10)
    assert rel(r.C, laminate([C_SOFT, TI], [3 / 8, 5 / 8], axis)) < (1e-10 if scheme == "pcg" else 1e-6)


def test_spectral_even_grid_nyquist_error_vanishes_with_n():
    """Even grid + spectral: Nyquist frequencies carry no fluctuation. A layer with an odd number of voxels has
    Nyquist content, so the laminate is not exact but converges (~N⁻²); an even number of voxels is exact."""
    stiff = isotropic_voigt(10.0, 0.2)
    errors = []
    for n, n_stiff in ((16, 7), (32, 13), (16, 6)):
        r = homogenize_fft(layered_image(n, 0, n_stiff), [C_SOFT, stiff], discretization="spectral", tol=1e-10,
                           macro_strains=np.eye(6)[:1])
        expected = laminate([C_SOFT, stiff], [1 - n_stiff / n, n_stiff / n], 0)
        errors.append(rel(r.C_raw[:, 0], expected[:, 0]))
    assert 1e-3 < errors[0] < 1e-2 and 3.0 < errors[0] / errors[1] < 6.0
    assert errors[2] < 1e-12


def hashin_shtrikman(k, g, f):
    """HS lower/upper bounds (κ, μ) of a two-phase isotropic mixture (k, g: moduli; f: fractions)."""
    def bound(i):
        j = 1 - i
        K = k[i] + f[j] / (1 / (k[j] - k[i]) + 3 * f[i] / (3 * k[i] + 4 * g[i]))
        G = g[i] + f[j] / (1 / (g[j] - g[i]) + 6 * f[i] * (k[i] + 2 * g[i]) / (5 * g[i] * (3 * k[i] + 4 * g[i])))
        return K, G
    soft, stiff = (0, 1) if k[0] < k[1] else (1, 0)
    return bound(soft), bound(stiff)


@pytest.mark.parametrize("discretization", ["rotated", "spectral"])
def test_spherical_inclusion_between_hashin_shtrikman_bounds(discretization):
    img = sphere_image(16, 0.3)
    stiff = isotropic_voigt(10.0, 0.25)
    r = homogenize_fft(img, [C_SOFT, stiff], discretization=discretization, tol=1e-8)
    f1 = img.mean()
    moduli = [closest_isotropic(C) for C in (C_SOFT, stiff)]
    k = [m.E / (3 * (1 - 2 * m.nu)) for m in moduli]
    g = [m.E / (2 * (1 + m.nu)) for m in moduli]
    (k_lo, g_lo), (k_hi, g_hi) = hashin_shtrikman(k, g, [1 - f1, f1])
    fit = r.isotropic_fit()
    k_eff, g_eff = fit.E / (3 * (1 - 2 * fit.nu)), fit.E / (2 * (1 + fit.nu))
    assert k_lo < k_eff < k_hi
    assert g_lo < g_eff < g_hi
    assert np.linalg.eigvalsh(voigt_to_mandel(r.C)).min() > 0  # positive definite
    assert r.asymmetry < 1e-6


def test_rotated_and_spectral_agree_as_n_grows():
    stiff = isotropic_voigt(10.0, 0.25)
    gaps = []
    for n in (8, 16, 32):
        img = sphere_image(n, 0.3)
        C = [homogenize_fft(img, [C_SOFT, stiff], discretization=d, tol=1e-8,
                            macro_strains=np.eye(6)[[0, 3]]).C_raw[:, [0, 3]] for d in ("rotated", "spectral")]
        gaps.append(rel(C[0], C[1]))
    assert gaps[2] < gaps[1] < gaps[0]
    assert gaps[2] < 1e-2


def test_void_phase_cg_converges_and_basic_refuses():
    img = sphere_image(12, 0.35)  # spherical pore, the solid percolates
    materials = [C_SOFT, np.zeros((6, 6))]
    r = homogenize_fft(img, materials, tol=1e-8)
    assert r.converged and max(r.iterations) < 200
    assert np.all(np.isfinite(r.C))
    eig = np.linalg.eigvalsh(voigt_to_mandel(r.C))
    assert 0 < eig.min() and eig.max() < np.linalg.eigvalsh(voigt_to_mandel(C_SOFT)).max()
    assert r.C[0, 0] < (1 - img.mean()) * C_SOFT[0, 0]  # below the Voigt bound
    with pytest.raises(InputError, match="basic.*cannot handle.*void"):
        homogenize_fft(img, materials, scheme="basic")


def test_basic_at_huge_contrast_reports_instead_of_nan():
    img = sphere_image(8, 0.3)
    materials = [C_SOFT, 1e9 * C_SOFT]
    with pytest.raises(FFTConvergenceError, match="did not reach tol") as info:
        homogenize_fft(img, materials, scheme="basic", maxiter=30)
    assert np.all(np.isfinite(info.value.residuals)) and len(info.value.residuals) == 31
    r = homogenize_fft(img, materials, scheme="basic", maxiter=30, raise_on_failure=False,
                       macro_strains=np.eye(6)[:1])
    assert not r.converged and np.all(np.isfinite(r.C_raw[:, 0])) and r.info["failures"]


@pytest.mark.parametrize("scheme", ["cg", "basic", "pcg"])
def test_unconverged_result_is_flagged_and_its_fields_are_consistent(scheme):
    img = sphere_image(8, 0.3)
    r = homogenize_fft(img, [C_SOFT, isotropic_voigt(4.0, 0.2)], scheme=scheme, maxiter=2, tol=1e-12,
                       raise_on_failure=False, return_fields=True, macro_strains=np.eye(6)[:1])
    assert not r.converged and r.iterations == [2] and r.residuals[0][-1] > 1e-12
    assert "maxiter = 2" in r.info["failures"][0]
    assert np.allclose(r.fields["strain"].mean(axis=(2, 3, 4)), np.eye(6)[:1], atol=1e-14)
    assert np.allclose(r.fields["stress"].mean(axis=(2, 3, 4))[0], r.C_raw[:, 0], rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("scheme", ["cg", "basic", "pcg"])
def test_checkpoints_are_the_looser_runs(scheme):
    """A checkpoint at t is exactly what a run with tol = t returns: C bit for bit, iterations; one not reached
    within maxiter is flagged and holds the final state, like the unconverged run."""
    img = sphere_image(10, 0.3)
    materials = [C_SOFT, isotropic_voigt(6.0, 0.2)]
    tight = homogenize_fft(img, materials, scheme=scheme, tol=1e-7, checkpoints=[1e-3, 1e-5, 1e-7], threads=1)
    points = tight.info["checkpoints"]
    assert [p["tol"] for p in points] == [1e-3, 1e-5, 1e-7]
    for point in points:
        run = homogenize_fft(img, materials, scheme=scheme, tol=point["tol"], threads=1)
        assert point["iterations"] == run.iterations and point["converged"]
        assert np.array_equal(point["C"], run.C)
        assert 0.0 < point["wall_s"] <= tight.wall_s
    assert points[0]["wall_s"] < points[-1]["wall_s"] and np.array_equal(points[-1]["C"], tight.C)
    assert sum(points[0]["iterations"]) < sum(points[1]["iterations"]) < sum(points[2]["iterations"])

    capped = homogenize_fft(img, materials, scheme=scheme, tol=1e-12, maxiter=5, raise_on_failure=False,
                            checkpoints=[1e-1, 1e-12], threads=1)
    loose, unreached = capped.info["checkpoints"]
    assert not unreached["converged"] and unreached["iterations"] == capped.iterations
    assert np.array_equal(unreached["C"], capped.C)
    assert loose["converged"] == all(min(r) <= 1e-1 for r in capped.residuals)


def test_basic_and_cg_agree_on_finite_contrast():
    img = sphere_image(10, 0.3)
    materials = [C_SOFT, isotropic_voigt(5.0, 0.2)]
    cg = homogenize_fft(img, materials, tol=1e-9)
    basic = homogenize_fft(img, materials, scheme="basic", tol=1e-9)
    assert rel(basic.C, cg.C) < 1e-7
    ref = basic.info["reference_medium"]
    k, g = np.array([1 / 1.2, 5 / 1.8]), np.array([1 / 2.6, 5 / 2.4])  # κ = E/(3(1-2ν)), μ = E/(2(1+ν))
    contrast = max((k[1] - k[0]) / (k[1] + k[0]), (g[1] - g[0]) / (g[1] + g[0]))
    assert ref["contraction_factor"] == pytest.approx(contrast, rel=1e-12)
    assert sum(cg.iterations) < sum(basic.iterations)


def test_reference_medium_is_crafts_average_for_isotropic_phases():
    E, nu = np.array([1.0, 7.0]), np.array([0.3, 0.2])
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    ref = reference_medium([voigt_to_mandel(isotropic_voigt(e, n)) for e, n in zip(E, nu)])
    assert ref.mu == pytest.approx(mu.mean(), rel=1e-12)
    assert ref.lam == pytest.approx(lam.mean(), rel=1e-12)  # the stiffer phase has both larger moduli
    assert 0 < ref.rate < 1


def test_rotating_the_image_by_90_degrees_rotates_c():
    rng = np.random.default_rng(3)
    img = (rng.random((8, 8, 8)) < 0.4).astype(np.int8)
    materials = [C_SOFT, isotropic_voigt(8.0, 0.2)]
    C = homogenize_fft(img, materials, tol=1e-10).C
    # np.rot90 over axes (0, 1): new(x, y) = old(y, 1 - x), a +90° rotation about z.
    C_rot = homogenize_fft(np.rot90(img, 1, axes=(0, 1)), materials, tol=1e-10).C
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert rel(C, C_rot) > 1e-3  # the image is anisotropic: the test can fail
    assert rel(C_rot, rotate_voigt(C, R)) < 1e-7


@pytest.mark.parametrize("scheme", ["cg", "pcg"])
def test_threads_give_the_same_result(scheme):
    img = sphere_image(10, 0.3)
    materials = [np.zeros((6, 6)), C_SOFT, isotropic_voigt(3.0, 0.2)]
    img[:, :, :2] = 2  # three phases, one of them void
    C = [homogenize_fft(img, materials, scheme=scheme, tol=1e-8, threads=t,
                        macro_strains=np.eye(6)[[0, 4]]).C_raw[:, [0, 4]] for t in (1, 2)]
    assert rel(C[1], C[0]) < 1e-9  # only the summation order of the inner products differs


@pytest.mark.parametrize("discretization,scheme", [("rotated", "cg"), ("spectral", "cg"), ("spectral", "basic"),
                                                   ("rotated", "pcg")])
def test_native_and_numpy_kernels_agree(monkeypatch, discretization, scheme):
    """The fused C kernels and the numpy kernels do the same algebra: same C and residual histories.

    Only the summation order of the inner products differs (CG amplifies that round-off slowly). Odd and even
    axes, three phases (a rotated TI among them, and a void with ``rotated``), two threads to split the blocks.
    """
    from homogenization import _native

    if _native.load() is None:
        pytest.skip("no C compiler: only the numpy kernels exist here")
    img = sphere_image(12, 0.3)[:, :11, :]
    img[:, :, :3] = 2
    materials = [np.zeros((6, 6)) if discretization == "rotated" else C_SOFT, 4.0 * C_SOFT, TI]
    # the spheres of solid 1 are isolated in the void: a deliberately singular C
    kwargs = dict(scheme=scheme, discretization=discretization, tol=1e-7, threads=2,
                  allow_singular=discretization == "rotated")
    native = homogenize_fft(img, materials, **kwargs)
    monkeypatch.setattr(_native, "load", lambda: None)
    numpy = homogenize_fft(img, materials, **kwargs)
    assert native.iterations == numpy.iterations
    assert rel(native.C_raw, numpy.C_raw) < 1e-10
    for a, b in zip(native.residuals, numpy.residuals):  # relative residuals: agree to 1e-8 of the first one
        np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-8)


def test_fields_macro_strains_and_callback():
    img = sphere_image(8, 0.3)
    materials = [C_SOFT, isotropic_voigt(4.0, 0.2)]
    full = homogenize_fft(img, materials, tol=1e-10)
    calls = []
    strains = np.array([[0.0, 0.0, 0.0, 0.02, 0.0, 0.0], [1e-3, 2e-3, 0.0, 0.0, 0.0, 0.0]])
    part = homogenize_fft(img, materials, tol=1e-10, macro_strains=strains, return_fields=True,
                          callback=lambda case, it, res: calls.append((case, it, res)))
    assert np.allclose(part.C_raw[:, 3], full.C_raw[:, 3], rtol=1e-7, atol=1e-12)
    assert np.all(np.isnan(part.C_raw[:, [0, 1, 2, 4, 5]]))
    assert np.allclose(part.info["mean_stress"][1], full.C_raw @ strains[1], rtol=1e-7, atol=1e-12)
    strain, stress = part.fields["strain"], part.fields["stress"]
    assert strain.shape == (2, 6, 8, 8, 8)
    assert np.allclose(strain.mean(axis=(2, 3, 4)), strains, atol=1e-14)
    assert np.allclose(stress.mean(axis=(2, 3, 4)), part.info["mean_stress"], rtol=1e-10, atol=1e-14)
    assert {c for c, _, _ in calls} == {0, 1}
    assert calls[-1][1] == part.iterations[1] and calls[-1][2] == part.residuals[1][-1] <= 1e-10


def test_wave_directions_zero_where_g_vanishes():
    n = wave_directions((4, 4, 4), "rotated")
    norm = np.sqrt((n**2).sum(axis=0))
    assert norm[0, 0, 0] == 0 and norm[2, 2, 0] == 0 and norm[2, 0, 2] == 0  # ξ = 0 and hourglass modes
    assert np.allclose(norm[1, 2, 1], 1.0)
    s = wave_directions((5, 4, 4), "spectral")
    assert np.all(s[:, :, 2] == 0) and np.all(s[:, :, :, 2] == 0)  # Nyquist planes of the even axes
    assert np.allclose(np.sqrt((s[:, 1:, :2, :2] ** 2).sum(axis=0))[:, 1:], 1.0)


@pytest.mark.parametrize("phases,materials,kwargs,match", [
    (np.zeros((4, 4, 4), int) + 2, [C_SOFT, C_SOFT], {}, r"phase ids \[2\].*no material"),
    (np.zeros((4, 4), int), [C_SOFT], {}, "3-D"),
    (np.zeros((4, 4, 4)), [C_SOFT], {}, "integer phase ids"),
    (np.zeros((4, 4, 4), int) - 1, [C_SOFT], {}, ">= 0"),
    (np.zeros((4, 4, 4), int), [C_SOFT + np.triu(np.ones((6, 6)), 1)], {}, r"materials\[0\] is not symmetric"),
    (np.zeros((4, 4, 4), int), [np.eye(3)], {}, r"materials\[0\] must be a 6×6"),
    (np.zeros((4, 4, 4), int), [-C_SOFT], {}, "not positive definite"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"tol": -1e-6}, "tol must satisfy"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"scheme": "fancy"}, "scheme must be one of"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"discretization": "hex27"}, "discretization must be one of"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"scheme": "pcg", "discretization": "spectral"}, "pcg.*use scheme='cg'"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"maxiter": 0}, "maxiter must be a positive integer"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"threads": 0}, "threads must be a positive integer"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"macro_strains": np.ones((2, 3))}, r"\(n_cases, 6\)"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"tol": 1e-4, "checkpoints": [1e-6]}, r"tol = 0.0001 <= t < 1.*1e-06"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"checkpoints": [1.0]}, r"checkpoints must satisfy.*\[1.0\]"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"macro_strains": np.zeros((2, 6))}, r"macro_strains\[0\] is zero.*\[0, 1\]"),
    (np.zeros((4, 4, 4), int), [C_SOFT], {"macro_strains": np.eye(6)[[0, 0]] * [[1], [0]]},
     r"macro_strains\[1\] is zero"),
    (np.zeros((4, 4, 4), int), [np.zeros((6, 6))], {}, r"every phase in the image \(\[0\]\) has zero stiffness"),
    (np.arange(8).reshape(2, 2, 2) % 2, [np.zeros((6, 6))] * 2, {"scheme": "cg"}, r"\(\[0, 1\]\) has zero stiffness"),
    (np.zeros((4, 4, 4), int), [C_SOFT + np.inf], {}, r"materials\[0\] has non-finite entries"),
    (np.zeros((4, 4, 4), int), [C_SOFT * 1e-310], {}, "subnormal"),
])
def test_bad_inputs(phases, materials, kwargs, match):
    with pytest.raises(InputError, match=match):
        homogenize_fft(phases, materials, **kwargs)


@pytest.mark.parametrize("scheme,void", [("pcg", True), ("cg", True), ("basic", False)])
def test_c_scales_with_the_moduli_and_not_with_the_strain(scheme, void):
    """C is linear in the phases' stiffnesses: C(λ C_p)/λ = C(C_p) for moduli in any unit, 1e200 or 1e-170 (their
    squared norms overflow or underflow double precision: a solver that forms them stops at iteration 0 with the
    Voigt bound); and C does not depend on the size of the macroscopic strains (1e-200 or 1e150)."""
    img = sphere_image(10, 0.3)
    materials = [TI, np.zeros((6, 6)) if void else isotropic_voigt(0.1, 0.3)]  # the sphere is the pore
    kwargs = dict(scheme=scheme, tol=1e-8)
    ref = homogenize_fft(img, materials, **kwargs)
    assert sum(ref.iterations) > 30  # a real solve, so the scaled runs can fail to reproduce it
    for lam in (1e200, 3.7e-170, 2.0**-300):
        r = homogenize_fft(img, [lam * C for C in materials], **kwargs)
        assert r.iterations == ref.iterations
        assert rel(r.C / lam, ref.C) < 1e-12  # measured < 5e-14 (power of two: 0)
    r = homogenize_fft(img, materials, macro_strains=np.diag([1e-200, 1e150, 3e-7, 1e-200, 1.0, 1e100]), **kwargs)
    assert rel(r.C, ref.C) < 1e-12
    assert np.all(ref.C != homogenize_fft(img, materials, scheme=scheme, tol=1e-8, maxiter=1,
                                          raise_on_failure=False).C)  # the Voigt bound is not the answer


def test_overflowing_stress_and_nan_residual_are_computation_errors(monkeypatch):
    """Results that are not finite numbers are never returned, with or without raise_on_failure."""
    from foambase.errors import ComputationError
    from homogenization import _nodal

    img = sphere_image(8, 0.3)
    materials = [isotropic_voigt(1e308, 0.3), np.zeros((6, 6))]  # ⟨σ⟩ of a strain of 100 overflows
    with pytest.raises(ComputationError, match="mean stress is not finite"):
        homogenize_fft(img, materials, macro_strains=100 * np.eye(6)[:1], raise_on_failure=False)
    calls = []
    precondition = _nodal.NodalWorkspace.precondition

    def poisoned(self):  # a NaN enters the fields at the third preconditioner call
        out = precondition(self)
        calls.append(1)
        return out * np.nan if len(calls) == 3 else out
    monkeypatch.setattr(_nodal.NodalWorkspace, "precondition", poisoned)
    with pytest.raises(ComputationError, match=r"load case 0 .*residual is nan at iteration 2"):
        homogenize_fft(img, [C_SOFT, np.zeros((6, 6))], scheme="pcg", raise_on_failure=False)


def test_convergence_error_survives_pickling():
    """The error crosses process boundaries (multiprocessing, the benchmark) with its case and residuals."""
    import pickle

    err = pickle.loads(pickle.dumps(FFTConvergenceError("no convergence", 3, [1.0, 0.5])))
    assert (str(err), err.case, err.residuals) == ("no convergence", 3, [1.0, 0.5])


# --------------------------------------------------------------------------------------------------
# Non-cubic periodic boxes (box=(L1, L2, L3), voxel sizes h_j = L_j/N_j)
# --------------------------------------------------------------------------------------------------
BOX_SHAPE = (8, 12, 6)  # cubic voxels in the box (8, 12, 6) h: box=BOX_SHAPE
VOIGT_PAIRS = [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]


def permute_voigt(C, perm):
    """C of the image ``np.transpose(img, perm)``: new axis a is old axis perm[a]."""
    index = [VOIGT_PAIRS.index(tuple(sorted((perm[a], perm[b])))) for a, b in VOIGT_PAIRS]
    return C[np.ix_(index, index)]


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("discretization,scheme", [("rotated", "cg"), ("spectral", "cg"), ("rotated", "pcg")])
def test_laminate_in_a_non_cubic_box_is_exact(axis, discretization, scheme):
    img = np.zeros(BOX_SHAPE, dtype=np.int8)
    index = [slice(None)] * 3
    index[axis] = slice(1, 5)  # four layers: no Nyquist content on the even grid (spectral is exact too)
    img[tuple(index)] = 1
    stiff = isotropic_voigt(1000.0, 0.2)
    r = homogenize_fft(img, [C_SOFT, stiff], box=BOX_SHAPE, discretization=discretization, scheme=scheme, tol=1e-12)
    f = 4 / BOX_SHAPE[axis]
    assert rel(r.C, laminate([C_SOFT, stiff], [1 - f, f], axis)) < 1e-10


def test_homogeneous_non_cubic_box_returns_itself():
    r = homogenize_fft(np.zeros(BOX_SHAPE, dtype=int), [TI], box=(0.8, 1.2, 0.6))
    assert rel(r.C, TI) < 1e-12 and r.iterations == [0] * 6 and r.info["box"] == [0.8, 1.2, 0.6]


@pytest.mark.parametrize("perm", [(1, 0, 2), (2, 0, 1)])
def test_permuting_the_axes_of_a_box_permutes_c(perm):
    rng = np.random.default_rng(5)
    img = (rng.random(BOX_SHAPE) < 0.4).astype(np.int8)
    materials = [C_SOFT, isotropic_voigt(8.0, 0.2)]
    C = homogenize_fft(img, materials, box=BOX_SHAPE, tol=1e-10).C
    box = [BOX_SHAPE[p] for p in perm]
    C_perm = homogenize_fft(np.transpose(img, perm), materials, box=box, tol=1e-10).C
    assert rel(C_perm, C) > 1e-3  # the image is anisotropic: the test can fail
    assert rel(C_perm, permute_voigt(C, perm)) < 1e-8


@pytest.mark.parametrize("discretization,scheme", [("rotated", "cg"), ("spectral", "cg"), ("rotated", "pcg")])
def test_box_of_two_periods_gives_the_cube(discretization, scheme):
    """Two periods of a unit-cube image along y, as the box (1, 2, 1) with cubic voxels, have the cube's C; read
    as the unit cube (the default, voxels twice as thin along y) they do not: the box is really used."""
    img = sphere_image(9, 0.3, centre=(0.4, 0.5, 0.55))
    img[:, :, :2] = 2
    materials = [C_SOFT, isotropic_voigt(6.0, 0.2), TI]
    kwargs = dict(discretization=discretization, scheme=scheme, tol=1e-10)
    C = homogenize_fft(img, materials, **kwargs).C
    twice = np.concatenate([img, img], axis=1)
    assert rel(homogenize_fft(twice, materials, box=(1.0, 2.0, 1.0), **kwargs).C, C) < 1e-10
    assert rel(homogenize_fft(twice, materials, box=twice.shape, **kwargs).C, C) < 1e-10
    assert rel(homogenize_fft(twice, materials, **kwargs).C, C) > 1e-2


def test_unit_box_is_the_default_bit_for_bit():
    img = sphere_image(8, 0.3)
    materials = [np.zeros((6, 6)), C_SOFT]
    default = homogenize_fft(img, materials, tol=1e-8, macro_strains=np.eye(6)[[0, 3]])
    for box in [(1, 1, 1), (4.0, 4.0, 4.0)]:  # a power-of-two scale leaves n = k/|k| bit for bit
        r = homogenize_fft(img, materials, box=box, tol=1e-8, macro_strains=np.eye(6)[[0, 3]])
        assert np.array_equal(r.C_raw, default.C_raw, equal_nan=True) and r.residuals == default.residuals


@pytest.mark.parametrize("box", [(1.0, 2.0), (1.0, 0.0, 1.0), (1.0, np.nan, 1.0), "abc", 3.0])
def test_bad_box(box):
    with pytest.raises(InputError, match="box must be three positive"):
        homogenize_fft(np.zeros((4, 4, 4), int), [C_SOFT], box=box)


# --------------------------------------------------------------------------------------------------
# pcg: the rotated scheme solved for the nodal displacements (trilinear voxels, one-point quadrature)
# --------------------------------------------------------------------------------------------------
def foam_like_image(n, seed=2):
    """A porous image whose solid percolates: random walls of a periodic 3-D grid of cells (18-30 % solid)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((n, n, n), dtype=np.int8)
    for axis in range(3):
        for w in rng.choice(n, size=2, replace=False):
            index = [slice(None)] * 3
            index[axis] = slice(w, w + 1)
            img[tuple(index)] = 1
    holes = sphere_image(n, 0.22, centre=tuple(rng.random(3)))  # punch a pore through the walls
    img[holes.astype(bool)] = 0
    return img


def test_pcg_iterates_are_those_of_cg_on_a_void_structure():
    """The nodal-displacement CG with the Green preconditioner K_I⁻¹ is the strain-based Galerkin CG mapped by B:
    same residual histories (the same ‖G[σ]‖/‖G[C:E]‖), same iteration counts, same C — two independent
    implementations (FFT projection of 6 strain components vs. a real-space hexahedron stencil and an FFT of 3
    displacement components) of one discrete problem."""
    img = foam_like_image(16)
    materials = [np.zeros((6, 6)), C_SOFT]
    cg = homogenize_fft(img, materials, scheme="cg", tol=1e-6)
    pcg = homogenize_fft(img, materials, scheme="pcg", tol=1e-6)
    assert 0.05 < img.mean() < 0.5 and sum(cg.iterations) > 60  # void: many iterations, so the test can fail
    assert [abs(a - b) <= 1 for a, b in zip(cg.iterations, pcg.iterations)] == [True] * 6
    for a, b in zip(cg.residuals, pcg.residuals):  # round-off grows along the history (measured: 1e-10 up to
        np.testing.assert_allclose(a[:150], b[:150], rtol=1e-10)  # iteration 178, 1e-6 up to 213 of 415-494)
    assert rel(pcg.C, cg.C) < 1e-7  # measured 1.7e-9


@pytest.mark.parametrize("box", [None, (1.0, 1.6, 0.7)], ids=["cube", "non-cubic-voxels"])
def test_pcg_fields_are_those_of_cg(box):
    """pcg's voxel strain E + B u and stress are cg's; in a box of voxels with three different edge lengths too
    (each derivative of the nodal displacements divided by its own voxel size)."""
    img = sphere_image(10, 0.3)
    img[:, :, :3] = 2
    materials = [np.zeros((6, 6)), C_SOFT, TI]
    kwargs = dict(tol=1e-10, return_fields=True, macro_strains=np.eye(6)[[1, 5]], box=box)
    cg, pcg = (homogenize_fft(img, materials, scheme=s, **kwargs) for s in ("cg", "pcg"))
    assert pcg.fields["strain"].shape == (2, 6, 10, 10, 10)
    solid = img > 0  # the strain of a void voxel is not determined by the problem
    for key in ("strain", "stress"):
        a, b = cg.fields[key], pcg.fields[key]
        assert np.abs(a - b)[:, :, solid].max() < 1e-7 * np.abs(a).max()
    assert np.allclose(pcg.fields["strain"].mean(axis=(2, 3, 4)), np.eye(6)[[1, 5]], atol=1e-14)
    assert np.allclose(pcg.fields["stress"].mean(axis=(2, 3, 4)), pcg.info["mean_stress"], rtol=1e-10, atol=1e-14)


# --------------------------------------------------------------------------------------------------
# Distributed mode (comm=...): slabs of planes over the ranks, FFTs by mpi4py-fft
# --------------------------------------------------------------------------------------------------
def world():
    from mpi4py import MPI

    return MPI.COMM_WORLD


def three_phase_image(shape):
    img = sphere_image(max(shape), 0.3)[:shape[0], :shape[1], :shape[2]].copy()
    img[:, :, :2] = 2
    img[:3, :4, 5:] = 0
    return img


@pytest.mark.mpi
@pytest.mark.parametrize("shape", [(15, 13, 11), (16, 12, 10)])
def test_distributed_result_equals_serial(shape):
    """Odd and even grids; under ``mpirun -n 2`` the 15 planes split 8 + 7 (uneven), and so do the 6 or 7
    spectral planes of the last axis. Full image on every rank and local slabs give the serial C (measured to
    4e-16) and fields."""
    from homogenization.fft import slab_planes

    comm = world()
    img = three_phase_image(shape)
    materials = [isotropic_voigt(0.1, 0.2), C_SOFT, TI]
    kwargs = dict(tol=1e-10, threads=1, macro_strains=np.eye(6)[[0, 2, 3]])
    serial = homogenize_fft(img, materials, return_fields=True, **kwargs)
    full = homogenize_fft(img, materials, comm=comm, **kwargs)
    a, b = slab_planes(shape[0], comm)
    part = homogenize_fft(img[a:b], materials, comm=comm, slab=True, return_fields=True, **kwargs)
    assert rel(full.C_raw[:, [0, 2, 3]], serial.C_raw[:, [0, 2, 3]]) < 1e-10
    assert rel(part.C_raw[:, [0, 2, 3]], serial.C_raw[:, [0, 2, 3]]) < 1e-10
    assert full.iterations == serial.iterations and full.info["ranks" if comm.Get_size() > 1 else "shape"]
    assert part.fields["stress"].shape[2] == b - a
    np.testing.assert_allclose(part.fields["stress"], serial.fields["stress"][:, :, a:b], rtol=0, atol=1e-10)
    if comm.Get_size() > 1:
        assert full.info["planes"] == [a, b] and len(full.info["work_bytes_per_rank"]) == comm.Get_size()
        assert max(full.info["work_bytes_per_rank"]) < 0.75 * serial.info["work_bytes"]  # memory is split


@pytest.mark.mpi
def test_distributed_moduli_in_any_unit():
    """The distributed solve scales like the serial one: moduli of 1e-170 on the ranks give the serial C of the
    moduli of 1, times 1e-170; a zero load case is refused on every rank."""
    comm = world()
    img = three_phase_image((9, 8, 8))
    materials = [np.zeros((6, 6)), C_SOFT, TI]
    kwargs = dict(tol=1e-10, threads=1, macro_strains=np.eye(6)[[0, 3]])
    serial = homogenize_fft(img, materials, **kwargs)
    r = homogenize_fft(img, [1e-170 * C for C in materials], comm=comm, **kwargs)
    assert all(abs(a - b) <= 1 for a, b in zip(r.iterations, serial.iterations)) and min(r.iterations) > 10
    assert rel(r.C_raw[:, [0, 3]] / 1e-170, serial.C_raw[:, [0, 3]]) < 1e-10
    with pytest.raises(InputError, match=r"macro_strains\[1\] is zero"):
        homogenize_fft(img, materials, comm=comm, macro_strains=np.eye(6)[[0]] * [[1], [0]])


@pytest.mark.mpi
def test_distributed_bad_input_fails_on_every_rank():
    """Errors are raised on every rank before any collective work (no rank is left waiting)."""
    comm = world()
    if comm.Get_size() == 1:
        pytest.skip("needs mpirun -n 2 or more")
    size = comm.Get_size()
    with pytest.raises(InputError, match=r"at most min\(N1, N3//2 \+ 1\) = 1 ranks"):
        homogenize_fft(np.zeros((1, 8, 8), dtype=int), [C_SOFT], comm=comm)
    with pytest.raises(InputError, match=r"at most min\(N1, N3//2 \+ 1\) = 1 ranks"):
        homogenize_fft(np.zeros((8, 8, 1), dtype=int), [C_SOFT], comm=comm)
    with pytest.raises(InputError, match=rf"at most min\(N1, N3//2 \+ 1\) = {size - 1} ranks"):  # an empty slab
        homogenize_fft(np.zeros((int(comm.Get_rank() < size - 1), 8, 8), dtype=int), [C_SOFT], comm=comm, slab=True)
    with pytest.raises(InputError, match="slab_planes"):  # the last rank passes one plane too many
        homogenize_fft(np.zeros((4 + (comm.Get_rank() == size - 1), 8, 8), dtype=int), [C_SOFT], comm=comm,
                       slab=True)
    with pytest.raises(InputError, match="same full image"):
        homogenize_fft(np.zeros((8 + comm.Get_rank(), 8, 8), dtype=int), [C_SOFT], comm=comm)
    with pytest.raises(InputError, match="runs scheme='pcg'"):
        homogenize_fft(np.zeros((8, 8, 8), dtype=int), [C_SOFT], comm=comm, scheme="cg")
    bad = np.zeros((2 * size, 8, 8), dtype=int)
    bad[-1, 0, 0] = 3 if comm.Get_rank() == size - 1 else 0  # a phase without material, in the last slab only
    with pytest.raises(InputError, match=r"phase ids \[3\].*no material"):
        homogenize_fft(bad, [C_SOFT], comm=comm)


def test_slab_planes_is_the_block_distribution():
    from homogenization.fft import slab_planes

    class Comm:  # a communicator of `size` ranks
        def __init__(self, size):
            self.size = size

        def Get_size(self):  # noqa: N802
            return self.size

    for n1, size in [(16, 2), (15, 2), (10, 3), (7, 7)]:
        parts = [slab_planes(n1, Comm(size), rank) for rank in range(size)]
        assert parts[0][0] == 0 and parts[-1][1] == n1
        assert all(p[1] == q[0] for p, q in zip(parts, parts[1:]))
        assert max(b - a for a, b in parts) - min(b - a for a, b in parts) <= 1


def test_pcg_stencil_is_the_assembled_hexahedron_stiffness():
    """The fused stencil ``K p = Bᵀ C B p`` equals the finite-element stiffness assembled from element matrices
    ``h1 h2 h3 Bₑᵀ C Bₑ`` of one-point hexahedra (``Bₑ`` from ``∂N/∂x_d = ±1/(4 h_d)`` at the centre), on a
    non-cubic box with three phases (void, isotropic, rotated TI) and odd and even axes."""
    import scipy.sparse as sparse

    from homogenization import _nodal

    shape, box = (5, 6, 4), (0.5, 0.9, 0.3)
    h = np.array(box) / np.array(shape)
    img = np.random.default_rng(4).integers(0, 3, shape)
    materials = {0: np.zeros((6, 6)), 1: voigt_to_mandel(C_SOFT), 2: voigt_to_mandel(TI)}
    B = np.zeros((6, 24))
    for ci, corner in enumerate(np.ndindex(2, 2, 2)):
        g = np.array([(1 if corner[d] else -1) / (4 * h[d]) for d in range(3)])
        for c in range(3):
            G = np.zeros((3, 3))
            G[c] = g
            B[:, 3 * ci + c] = [G[a, a] if a == d else (G[a, d] + G[d, a]) / np.sqrt(2)
                                for a, d in [(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)]]
    index = np.arange(img.size).reshape(shape)
    rows, cols, vals = [], [], []
    for v in np.ndindex(*shape):
        dofs = [3 * index[tuple((np.array(v) + corner) % shape)] + c for corner in np.ndindex(2, 2, 2)
                for c in range(3)]
        ke = h.prod() * B.T @ materials[img[v]] @ B
        rows += np.repeat(dofs, 24).tolist()
        cols += np.tile(dofs, 24).tolist()
        vals += ke.ravel().tolist()
    K = sparse.coo_matrix((vals, (rows, cols)), shape=(3 * img.size,) * 2).tocsr()
    ws = _nodal.NodalWorkspace(img, _nodal.stiffness_tables(materials), shape, box, 1, False)
    u = np.random.default_rng(5).random((3,) + shape)
    ws.p[:, 1:-1] = u
    ws.fill_ghosts(ws.p)
    energy, _ = ws.apply(True, None)
    expected = (K @ u.transpose(1, 2, 3, 0).ravel()).reshape(shape + (3,)).transpose(3, 0, 1, 2) / h.prod()
    assert np.abs(ws.q - expected).max() < 1e-12 * np.abs(expected).max()
    assert energy == pytest.approx(float(np.vdot(u, expected)), rel=1e-12)


# --------------------------------------------------------------------------------------------------
# Accuracy tied to tol: the equilibrium residual recomputed from the returned fields, and the CG error bounds
# --------------------------------------------------------------------------------------------------
VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
MANDEL_W = np.array([1.0, 1.0, 1.0, np.sqrt(2.0), np.sqrt(2.0), np.sqrt(2.0)])


def unit_wave_vectors(N: int, discretization: str) -> np.ndarray:
    """n = k/|k| on the full FFT grid (3, N, N, N), written from the definitions in homogenization.fft's docstring
    (``spectral``: k = 2π m; ``rotated``: Willot's k_j ∝ sin(π m_j/N) ∏_{l≠j} cos(π m_l/N)); n = 0 where k = 0.
    Odd N only (no Nyquist frequencies to treat)."""
    assert N % 2 == 1
    m = np.meshgrid(*[np.fft.fftfreq(N, 1.0 / N)] * 3, indexing="ij")
    if discretization == "spectral":
        k = np.array([2 * np.pi * mj for mj in m])
    else:
        s, c = [np.sin(np.pi * mj / N) for mj in m], [np.cos(np.pi * mj / N) for mj in m]
        k = 2 * N * np.array([s[0] * c[1] * c[2], c[0] * s[1] * c[2], c[0] * c[1] * s[2]])
    norm = np.sqrt((k**2).sum(axis=0))
    zero = norm <= 1e-10 * norm.max()
    return np.where(zero, 0.0, k / np.where(zero, 1.0, norm))


def projected_rms(stress_voigt: np.ndarray, n: np.ndarray) -> float:
    """‖G[σ]‖ (root mean square over the voxels of the tensor Frobenius norm) of a Voigt stress field (6, N, N, N),
    G[τ̂] = n⊗w + w⊗n, w = τ̂n − ½ (n·τ̂n) n: the orthogonal projection onto compatible zero-mean strain fields."""
    N = stress_voigt.shape[1]
    T = np.empty((3, 3) + stress_voigt.shape[1:])
    for I, (i, j) in enumerate(VOIGT):
        T[i, j] = T[j, i] = stress_voigt[I]
    T_hat = np.fft.fftn(T, axes=(2, 3, 4))
    tn = np.einsum("ij...,j...->i...", T_hat, n)
    w = tn - 0.5 * np.einsum("i...,i...->...", n, tn) * n
    G = n[:, None] * w[None] + w[:, None] * n[None]
    return float(np.sqrt((np.abs(G) ** 2).sum() / N**6))


ACCURACY_IMAGE = sphere_image(15, 0.32)
ACCURACY_PHASES = [C_SOFT, 4.0 * TI]
#: extreme Mandel eigenvalues over the phases: the spectrum of the CG operator G C G on compatible fields
_EIG = np.concatenate([np.linalg.eigvalsh(C * np.outer(MANDEL_W, MANDEL_W)) for C in ACCURACY_PHASES])
C_MIN, C_MAX = _EIG.min(), _EIG.max()


@pytest.fixture(scope="module")
def exact_fft():
    return {d: homogenize_fft(ACCURACY_IMAGE, ACCURACY_PHASES, discretization=d, tol=1e-12, threads=1)
            for d in ("rotated", "spectral")}


@pytest.mark.parametrize("discretization", ["rotated", "spectral"])
@pytest.mark.parametrize("tol", [1e-2, 1e-3, 1e-4])
def test_equilibrium_residual_of_the_returned_fields_is_below_tol(exact_fft, discretization, tol):
    """The stopping criterion, recomputed independently: ‖G[σ]‖/‖G[C:E]‖ ≤ tol for the returned stress field.

    CG minimises the energy error, so with δ the error of the strain fluctuation and r = G[σ] (Vondřejc et al.):
    C_JJ(tol) − C_JJ = ⟨δ, C δ⟩ ∈ [‖r‖²/c_max, ‖r‖²/c_min] (diagonal: quadratic in the residual, from above) and
    |C_IJ(tol) − C_IJ| ≤ ‖G[C:E_I]‖ ‖r_J‖/c_min, c_min, c_max the extreme Mandel eigenvalues of the phases: the
    error of C shrinks in proportion to tol (to tol² on the diagonal). C at tol = 1e-12 stands for the exact
    solution of the discrete problem."""
    n = unit_wave_vectors(ACCURACY_IMAGE.shape[0], discretization)
    r = homogenize_fft(ACCURACY_IMAGE, ACCURACY_PHASES, discretization=discretization, tol=tol, threads=1,
                       return_fields=True)
    stiff = np.array(ACCURACY_PHASES)[ACCURACY_IMAGE]                       # (N, N, N, 6, 6) Voigt
    load, residual = np.empty(6), np.empty(6)
    for J in range(6):
        load[J] = projected_rms(np.moveaxis(stiff[..., :, J], -1, 0), n)    # ‖G[C:E_J]‖, E_J = unit Voigt strain
        residual[J] = projected_rms(r.fields["stress"][J], n)
    assert np.all(load > 0)
    assert np.all(residual <= tol * load), residual / load
    assert np.all(residual > 0)
    err = r.C_raw - exact_fft[discretization].C_raw
    roundoff = 1e-12 * np.abs(r.C_raw).max()
    for J in range(6):
        assert residual[J] ** 2 / C_MAX - roundoff <= err[J, J] <= residual[J] ** 2 / C_MIN + roundoff, J
        for I in range(6):
            assert abs(err[I, J]) <= load[I] * residual[J] / C_MIN + roundoff, (I, J)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("scheme", ["cg", "pcg"])
def test_laminate_on_non_cubic_voxels_is_exact(axis, scheme):
    """The grid (8, 12, 6) in the box (0.1, 1, 1) (the equiaxed box of γ = 0.1): voxels 0.0125 × 0.083 × 0.167,
    13× longer along z than along x. A laminate along each axis is still exact."""
    img = np.zeros(BOX_SHAPE, dtype=np.int8)
    index = [slice(None)] * 3
    index[axis] = slice(1, 4)
    img[tuple(index)] = 1
    stiff = isotropic_voigt(1000.0, 0.2)
    r = homogenize_fft(img, [C_SOFT, stiff], box=(0.1, 1.0, 1.0), scheme=scheme, tol=1e-12)
    f = 3 / BOX_SHAPE[axis]
    assert rel(r.C, laminate([C_SOFT, stiff], [1 - f, f], axis)) < 1e-10
