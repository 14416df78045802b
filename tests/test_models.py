"""The hyperelastic Bonet–Burton model and SOFA's corotational element: tangents (Taylor), frame invariance, the
small-strain limit against the linear TI stiffness, strong ellipticity against an independent numpy computation,
and serial = MPI."""

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI
from scipy.spatial.transform import Rotation

from fenicsfoam import orientation
from fenicsfoam.bcs import RigidMotion
from fenicsfoam.constitutive import MODELS, EdgeRotation, MaterialField, edge_frame
from fenicsfoam.materials import TransverseIsotropic
from fenicsfoam.sensitivity import Adjoint
from fenicsfoam.solver import ElasticityProblem, LoadStep
from fenicsfoam.stability import acoustic_margin, ellipticity_margin
from foambase.errors import InputError
from homogenization.tensors import VOIGT_PAIRS, rotate_voigt, rotation_from_axis

#: The paper's foam as its SOFA simulation used it (kPa → Pa; see studies/tripod_models.py), and a tamer TI.
PAPER_FOAM = TransverseIsotropic(E_t=1390e3, E_l=94.22e3, nu_t=0.26162, nu_tl=0.4161, G_l=16.28215e3, rho=180.0)
TI = TransverseIsotropic(E_t=3.0e5, E_l=0.4e5, nu_t=0.35, nu_tl=0.15, G_l=0.25e5, rho=200.0)
#: A mildly anisotropic TI (G_l near the in-plane shear modulus), for which Bonet–Burton stays elliptic in the solve.
MILD = TransverseIsotropic(E_t=3.0e5, E_l=2.0e5, nu_t=0.3, nu_tl=0.2, G_l=0.9e5, rho=200.0)
AXIS = np.array([0.48, -0.6, 0.64])
NEW = ("bonet_burton", "corotational_sofa")
ONE_RANK_SKIP = pytest.mark.skipif(MPI.COMM_WORLD.size < 2, reason="compares COMM_WORLD with COMM_SELF (mpirun -n 2)")


@pytest.fixture(scope="module")
def cell():
    """One unit cube of six tetrahedra (COMM_SELF), P1, a TI field with l along AXIS."""
    msh = mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)
    V = fem.VectorFunctionSpace(msh, ("CG", 1))
    return msh, V, orientation.uniform(msh, tuple(AXIS))


def homogeneous(V, H):
    u = fem.Function(V)
    u.interpolate(lambda x: H @ x)
    return u


def piola(model, u, field, a):
    """``P`` of the model at ``u`` on cell 0 (P1: uniform), with the model's rotation updated."""
    rotation = MODELS[model].rotation_field(u, 0) if MODELS[model].needs_rotation else None
    if rotation is not None:
        rotation.update()
    P = MODELS[model].first_piola_kirchhoff(u, field, a, rotation)
    return fem.Expression(P, np.array([[0.25, 0.25, 0.25]])).eval(np.array([0], dtype=np.int32)).reshape(3, 3)


def bonet_burton_piola(F, m, a):
    """Independent numpy Bonet–Burton stress (Spencer moduli ``m``, unit axis ``a``)."""
    J, Finv_T = np.linalg.det(F), np.linalg.inv(F).T
    C = F.T @ F
    I4 = a @ C @ a
    ca, cb, cc = m["mu_T"] - m["mu_L"], 0.5 * m["alpha"], 0.125 * m["beta"]
    P = m["mu_T"] * (F - Finv_T) + m["lmbda"] * (J - 1) * J * Finv_T + cb * (I4 - 1) * Finv_T
    P += 2 * (ca + cb * np.log(J) + 2 * cc * (I4 - 1)) * np.outer(F @ a, a)
    P -= ca * F @ (np.outer(a, C @ a) + np.outer(C @ a, a))
    return P


def numpy_margin(F, m, a, h=1e-6):
    """Acoustic margin of the central-difference tangent of :func:`bonet_burton_piola` (acoustic_margin)."""
    A = np.empty((3, 3, 3, 3))
    for k in range(3):
        for l in range(3):  # noqa: E741
            dF = np.zeros((3, 3))
            dF[k, l] = h
            A[:, :, k, l] = (bonet_burton_piola(F + dF, m, a) - bonet_burton_piola(F - dF, m, a)) / (2 * h)
    return acoustic_margin(A[None], directions=1024)[0][0]


