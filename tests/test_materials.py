"""Isotropic and TI material constants: stiffness, engineering constants, Spencer moduli, fits, admissibility."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fenicsfoam.materials import InadmissibleMaterialError, Isotropic, TransverseIsotropic
from homogenization.tensors import (
    VOIGT_PAIRS,
    isotropic_voigt,
    rotate_voigt,
    rotation_from_axis,
    transverse_isotropic_compliance,
)

TI = dict(E_t=3.0e5, E_l=0.4e5, nu_t=0.35, nu_tl=0.15, G_l=0.25e5)
RTOL = 1e3 * np.finfo(float).eps


def spencer_stress(eps: np.ndarray, moduli: dict, a: np.ndarray) -> np.ndarray:
    """σ = λ tr(ε) I + 2μ_T ε + α (tr(Aε) I + tr(ε) A) + 2(μ_L − μ_T)(Aε + εA) + β tr(Aε) A, A = a⊗a."""
    A, I = np.outer(a, a), np.eye(3)
    tr, trA = np.trace(eps), np.sum(A * eps)
    return (moduli["lmbda"] * tr * I + 2 * moduli["mu_T"] * eps + moduli["alpha"] * (trA * I + tr * A)
            + 2 * (moduli["mu_L"] - moduli["mu_T"]) * (A @ eps + eps @ A) + moduli["beta"] * trA * A)


def voigt_columns_of(stress_of_strain) -> np.ndarray:
    """The 6×6 Voigt stiffness of a linear map ε ↦ σ, column J = σ(unit engineering strain J)."""
    C = np.empty((6, 6))
    for J, (k, l) in enumerate(VOIGT_PAIRS):
        eps = np.zeros((3, 3))
        eps[k, l] = eps[l, k] = 1.0 if k == l else 0.5
        sigma = stress_of_strain(eps)
        C[:, J] = [sigma[i, j] for i, j in VOIGT_PAIRS]
    return C


def test_isotropic_matches_tensor_layer():
    m = Isotropic(E=2.0e5, nu=0.3, rho=100.0)
    np.testing.assert_allclose(m.voigt(), isotropic_voigt(2.0e5, 0.3), rtol=RTOL)
    lam, mu = m.lame
    assert lam == pytest.approx(2.0e5 * 0.3 / (1.3 * 0.4), rel=RTOL)
    assert mu == pytest.approx(2.0e5 / 2.6, rel=RTOL)
    c = m.engineering_constants()
    assert c["E1"] == pytest.approx(2.0e5, rel=1e-12) and c["nu12"] == pytest.approx(0.3, rel=1e-12)


def test_transverse_isotropic_engineering_constants_round_trip():
    m = TransverseIsotropic(**TI)
    np.testing.assert_allclose(np.linalg.inv(m.voigt()), transverse_isotropic_compliance(**TI), rtol=1e-12)
    c = m.engineering_constants()
    expected = {"E1": TI["E_t"], "E2": TI["E_t"], "E3": TI["E_l"], "G13": TI["G_l"], "G23": TI["G_l"],
                "G12": TI["E_t"] / (2 * (1 + TI["nu_t"])), "nu12": TI["nu_t"], "nu13": TI["nu_tl"],
                "nu31": TI["nu_tl"] * TI["E_l"] / TI["E_t"]}
    for key, value in expected.items():
        assert c[key] == pytest.approx(value, rel=1e-12), key


@pytest.mark.parametrize("material", [TransverseIsotropic(**TI), Isotropic(E=2.0e5, nu=0.3)], ids=["ti", "iso"])
def test_spencer_form_reproduces_rotated_voigt_stiffness(material):
    """The Spencer moduli in the structural-tensor stress give C rotated so that l = a, for several a."""
    moduli = material.spencer_moduli()
    rng = np.random.default_rng(7)
    for a in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1), rng.standard_normal(3)]:
        a = np.asarray(a, dtype=float) / np.linalg.norm(a)
        expected = rotate_voigt(material.voigt(), rotation_from_axis(a))
        C = voigt_columns_of(lambda eps: spencer_stress(eps, moduli, a))  # noqa: B023
        np.testing.assert_allclose(C, expected, rtol=0, atol=RTOL * np.abs(expected).max())


def test_from_voigt_recovers_constants_and_reports_fit_error():
    axis = np.array([1.0, 2.0, -0.5])
    R = rotation_from_axis(axis)
    C = rotate_voigt(TransverseIsotropic(**TI).voigt(), R)
    fitted, error = TransverseIsotropic.from_voigt(C, axis=axis, rho=50.0)
    assert error < 1e-12
    for key, value in TI.items():
        assert getattr(fitted, key) == pytest.approx(value, rel=1e-10), key
    assert fitted.rho == 50.0
    # A stiffness that is not TI about this axis (a different axis) has a non-zero fit error.
    C_other = rotate_voigt(TransverseIsotropic(**TI).voigt(), Rotation.from_rotvec([0.4, 0.0, 0.0]).as_matrix())
    assert TransverseIsotropic.from_voigt(C_other, axis=2)[1] > 1e-2


@pytest.mark.parametrize("changes, match", [
    ({"E_t": -1.0}, "E_t must be > 0"),
    ({"G_l": 0.0}, "G_l must be > 0"),
    ({"nu_t": 1.0}, "-1 < nu_t < 1"),
    ({"nu_tl": 2.0}, r"1 - nu_t - 2 nu_tl² E_l/E_t > 0"),
    ({"rho": -1.0}, "density must be finite and >= 0"),
])
def test_inadmissible_transverse_isotropic(changes, match):
    with pytest.raises(InadmissibleMaterialError, match=match):
        TransverseIsotropic(**{**TI, **changes})


@pytest.mark.parametrize("kwargs, match", [
    ({"E": 0.0, "nu": 0.3}, "Young's modulus must be > 0"),
    ({"E": 1.0, "nu": 0.5}, "-1 < nu < 0.5"),
    ({"E": 1.0, "nu": 0.3, "rho": float("nan")}, "density must be finite"),
])
def test_inadmissible_isotropic(kwargs, match):
    with pytest.raises(InadmissibleMaterialError, match=match):
        Isotropic(**kwargs)


def test_materials_are_frozen():
    m = Isotropic(E=1.0, nu=0.2)
    with pytest.raises(AttributeError):
        m.E = 2.0
