"""Strong ellipticity (fenicsfoam.stability): the acoustic-tensor margin against closed forms, and the
diagnosis a failed load step carries."""

import numpy as np
import pytest
from dolfinx import mesh
from mpi4py import MPI

from fenicsfoam import orientation
from fenicsfoam.bcs import RigidMotion
from fenicsfoam.constitutive import MODELS, MaterialField
from fenicsfoam.materials import Isotropic, TransverseIsotropic
from fenicsfoam.solver import ConvergenceError, ElasticityProblem, LoadStep
from fenicsfoam.stability import acoustic_margin, ellipticity_margin, hemisphere_directions

#: The Fig. 6 foam (18 %, gamma 0.1) as explicit constants: foam_material(0.18, 0.1, 12e6, 0.3, 1190, "transverse").
FOAM = TransverseIsotropic(E_t=748164.5, E_l=4662.9, nu_t=0.3636, nu_tl=1.0983, G_l=6815.0, rho=214.2)
IRON = Isotropic(E=1e6, nu=0.3)


def isotropic_tangent(lam: float, mu: float) -> np.ndarray:
    """``A_ijkl = λ δ_ij δ_kl + μ (δ_ik δ_jl + δ_il δ_jk)``: the tangent of every model at rest."""
    d = np.eye(3)
    return lam * np.einsum("ij,kl->ijkl", d, d) + mu * (np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d))


@pytest.fixture(scope="module")
def cube():
    return mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2)


def test_hemisphere_directions_are_unit_and_refuse_bad_counts():
    n = hemisphere_directions(100)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-14)
    assert n.shape == (100, 3) and (n[:, 2] > 0).all()
    with pytest.raises(ValueError, match="count must be an integer >= 1, got 0"):
        hemisphere_directions(0)
    with pytest.raises(ValueError, match=r"A must have shape \(p, 3, 3, 3, 3\), got \(3, 3, 3, 3\)"):
        acoustic_margin(isotropic_tangent(1.0, 1.0))


@pytest.mark.parametrize(("lam", "mu"), [(2.0, 1.0), (-1.5, 1.0), (-3.0, 1.0), (1.0, -0.5)])
def test_isotropic_margin_is_min_of_mu_and_lambda_plus_two_mu(lam, mu):
    """``Q(n) = μ I + (λ + μ) n⊗n`` for every n: eigenvalues μ (twice, m ⊥ n) and λ + 2μ (m = n)."""
    margin, normal, m = acoustic_margin(isotropic_tangent(lam, mu)[None])
    assert margin[0] == pytest.approx(min(mu, lam + 2 * mu), rel=1e-12)
    expected_alignment = 1.0 if lam + 2 * mu < mu else 0.0  # the longitudinal wave (m = ±n) is the softest
    assert abs(m[0] @ normal[0]) == pytest.approx(expected_alignment, abs=1e-8)


def test_margin_of_random_tangents_matches_dense_sampling():
    """Sampling + pattern search reach the minimum found on 200 000 directions (never above it by more than
    the dense sampling's own error), and m·Q(n)·m equals the margin."""
    rng = np.random.default_rng(1)
    A = isotropic_tangent(2.0, 1.0) + 0.3 * rng.standard_normal((5, 3, 3, 3, 3))
    margin, normal, m = acoustic_margin(A)
    dense = hemisphere_directions(200_000)
    for a, value, n, mi in zip(A, margin, normal, m):
        Q = np.einsum("ijkl,dj,dl->dik", a, dense, dense)
        brute = np.linalg.eigvalsh(0.5 * (Q + Q.swapaxes(1, 2)))[:, 0].min()
        assert brute - 1e-4 < value <= brute + 1e-12
        assert mi @ np.einsum("ijkl,j,l->ik", a, n, n) @ mi == pytest.approx(value, rel=1e-12)


@pytest.mark.mpi
@pytest.mark.parametrize(("model", "degree"), [(m, 1) for m in MODELS] + [("corotational", 2)])
def test_isotropic_material_at_rest_has_the_closed_form_margin_everywhere(cube, model, degree):
    """At u = 0 every model's tangent is the isotropic stiffness: margin min(μ, λ + 2μ) = μ in every cell."""
    problem = ElasticityProblem(cube, MaterialField.uniform(cube, IRON), model=model, degree=degree,
                                prefix=f"rest_{model}{degree}_")
    check = ellipticity_margin(problem.u, model, problem.material)  # standalone: its own rotation and quadrature
    lam, mu = IRON.lame
    assert check.min_margin == pytest.approx(min(mu, lam + 2 * mu), rel=1e-12)
    np.testing.assert_allclose(check.margin.x.array, mu, rtol=1e-12)
    assert not check.lost and check.lost_cells == 0 and check.n_cells == 48
    assert "strongly elliptic in all 48 cells" in str(check)