@pytest.mark.parametrize("model", NEW)
def test_small_strain_tangent_is_the_linear_ti_stiffness(cell, model):
    """∂P/∂F at F = I, column by column, equals TransverseIsotropic.voigt() rotated so that l = AXIS."""
    msh, V, a = cell
    field = MaterialField.uniform(msh, PAPER_FOAM)
    u, w = fem.Function(V), fem.Function(V)
    rotation = MODELS[model].rotation_field(u, 0) if MODELS[model].needs_rotation else None
    if rotation is not None:
        rotation.update()
    dP = ufl.derivative(MODELS[model].first_piola_kirchhoff(u, field, a, rotation), u, w)
    expr = fem.Expression(dP, np.array([[0.25, 0.25, 0.25]]))
    C = np.empty((6, 6))
    for J, (k, l) in enumerate(VOIGT_PAIRS):
        e = np.zeros((3, 3))
        e[k, l] = e[l, k] = 1.0 if k == l else 0.5
        w.interpolate(lambda x, e=e: e @ x)
        s = expr.eval(np.array([0], dtype=np.int32)).reshape(3, 3)
        C[:, J] = [s[i, j] for i, j in VOIGT_PAIRS]
    expected = rotate_voigt(PAPER_FOAM.voigt(), rotation_from_axis(AXIS))
    np.testing.assert_allclose(C, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


@pytest.mark.parametrize("model", NEW)
def test_frame_invariance(cell, model):
    """P(QF) = Q P(F) and ψ(QF) = ψ(F) for a finite deformation and a superposed rotation Q."""
    msh, V, a = cell
    field = MaterialField.uniform(msh, TI)
    G = np.array([[0.12, 0.3, -0.05], [-0.1, -0.15, 0.2], [0.08, 0.1, 0.25]])
    Q = Rotation.from_rotvec([0.4, -1.3, 0.7]).as_matrix()
    values = []
    for H in (G, Q @ (np.eye(3) + G) - np.eye(3)):
        u = homogeneous(V, H)
        rotation = MODELS[model].rotation_field(u, 0) if MODELS[model].needs_rotation else None
        if rotation is not None:
            rotation.update()
        psi = fem.assemble_scalar(fem.form(MODELS[model].energy(u, field, a, rotation) * ufl.dx))
        values.append((piola(model, u, field, a), psi))
    (P0, psi0), (P1, psi1) = values
    assert psi0 > 0.0
    assert psi1 == pytest.approx(psi0, rel=1e-12)
    np.testing.assert_allclose(P1, Q @ P0, atol=1e-11 * np.abs(P0).max())


def test_bonet_burton_stress_matches_an_independent_numpy_implementation(cell):
    msh, V, a = cell
    field = MaterialField.uniform(msh, PAPER_FOAM)
    G = np.array([[0.12, 0.3, -0.05], [-0.1, -0.15, 0.2], [0.08, 0.1, 0.25]])
    P = piola("bonet_burton", homogeneous(V, G), field, a)
    expected = bonet_burton_piola(np.eye(3) + G, PAPER_FOAM.spencer_moduli(), AXIS / np.linalg.norm(AXIS))
    np.testing.assert_allclose(P, expected, atol=1e-10 * np.abs(expected).max())


def taylor_remainders(problem, direction, steps, update_rotation=True):
    """|R(u + h v) - R(u) - h J(u) v| for each h, with the unconstrained residual and Jacobian forms."""
    u = problem.u
    u0 = u.x.array.copy()
    rotation = problem.rotation
    if rotation is not None:
        rotation.update()
    residual, jacobian = fem.form(problem.residual_form), fem.form(problem.jacobian_form)
    R0 = fem.petsc.assemble_vector(residual)
    J = fem.petsc.assemble_matrix(jacobian)
    J.assemble()
    v = R0.duplicate()
    v.array[:] = direction
    Jv = R0.duplicate()
    J.mult(v, Jv)
    out = []
    for h in steps:
        u.x.array[:] = u0 + h * direction
        if rotation is not None and update_rotation:
            rotation.update()
        Rh = fem.petsc.assemble_vector(residual)
        out.append((Rh - R0 - h * Jv).norm())
    u.x.array[:] = u0
    if rotation is not None:
        rotation.update()
    return np.array(out)


@pytest.fixture(scope="module")
def deformed_problems():
    """Bonet–Burton and the SOFA element on a 2×2×2 cube at a finite homogeneous deformation plus a perturbation."""
    msh = mesh.create_unit_cube(MPI.COMM_SELF, 2, 2, 2)
    field = MaterialField.uniform(msh, TI)
    a = orientation.uniform(msh, tuple(AXIS))
    rng = np.random.default_rng(5)
    out = {}
    for model in NEW:
        problem = ElasticityProblem(msh, field, orientation=a, model=model, prefix=f"taylor_{model}_")
        G = np.array([[0.1, 0.25, 0.0], [-0.2, -0.1, 0.1], [0.05, 0.0, 0.15]])
        problem.u.interpolate(lambda x, G=G: G @ x)
        problem.u.x.array[:] += 0.02 * rng.standard_normal(problem.u.x.array.size)
        out[model] = problem, 0.1 * rng.standard_normal(problem.u.x.array.size)
    return out


def test_bonet_burton_tangent_is_consistent(deformed_problems):
    """Taylor remainder of the exact tangent: second order (ratio 4 when h halves)."""
    problem, v = deformed_problems["bonet_burton"]
    r = taylor_remainders(problem, v, [1e-2, 5e-3, 2.5e-3])
    np.testing.assert_allclose(r[:-1] / r[1:], 4.0, rtol=0.05)


def test_sofa_tangent_is_the_derivative_at_frozen_rotation_only(deformed_problems):
    """The SOFA element's tangent is exact with R held fixed (the residual is then affine in u: remainder at
    round-off) but not with R following u (remainder O(h): ratio 2 when h halves)."""
    problem, v = deformed_problems["corotational_sofa"]
    moving = taylor_remainders(problem, v, [1e-2, 5e-3, 2.5e-3], update_rotation=True)
    np.testing.assert_allclose(moving[:-1] / moving[1:], 2.0, rtol=0.05)
    frozen = taylor_remainders(problem, v, [1e-2, 5e-3, 2.5e-3], update_rotation=False)
    assert frozen.max() < 1e-9 * moving.min()
    assert MODELS["corotational_sofa"].exact_tangent is False
    with pytest.raises(InputError, match="corotational_sofa.*approximate"):
        Adjoint(problem)


def test_edge_rotation_is_the_frame_of_the_current_edges():
    """On one tetrahedron, R = G(current edges) G(rest edges)ᵀ from the vertex coordinates; R(QF) = Q R(F)."""
    msh = mesh.create_mesh(MPI.COMM_SELF, np.array([[0, 1, 2, 3]], dtype=np.int64),
                           np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.0], [0.3, 0.9, 0.1], [0.2, 0.1, 0.8]]),
                           ufl.Mesh(ufl.VectorElement("Lagrange", "tetrahedron", 1)))
    V = fem.VectorFunctionSpace(msh, ("CG", 1))
    x = msh.geometry.x[msh.geometry.dofmap.links(0)]
    G = np.array([[0.1, 0.25, 0.0], [-0.2, -0.1, 0.1], [0.05, 0.0, 0.15]])
    Q = Rotation.from_rotvec([0.2, 0.9, -0.4]).as_matrix()
    rotations = []
    for F in (np.eye(3) + G, Q @ (np.eye(3) + G)):
        u = homogeneous(V, F - np.eye(3))
        rotation = EdgeRotation(u, 0)
        rotation.update()
        R = rotation.R.x.array.reshape(3, 3)
        y = x @ F.T
        expected = (edge_frame((y[1] - y[0])[None], (y[2] - y[0])[None])[0]
                    @ edge_frame((x[1] - x[0])[None], (x[2] - x[0])[None])[0].T)
        np.testing.assert_allclose(R, expected, atol=1e-14)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(R) == pytest.approx(1.0)
        rotations.append(R)
    np.testing.assert_allclose(rotations[1], Q @ rotations[0], atol=1e-14)
    assert np.abs(rotations[0] - np.eye(3)).max() > 0.1


