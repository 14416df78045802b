"""Voigt/Mandel/tensor conversions, TI and isotropic stiffnesses, projections and admissibility."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from homogenization.tensors import (
    InadmissibleMaterialError,
    check_stiffness,
    closest_isotropic,
    closest_transverse_isotropic,
    engineering_constants,
    isotropic_voigt,
    mandel_to_voigt,
    rotate_voigt,
    rotation_from_axis,
    tensor_to_voigt,
    transverse_isotropic_voigt,
    voigt_to_mandel,
    voigt_to_tensor,
)

TI = dict(E_t=3.0, E_l=0.4, nu_t=0.35, nu_tl=0.15, G_l=0.25)
RTOL = 1e3 * np.finfo(float).eps


def random_spd(rng):
    A = rng.standard_normal((6, 6))
    return A @ A.T + 6 * np.eye(6)


def test_compliance_closed_form():
    """The inverse of the TI stiffness is the compliance written in docs/conventions.md."""
    p = TI
    S = np.linalg.inv(transverse_isotropic_voigt(**p))
    G12 = p["E_t"] / (2 * (1 + p["nu_t"]))
    expected = np.zeros((6, 6))
    expected[0, 0] = expected[1, 1] = 1 / p["E_t"]
    expected[2, 2] = 1 / p["E_l"]
    expected[0, 1] = expected[1, 0] = -p["nu_t"] / p["E_t"]
    expected[[0, 1, 2, 2], [2, 2, 0, 1]] = -p["nu_tl"] / p["E_t"]
    expected[3, 3] = expected[4, 4] = 1 / p["G_l"]
    expected[5, 5] = 1 / G12
    np.testing.assert_allclose(S, expected, rtol=RTOL, atol=RTOL * np.abs(expected).max())


def test_ti_stiffness_structure_matches_paper_eq4():
    """Paper eq. (4): C11 = C22, C13 = C23, C44 = C55, C66 = (C11 - C12)/2, no shear coupling."""
    C = transverse_isotropic_voigt(**TI)
    assert C[0, 0] == pytest.approx(C[1, 1], rel=RTOL)
    assert C[0, 2] == pytest.approx(C[1, 2], rel=RTOL)
    assert C[3, 3] == pytest.approx(C[4, 4], rel=RTOL)
    assert C[5, 5] == pytest.approx((C[0, 0] - C[0, 1]) / 2, rel=1e-12)
    assert np.abs(C[:3, 3:]).max() < RTOL * np.abs(C).max()


def test_engineering_constants_isotropic():
    E, nu = 7.0, 0.3
    c = engineering_constants(isotropic_voigt(E, nu))
    for k in ("E1", "E2", "E3"):
        assert c[k] == pytest.approx(E, rel=RTOL)
    for k in ("G23", "G13", "G12"):
        assert c[k] == pytest.approx(E / (2 * (1 + nu)), rel=RTOL)
    for k in ("nu12", "nu13", "nu23", "nu21", "nu31", "nu32"):
        assert c[k] == pytest.approx(nu, rel=RTOL)


def test_engineering_constants_ti_local():
    c = engineering_constants(transverse_isotropic_voigt(**TI))
    assert c["E1"] == pytest.approx(TI["E_t"]) and c["E2"] == pytest.approx(TI["E_t"])
    assert c["E3"] == pytest.approx(TI["E_l"])
    assert c["nu12"] == pytest.approx(TI["nu_t"])
    assert c["nu13"] == pytest.approx(TI["nu_tl"]) and c["nu23"] == pytest.approx(TI["nu_tl"])
    assert c["nu31"] == pytest.approx(TI["nu_tl"] * TI["E_l"] / TI["E_t"])
    assert c["G13"] == pytest.approx(TI["G_l"]) and c["G23"] == pytest.approx(TI["G_l"])
    assert c["G12"] == pytest.approx(TI["E_t"] / (2 * (1 + TI["nu_t"])))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rotating_l_axis_to_each_global_axis(axis):
    """Rotating the TI tensor so its l axis goes to x, y or z moves E_l, nu_tl, G_l there."""
    C = rotate_voigt(transverse_isotropic_voigt(**TI), rotation_from_axis(np.eye(3)[axis]))
    c = engineering_constants(C)
    others = [i for i in range(3) if i != axis]
    assert c[f"E{axis + 1}"] == pytest.approx(TI["E_l"], rel=1e-12)
    for i in others:
        assert c[f"E{i + 1}"] == pytest.approx(TI["E_t"], rel=1e-12)
        assert c[f"nu{i + 1}{axis + 1}"] == pytest.approx(TI["nu_tl"], rel=1e-12)
    i, j = others
    assert c[f"nu{i + 1}{j + 1}"] == pytest.approx(TI["nu_t"], rel=1e-12)
    shear_in_plane = {0: "G23", 1: "G13", 2: "G12"}[axis]
    assert c[shear_in_plane] == pytest.approx(TI["E_t"] / (2 * (1 + TI["nu_t"])), rel=1e-12)
    for g in {"G23", "G13", "G12"} - {shear_in_plane}:
        assert c[g] == pytest.approx(TI["G_l"], rel=1e-12)


def test_random_rotation_and_back_is_identity():
    rng = np.random.default_rng(0)
    C = random_spd(rng)
    for R in Rotation.random(5, random_state=1).as_matrix():
        np.testing.assert_allclose(rotate_voigt(rotate_voigt(C, R), R.T), C, rtol=1e-12, atol=1e-12 * np.abs(C).max())


def test_rotation_preserves_mandel_spectrum():
    """Rotation is an orthogonal change of basis in Mandel space: eigenvalues are invariant."""
    C = transverse_isotropic_voigt(**TI)
    R = Rotation.random(random_state=3).as_matrix()
    e0 = np.linalg.eigvalsh(voigt_to_mandel(C))
    e1 = np.linalg.eigvalsh(voigt_to_mandel(rotate_voigt(C, R)))
    np.testing.assert_allclose(e0, e1, rtol=1e-12)


def test_representation_round_trips():
    C = random_spd(np.random.default_rng(2))
    np.testing.assert_allclose(mandel_to_voigt(voigt_to_mandel(C)), C, rtol=1e-15)
    np.testing.assert_allclose(tensor_to_voigt(voigt_to_tensor(C)), C, rtol=1e-15)
    T = voigt_to_tensor(C)
    np.testing.assert_array_equal(T, T.transpose(1, 0, 2, 3))
    np.testing.assert_array_equal(T, T.transpose(2, 3, 0, 1))


def test_voigt_engineering_shear_convention():
    """σ = C ε with engineering shear: σ12 = G γ12 = 2 G ε12 for an isotropic material."""
    E, nu = 2.0, 0.25
    C = isotropic_voigt(E, nu)
    eps = np.zeros((3, 3))
    eps[0, 1] = eps[1, 0] = 0.01
    sigma = np.einsum("ijkl,kl->ij", voigt_to_tensor(C), eps)
    gamma = np.array([0, 0, 0, 0, 0, 2 * eps[0, 1]])
    assert (C @ gamma)[5] == pytest.approx(sigma[0, 1], rel=1e-14)
    assert sigma[0, 1] == pytest.approx(2 * E / (2 * (1 + nu)) * eps[0, 1], rel=1e-14)


def test_projection_of_exact_ti_is_itself():
    R = Rotation.random(random_state=4).as_matrix()
    a = R[:, 2]
    C = rotate_voigt(transverse_isotropic_voigt(**TI), R)
    fit = closest_transverse_isotropic(C, axis=a)
    assert fit.error < 1e-13
    np.testing.assert_allclose(fit.C, C, atol=1e-12 * np.abs(C).max())
    for k, v in TI.items():
        assert getattr(fit, k) == pytest.approx(v, rel=1e-12)


def test_projection_of_isotropic_is_itself_and_ti_fit_error_positive():
    C = isotropic_voigt(5.0, 0.2)
    fit = closest_isotropic(C)
    assert fit.error < 1e-14
    assert fit.E == pytest.approx(5.0) and fit.nu == pytest.approx(0.2)
    ti = transverse_isotropic_voigt(**TI)
    assert closest_isotropic(ti).error > 0.1
    # TI fit along the wrong axis is worse than along the right one.
    assert closest_transverse_isotropic(ti, axis=0).error > 0.1
    assert closest_transverse_isotropic(ti, axis=2).error < 1e-13


def test_projection_is_orthogonal():
    """The residual of a least-squares projection is orthogonal to the subspace (here: to the fit)."""
    C = random_spd(np.random.default_rng(5))
    for fit in (closest_isotropic(C), closest_transverse_isotropic(C, axis=1)):
        r = voigt_to_mandel(C) - voigt_to_mandel(fit.C)
        assert abs(np.sum(r * voigt_to_mandel(fit.C))) < 1e-10 * np.sum(voigt_to_mandel(C) ** 2)


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(E_t=-1.0), "E_t must be > 0"),
        (dict(E_l=0.0), "E_l must be > 0"),
        (dict(G_l=-0.1), "G_l must be > 0"),
        (dict(nu_t=1.0), "-1 < nu_t < 1"),
        (dict(nu_t=-1.0), "-1 < nu_t < 1"),
        (dict(nu_tl=float("nan")), "nu_tl must be finite"),
        (dict(E_l=30.0, nu_tl=0.45), r"1 - nu_t - 2 nu_tl² E_l/E_t > 0"),
    ],
)
def test_ti_admissibility_errors(bad, match):
    with pytest.raises(InadmissibleMaterialError, match=match):
        transverse_isotropic_voigt(**{**TI, **bad})


def test_ti_admissibility_boundary_is_sharp():
    """Just inside the nu_tl bound the compliance is positive definite; the condition is the exact one."""
    nu_max = np.sqrt((1 - TI["nu_t"]) * TI["E_t"] / (2 * TI["E_l"]))
    C = transverse_isotropic_voigt(**{**TI, "nu_tl": 0.999 * nu_max})
    assert np.linalg.eigvalsh(voigt_to_mandel(C)).min() > 0
    with pytest.raises(InadmissibleMaterialError):
        transverse_isotropic_voigt(**{**TI, "nu_tl": 1.001 * nu_max})


@pytest.mark.parametrize("E, nu, match", [(0.0, 0.3, "Young's modulus"), (1.0, 0.5, "Poisson"), (1.0, -1.0, "Poisson")])
def test_isotropic_admissibility_errors(E, nu, match):
    with pytest.raises(InadmissibleMaterialError, match=match):
        isotropic_voigt(E, nu)


def test_check_stiffness_errors():
    C = isotropic_voigt(1.0, 0.3)
    C_asym = C.copy()
    C_asym[0, 1] += 0.1
    with pytest.raises(InadmissibleMaterialError, match="not symmetric"):
        check_stiffness(C_asym)
    C_indef = C.copy()
    C_indef[3, 3] = -0.1
    with pytest.raises(InadmissibleMaterialError, match="not positive definite"):
        check_stiffness(C_indef)
    with pytest.raises(InadmissibleMaterialError, match="void phase"):
        check_stiffness(np.zeros((6, 6)))
    check_stiffness(np.zeros((6, 6)), allow_zero=True)
    with pytest.raises(ValueError, match="6×6"):
        check_stiffness(np.eye(3))


def test_result_symmetrises_and_reports_asymmetry():
    from homogenization.result import HomogenizationResult

    C = transverse_isotropic_voigt(**TI)
    C_raw = C.copy()
    C_raw[0, 1] += 1e-3 * np.abs(C).max()
    r = HomogenizationResult.from_columns(C_raw, method="test", iterations=[1] * 6, residuals=[[0.0]] * 6, wall_s=0.0)
    np.testing.assert_array_equal(r.C, r.C.T)
    assert r.asymmetry == pytest.approx(1e-3)
    d = r.to_dict()
    assert d["ti_fit"]["axis"] == [1.0, 0.0, 0.0] and d["asymmetry"] == pytest.approx(1e-3)
