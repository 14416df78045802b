"""UFL constitutive layer: the Spencer TI stress against rotated Voigt stiffnesses, strain measures, polar rotation."""

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from fenicsfoam import orientation
from fenicsfoam.constitutive import (
    MaterialField,
    PolarRotation,
    polar_rotation,
    strain_energy_density,
    stress,
)
from fenicsfoam.materials import Isotropic, TransverseIsotropic
from homogenization.tensors import VOIGT_PAIRS, rotate_voigt, rotation_from_axis

TI = TransverseIsotropic(E_t=3.0e5, E_l=0.4e5, nu_t=0.35, nu_tl=0.15, G_l=0.25e5)
ISO = Isotropic(E=2.0e5, nu=0.3)


@pytest.fixture(scope="module")
def unit_cube():
    return mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)


@pytest.mark.parametrize("material", [TI, ISO], ids=["ti", "iso"])
def test_ufl_stress_is_the_rotated_voigt_stiffness(unit_cube, material):
    """σ(ε) of the UFL form, column by column, equals the Voigt stiffness rotated so that l = a."""
    field = MaterialField.uniform(unit_cube, material)
    assert field.isotropic == isinstance(material, Isotropic)
    a = None if field.isotropic else orientation.uniform(unit_cube, (0.0, 0.0, 1.0))
    eps = fem.Constant(unit_cube, np.zeros((3, 3)))
    sigma = fem.Expression(stress(eps, field, a), np.array([[0.25, 0.25, 0.25]]))
    rng = np.random.default_rng(3)
    directions = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1), rng.standard_normal(3)]
    for d in directions:
        d = np.asarray(d, dtype=float) / np.linalg.norm(d)
        if a is not None:
            a.x.array.reshape(-1, 3)[:] = d
        C = np.empty((6, 6))
        for J, (k, l) in enumerate(VOIGT_PAIRS):
            e = np.zeros((3, 3))
            e[k, l] = e[l, k] = 1.0 if k == l else 0.5  # unit engineering strain J
            eps.value[:] = e
            s = sigma.eval(np.array([0], dtype=np.int32)).reshape(3, 3)
            C[:, J] = [s[i, j] for i, j in VOIGT_PAIRS]
        expected = rotate_voigt(material.voigt(), rotation_from_axis(d))
        np.testing.assert_allclose(C, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_polar_rotation_matches_scipy():
    rng = np.random.default_rng(0)
    n = 500
    stretches = np.exp(rng.uniform(np.log(0.5), np.log(2.0), (n, 3)))
    Q1 = Rotation.random(n, random_state=1).as_matrix()
    Q2 = Rotation.random(n, random_state=2).as_matrix()
    F = Q1 @ (stretches[:, :, None] * Q2)
    R = polar_rotation(F)
    expected = np.array([polar(f)[0] for f in F])
    np.testing.assert_allclose(R, expected, atol=1e-13)
    # A rotation is its own polar factor.
    np.testing.assert_allclose(polar_rotation(Q1), Q1, atol=1e-15)


def test_strain_energies_of_a_rotated_uniaxial_stretch(unit_cube):
    """ψ for u = (Q diag(λ, 1, 1) - I) X: the closed forms ½ C11 e² with e = λ - 1 (linear, corotational) and
    e = (λ² - 1)/2 (svk); svk and corotational are invariant under Q, the linear model is not."""
    lam = 1.2
    field = MaterialField.uniform(unit_cube, ISO)
    C11 = ISO.voigt()[0, 0]
    V = fem.VectorFunctionSpace(unit_cube, ("CG", 1))
    u = fem.Function(V)
    rotation = PolarRotation(u, 0)
    energies = {model: fem.form(strain_energy_density(model, u, field, None, rotation) * ufl.dx)
                for model in ("linear", "svk", "corotational")}
    expected = {"linear": 0.5 * C11 * (lam - 1) ** 2, "svk": 0.5 * C11 * ((lam**2 - 1) / 2) ** 2,
                "corotational": 0.5 * C11 * (lam - 1) ** 2}
    for rotated, Q in ((False, np.eye(3)), (True, Rotation.from_rotvec([0.3, -1.2, 0.9]).as_matrix())):
        H = Q @ np.diag([lam, 1.0, 1.0]) - np.eye(3)
        u.interpolate(lambda x: H @ x)  # noqa: B023
        rotation.update()
        for model, form in energies.items():
            psi = fem.assemble_scalar(form)
            if model == "linear" and rotated:
                assert abs(psi - expected[model]) > 0.1 * expected[model]  # not frame invariant
            else:
                assert psi == pytest.approx(expected[model], rel=1e-12), model