COMPRESSIONS = (0.95, 0.9, 0.8, 0.7, 0.6)


def test_ellipticity_over_compressions_with_the_paper_foam(cell):
    """Acoustic margins of uniaxial compressions along l and across l and simple shears, paper's foam:
    the SOFA element's (frozen-R) tangent keeps the linear law's margin G_l whatever the deformation;
    Bonet–Burton's margin equals that of an independent numpy tangent (finite differences), positive in every
    compression along l (to 0.6), lost across l between stretches 0.8 and 0.7 and in tension or shear of 5 %."""
    msh, V, a = cell
    field = MaterialField.uniform(msh, PAPER_FOAM)
    axis = AXIS / np.linalg.norm(AXIS)
    across = rotation_from_axis(axis)[:, 0]
    m = PAPER_FOAM.spencer_moduli()
    deformations = [np.eye(3) + (s - 1) * np.outer(d, d) for d in (axis, across) for s in (*COMPRESSIONS, 1.05)]
    deformations += [np.eye(3) + g * np.outer(across, axis) for g in (0.05, 0.2)]
    bb = {}
    for F in deformations:
        u = homogeneous(V, F - np.eye(3))
        sofa = ellipticity_margin(u, "corotational_sofa", field, a, directions=64)
        assert sofa.min_margin == pytest.approx(PAPER_FOAM.G_l, rel=1e-6) and not sofa.lost
        check = ellipticity_margin(u, "bonet_burton", field, a, directions=1024)
        expected = numpy_margin(F, m, axis)
        assert check.min_margin == pytest.approx(expected, rel=1e-4, abs=1e-3 * PAPER_FOAM.G_l)
        bb[tuple(F.ravel())] = check
    margins = [c.min_margin for c in bb.values()]
    along, across_, shears = margins[:6], margins[6:12], margins[12:]
    assert all(v > 0 for v in along[:5])
    assert all(v > 0 for v in across_[:3]) and all(v < 0 for v in across_[3:])
    assert along[5] < 0 and all(v < 0 for v in shears)
    assert all(c.lost_cells == 6 for c in bb.values() if c.min_margin < 0)