@pytest.mark.mpi
def test_ti_corotational_compressed_across_l_loses_ellipticity_at_the_analytic_threshold(cube):
    """Corotational TI (l = z), homogeneous ``F = diag(λ, 1, 1)`` (compression along the transverse axis x).

    Then ``R = I``, ``U = F``, ``σ_xx = C11 (λ - 1)`` (C11 the transverse uniaxial-strain modulus). For the
    band normal ``n = e_x`` and polarization ``m = e_z``, ``dF = e_z⊗e_x`` and the exact tangent
    (:func:`~fenicsfoam.constitutive.corotational_rotation_tangent`) gives ``σ(sym dF)_zx = G_l``,
    ``ω = 2 (tr U I - U)⁻¹ axial(dF) = -e_y / (1 + λ)``, ``(Ωσ)_zx = σ_xx / (1 + λ)`` and
    ``σ(sym(ΩU))_zx = G_l (λ - 1)/(λ + 1)``, so

        m·Q(n)·m = (2 G_l + σ_xx) / (1 + λ),

    which vanishes at ``σ_xx = -2 G_l``: ``λ_c = 1 - 2 G_l / C11`` (kink-band micro-buckling; the
    corotational tangent carries half the geometric term of a hyperelastic one, hence 2 G_l where Rosen's
    estimate for the latter is G_l). For the Fig. 6 foam this is the minimum over all n, m (checked here
    by the sampled minimum), λ_c = 0.98445.
    """
    a = orientation.uniform(cube, (0.0, 0.0, 1.0))
    problem = ElasticityProblem(cube, MaterialField.uniform(cube, FOAM), orientation=a, model="corotational",
                                prefix="kink_")
    C11 = FOAM.voigt()[0, 0]
    critical = 1.0 - 2.0 * FOAM.G_l / C11
    assert critical == pytest.approx(0.98445, abs=1e-5)
    for stretch in (0.99, critical * (1 + 1e-4), critical, critical * (1 - 1e-4), 0.95):
        problem.u.interpolate(lambda x, s=stretch: np.stack([(s - 1.0) * x[0], 0.0 * x[0], 0.0 * x[0]]))
        check = problem.ellipticity_margin()
        closed_form = (2.0 * FOAM.G_l + C11 * (stretch - 1.0)) / (1.0 + stretch)
        assert check.min_margin == pytest.approx(closed_form, rel=1e-6, abs=1e-6 * FOAM.G_l)
        np.testing.assert_allclose(check.margin.x.array, check.min_margin, rtol=1e-9, atol=1e-6 * FOAM.G_l)
        assert abs(check.normal[0]) == pytest.approx(1.0, abs=1e-6)
        assert abs(check.polarization[2]) == pytest.approx(1.0, abs=1e-6)
        assert check.lost_cells == (48 if stretch < critical * (1 - 1e-6) else 0)


@pytest.mark.mpi
def test_failed_step_reports_whether_ellipticity_is_lost(cube):
    """Squeezing the foam cube along x (l = z) by 5 % converges (|σ_xx| ≈ 37 kPa > 2 G_l = 13.6 kPa, so
    ellipticity is lost); a further squeeze to 10 % of the length then fails (inverted elements after the
    cut-backs) and the error names the lost cells; the same failure from rest, with a stable material
    (isotropic), says the tangent was elliptic everywhere."""
    left, right = (mesh.locate_entities_boundary(cube, 2, lambda x, v=v: np.isclose(x[0], v)) for v in (0.0, 1.0))
    a = orientation.uniform(cube, (0.0, 0.0, 1.0))
    problem = ElasticityProblem(cube, MaterialField.uniform(cube, FOAM), orientation=a, model="corotational",
                                motions=[RigidMotion("left", left), RigidMotion("right", right)],
                                prefix="squeeze_x_", max_cutbacks=2)
    problem.solve_step(LoadStep("squeeze", translations={"right": (-0.05, 0.0, 0.0)}, increments=1))
    with pytest.raises(ConvergenceError, match=r"load step 'crush' failed .* strong ellipticity lost in \d+ of 48 "
                                               r"cells .*a material instability") as failure:
        problem.solve_step(LoadStep("crush", translations={"right": (-0.9, 0.0, 0.0)}, increments=1))
    check = failure.value.ellipticity
    assert check.lost and check.min_margin < 0 and abs(check.normal[0]) > 0.9
    owned = check.margin.function_space.dofmap.index_map.size_local   # DG0: one value per cell, owned ones first
    lost = cube.comm.allreduce(int(np.count_nonzero(check.margin.x.array[:owned] <= 0)), op=MPI.SUM)
    assert check.lost_cells == lost > 0

    stable = ElasticityProblem(cube, MaterialField.uniform(cube, IRON), model="corotational",
                               motions=[RigidMotion("left", left), RigidMotion("right", right)],
                               prefix="squeeze_iso_", max_cutbacks=0, options={"snes_max_it": 1})
    with pytest.raises(ConvergenceError, match="DIVERGED_MAX_IT; .* strongly elliptic in all 48 cells") as failure:
        stable.solve_step(LoadStep("crush", translations={"right": (-0.2, 0.0, 0.0)}))
    assert not failure.value.ellipticity.lost