def small_solve(comm, model, options=None, tag=""):
    """A TI block clamped at x = 0, compressed 3 %, lifted and turned at x = 1, under gravity: the mean displacement."""
    msh = mesh.create_box(comm, [[0, 0, 0], [1.0, 0.3, 0.3]], [6, 2, 2])
    field = MaterialField.uniform(msh, MILD)
    a = orientation.uniform(msh, tuple(AXIS))
    clamp = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 0.0))
    end = mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[0], 1.0))
    motions = [RigidMotion("clamp", clamp), RigidMotion("end", end, axis=(0, 0, 1), point=(1.0, 0.15, 0.15))]
    problem = ElasticityProblem(msh, field, orientation=a, model=model, motions=motions, gravity=(0, 0, -9.81),
                                prefix=f"small_{model}_{comm.size}{tag}_", options=options)
    problem.run([LoadStep("load", gravity=1.0, angles={"end": 0.1}, translations={"end": (-0.03, 0.0, 0.02)},
                          increments=2)])
    mean = [comm.allreduce(fem.assemble_scalar(fem.form(problem.u[i] * ufl.dx)), op=MPI.SUM) for i in range(3)]
    return np.array(mean) / 0.09


def test_sofa_equilibrium_is_the_same_with_the_frozen_tangent_alone():
    """The default Newton system of the SOFA element (exact Jacobian matrix-free, preconditioned by the frozen-R
    tangent) and plain iterations with the frozen-R tangent (SOFA's own) reach the same equilibrium."""
    default = small_solve(MPI.COMM_SELF, "corotational_sofa")
    frozen = small_solve(MPI.COMM_SELF, "corotational_sofa", tag="frozen",
                         options={"snes_mf_operator": False, "ksp_type": "preonly", "snes_max_it": 400})
    assert np.abs(default).max() > 1e-3
    np.testing.assert_allclose(default, frozen, rtol=1e-7, atol=1e-10)


@pytest.mark.mpi
@ONE_RANK_SKIP
@pytest.mark.parametrize("model", NEW)
def test_serial_equals_mpi(model):
    parallel = small_solve(MPI.COMM_WORLD, model)
    serial = small_solve(MPI.COMM_SELF, model)
    assert np.abs(parallel).max() > 1e-3
    np.testing.assert_allclose(parallel, serial, rtol=1e-8, atol=1e-10)


@pytest.mark.slow
def test_bonet_burton_adjoint_gradient_is_second_order_accurate():
    """The design code's adjoint gradient with the hyperelastic model (isotropic beam: compressible neo-Hooke; the TI
    foams lose ellipticity under the beam's own weight with this model): Taylor remainders of order 2 in E_solid."""
    from test_sensitivity import SIGNIFICANT, assert_second_order, scene, taylor

    from fenicsfoam.design import SceneDesign

    design = SceneDesign(scene("beam_iso", 0.0075, table="cube", **{"fem.model": "bonet_burton"}))
    base = design.solve()
    gradients = design.gradient(list(base), ["E_solid"])
    slopes, remainders = taylor(design, base, gradients, "E_solid", 2e6)
    assert_second_order(slopes, remainders, SIGNIFICANT, "bonet_burton E_solid")
