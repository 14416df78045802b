"""The SNES elasticity problem: patch tests, frame invariance, consistent tangents, Newton's rate, cantilever
against beam theory, prescribed rigid motions, load stepping errors, options, serial vs MPI."""

from dataclasses import dataclass

import basix
import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI
from petsc4py import PETSc
from scipy.spatial.transform import Rotation

from fenicsfoam import orientation
from fenicsfoam.bcs import RigidMotion, rotation_matrix
from fenicsfoam.constitutive import MODELS, MaterialField
from fenicsfoam.materials import Isotropic, TransverseIsotropic
from fenicsfoam.solver import ConvergenceError, ElasticityProblem, LoadStep
from homogenization.tensors import VOIGT_PAIRS, rotate_voigt, rotation_from_axis

ONE_RANK_SKIP = pytest.mark.skipif(
    MPI.COMM_WORLD.size < 2,
    reason="compares a COMM_WORLD run with a COMM_SELF run: on one rank they are the same computation "
           "(runs under mpirun -n 2)")

# A soft TI foam-like material (Pa, kg/m³): soft along l, as the paper's γ < 1 foams.
TI = TransverseIsotropic(E_t=1.15e6, E_l=0.4e6, nu_t=0.3, nu_tl=0.15, G_l=0.2e6, rho=216.0)
UNIT_TI = TransverseIsotropic(E_t=3.0, E_l=0.4, nu_t=0.35, nu_tl=0.15, G_l=0.25)
ROTATED_AXIS = np.array([0.48, -0.6, 0.64])


def residual(problem, u_values=None):
    """The assembled residual (with Dirichlet rows) at the current ``u`` or at ``u_values``."""
    x = problem.u.vector.copy()
    if u_values is not None:
        x.array[:] = u_values
    b = x.duplicate()
    problem.snes.computeFunction(x, b)
    return b


def face(msh, axis, value):
    return mesh.locate_entities_boundary(msh, 2, lambda x: np.isclose(x[axis], value))


@pytest.fixture(scope="module")
def cube():
    return mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2)


@pytest.fixture(scope="module")
def free_cube_problems(cube):
    """One unconstrained TI problem per model on the unit cube (P1), sharing one orientation field."""
    field = MaterialField.uniform(cube, UNIT_TI)
    a = orientation.uniform(cube, (0.0, 0.0, 1.0))
    return a, {model: ElasticityProblem(cube, field, orientation=a, model=model, prefix=f"free_{model}_")
               for model in MODELS}


# --------------------------------------------------------------------------------------------------
# Patch tests
# --------------------------------------------------------------------------------------------------
@pytest.mark.mpi
@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1), tuple(ROTATED_AXIS)], ids=["x", "y", "z", "rot"])
def test_patch_uniform_stress_from_compliance_strains(cube, free_cube_problems, axis):
    """u = ε X with ε = S σ₀ (S the TI compliance rotated so that l = axis) for σ₀ uniaxial along l, uniaxial
    across l, and shear in a plane containing l (ε_lt = τ/(2 G_l)): the residual equals the nodal forces of the
    traction σ₀ n on the boundary, i.e. the discrete solution carries the uniform stress σ₀ exactly."""
    a_field, problems = free_cube_problems
    l = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    a_field.x.array.reshape(-1, 3)[:] = l
    t = rotation_from_axis(l)[:, 0]  # a direction across l
    C = rotate_voigt(UNIT_TI.voigt(), rotation_from_axis(l))
    sigma0_const = fem.Constant(cube, np.zeros((3, 3)))
    V = problems["linear"].V
    n = ufl.FacetNormal(cube)
    traction = fem.form(ufl.inner(sigma0_const * n, ufl.TestFunction(V)) * ufl.ds)
    scale = 1e-7  # stress (Pa) small enough that the nonlinear models differ from linear by ~1e-7
    cases = {"along l": np.outer(l, l), "across l": np.outer(t, t), "shear l-t": np.outer(l, t) + np.outer(t, l)}
    for name, direction in cases.items():
        sigma0 = scale * direction
        sigma_voigt = np.array([sigma0[i, j] for i, j in VOIGT_PAIRS])
        strain_voigt = np.linalg.solve(C, sigma_voigt)  # engineering shear strains
        eps = np.array([[strain_voigt[0], strain_voigt[5] / 2, strain_voigt[4] / 2],
                        [strain_voigt[5] / 2, strain_voigt[1], strain_voigt[3] / 2],
                        [strain_voigt[4] / 2, strain_voigt[3] / 2, strain_voigt[2]]])
        # The compliance read in the material frame: ε_ll = σ/E_l, ε_tt = σ/E_t, γ_lt = τ/G_l.
        along = {"along l": scale / UNIT_TI.E_l, "across l": scale / UNIT_TI.E_t, "shear l-t": scale / UNIT_TI.G_l}
        measured = {"along l": l @ eps @ l, "across l": t @ eps @ t, "shear l-t": 2 * l @ eps @ t}
        assert measured[name] == pytest.approx(along[name], rel=1e-12)
        sigma0_const.value[:] = sigma0
        expected = fem.petsc.assemble_vector(traction)
        expected.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        for model, problem in problems.items():
            problem.u.interpolate(lambda x: eps @ x)  # noqa: B023
            b = residual(problem)
            b.axpy(-1.0, expected)
            rtol = 1e-10 if model == "linear" else 1e-5
            assert b.norm() <= rtol * expected.norm(), (name, model)


# --------------------------------------------------------------------------------------------------
# Frame invariance and consistent tangents
# --------------------------------------------------------------------------------------------------
@pytest.mark.mpi
def test_rigid_rotation_is_stress_free_for_svk_and_corotational(cube, free_cube_problems):
    """u = (Q - I)(X - p), a 90° rotation: zero stress and residual for svk and corotational, not for linear."""
    a_field, problems = free_cube_problems
    a_field.x.array.reshape(-1, 3)[:] = ROTATED_AXIS
    Q, p = rotation_matrix((1.0, 1.0, 1.0), np.pi / 2), np.array([0.5, 0.2, 0.1])
    midpoint = np.array([[0.25, 0.25, 0.25]])
    cells = np.arange(cube.topology.index_map(3).size_local, dtype=np.int32)
    for model, problem in problems.items():
        problem.u.interpolate(lambda x: (Q - np.eye(3)) @ (x - p[:, None]))
        if problem.rotation is not None:
            problem.rotation.update()
        P = fem.Expression(problem.stress, midpoint).eval(cells)
        max_P = cube.comm.allreduce(np.abs(P).max(initial=0.0), op=MPI.MAX)
        force_scale = problem._bc_scale * problem.u.vector.norm()  # k ‖u‖: the size of elastic forces
        ratio = residual(problem).norm() / force_scale
        if model == "linear":
            assert ratio > 1e-2 and max_P > 0.1 * UNIT_TI.G_l
        else:
            assert ratio < 1e-13 and max_P < 1e-13 * UNIT_TI.E_t, model


def taylor_remainders(problem, u0, du, steps):
    """‖r(u0 + h du) - r(u0) - h J(u0) du‖ for each h in steps."""
    x = problem.u.vector.copy()
    x.array[:] = u0
    r0, J = residual(problem, u0), problem._A.duplicate()
    problem.snes.computeJacobian(x, J)
    Jdu = J.createVecLeft()
    d = x.duplicate()
    d.array[:] = du
    J.mult(d, Jdu)
    out = []
    for h in steps:
        r = residual(problem, u0 + h * du)
        r.axpy(-1.0, r0)
        r.axpy(-h, Jdu)
        out.append(r.norm())
    return np.array(out)


@pytest.mark.parametrize("model", ["svk", "corotational"])
def test_taylor_jacobian_is_consistent(cube, model):
    """Second-order Taylor remainder at a large rotation + stretch state (TI, rotated l axis), with the face
    z = 0 carried by a rotation (the lifted residual is differentiated at a state that satisfies it)."""
    field = MaterialField.uniform(cube, UNIT_TI)
    a = orientation.uniform(cube, ROTATED_AXIS)
    axis, angle = np.array([0.2, 0.9, -0.4]), 1.0
    clamp = RigidMotion("clamp", face(cube, 2, 0), axis=tuple(axis))
    problem = ElasticityProblem(cube, field, orientation=a, model=model, motions=[clamp], prefix=f"taylor_{model}_")
    problem.motions["clamp"].set(angle, (0.0, 0.0, 0.0))
    Q = rotation_matrix(axis, angle)
    problem.u.interpolate(lambda x: (Q - np.eye(3)) @ x + 0.1 * np.sin(3 * x[[1, 2, 0]]) * x[2])
    u0 = problem.u.vector.array.copy()
    problem.u.interpolate(lambda x: np.cos(2 * x) * x[[2, 0, 1]])
    du = problem.u.vector.array.copy()
    remainders = taylor_remainders(problem, u0, du, 1e-2 / 2.0 ** np.arange(4))
    rates = np.log2(remainders[:-1] / remainders[1:])
    assert rates.min() > 1.9, rates


def newton_orders(history):
    """Convergence orders log(r_{k+1}/r_k) / log(r_k/r_{k-1}) on iterates above the round-off floor."""
    r = np.asarray(history)
    r = r[r > 1e-13 * r[0]]
    return np.log(r[2:] / r[1:-1]) / np.log(r[1:-1] / r[:-2])


@pytest.mark.parametrize("model", ["svk", "corotational"])
def test_newton_converges_quadratically(cube, model):
    """Stretch + twist of the top face in one increment: every Newton step is superlinear and the order rises
    to ≈ 2 (orders log(r_{k+1}/r_k)/log(r_k/r_{k-1}) on the residuals above the round-off floor)."""
    field = MaterialField.uniform(cube, UNIT_TI)
    a = orientation.uniform(cube, ROTATED_AXIS)
    motions = [RigidMotion("bottom", face(cube, 2, 0)), RigidMotion("top", face(cube, 2, 1), point=(0.5, 0.5, 1))]
    problem = ElasticityProblem(cube, field, orientation=a, model=model, motions=motions, prefix=f"rate_{model}_")
    stats = problem.solve_step(LoadStep("twist", angles={"top": 0.5}, translations={"top": (0.1, 0.0, 0.2)}))
    assert stats.increments == 1 and stats.cutbacks == 0
    assert stats.newton_iterations == len(stats.residuals[0]) - 1 <= 6
    orders = newton_orders(stats.residuals[0])
    # Every step superlinear: order > 1, i.e. each contraction factor r_{k+1}/r_k smaller than the previous one (an
    # inconsistent tangent converges linearly: a constant factor, order ≈ 1); quadratic at the end. Measured for
    # twists of ±0.5, 0.3, 0.7 rad: orders from 1.17 at the first step (far from the solution) to 1.74–2.23 at the
    # last one above the round-off floor.
    assert len(orders) >= 2 and orders.min() > 1.0, orders
    assert orders[-1] > 1.6, orders
    assert stats.wall_s > 0 and stats.min_det_F > 0.5


# --------------------------------------------------------------------------------------------------
# Large deformation with a closed form: a homogeneous rotation + stretch of the whole cube
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AffineMotion(RigidMotion):
    """The boundary carried by the homogeneous deformation ``x = F(s) X`` along the path
    ``F(s) = R(s θ) (I + s (U − I))``, ``s`` = the motion's "angle" load parameter (0 → 1)."""

    stretch: tuple = ()   # U (3×3, nested tuples)
    turn: tuple = ()      # rotation vector θ n of R

    def deformation(self, s: float) -> np.ndarray:
        U = np.eye(3) + s * (np.array(self.stretch) - np.eye(3))
        return Rotation.from_rotvec(s * np.array(self.turn)).as_matrix() @ U

    def displacement(self, X, angle, translation):
        return X @ (self.deformation(angle) - np.eye(3)).T


def ti_stiffness_tensor(m: TransverseIsotropic, axis: np.ndarray) -> np.ndarray:
    """C_ijkl of a TI material with its l axis along ``axis``, from the compliance of docs/conventions.md
    (S11 = 1/E_t, S33 = 1/E_l, S12 = −ν_t/E_t, S13 = −ν_tl/E_t, S44 = S55 = 1/G_l, S66 = 2(1 + ν_t)/E_t), written
    out here with numpy alone."""
    S = np.zeros((6, 6))
    S[0, 0] = S[1, 1] = 1 / m.E_t
    S[2, 2] = 1 / m.E_l
    S[0, 1] = S[1, 0] = -m.nu_t / m.E_t
    S[0, 2] = S[2, 0] = S[1, 2] = S[2, 1] = -m.nu_tl / m.E_t
    S[3, 3] = S[4, 4] = 1 / m.G_l
    S[5, 5] = 2 * (1 + m.nu_t) / m.E_t
    C = np.linalg.inv(S)
    local = np.zeros((3, 3, 3, 3))
    for I, (i, j) in enumerate(VOIGT_PAIRS):
        for J, (k, l) in enumerate(VOIGT_PAIRS):
            for a, b in {(i, j), (j, i)}:
                for c, d in {(k, l), (l, k)}:
                    local[a, b, c, d] = C[I, J]
    e3 = axis / np.linalg.norm(axis)
    e1 = np.cross(e3, [1.0, 0.0, 0.0] if abs(e3[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    Q = np.column_stack([e1, np.cross(e3, e1), e3])          # local axes → global, any e1 ⊥ l
    return np.einsum("ip,jq,kr,ls,pqrs->ijkl", Q, Q, Q, Q, local)


@pytest.mark.mpi
@pytest.mark.parametrize("model", ["svk", "corotational"])
def test_homogeneous_rotation_and_stretch_has_the_closed_form_stress(cube, model):
    """Every boundary node carried by x = F X, F = R U: a 120° rotation and principal stretches 1.3, 0.8, 1.15
    along a tilted frame, TI with an oblique l axis, P2, in 4 increments. The homogeneous field is the exact
    discrete solution, so Newton must land on it (every dof, interior ones included) and the first
    Piola–Kirchhoff stress must equal the closed form at every quadrature point, to round-off:

    * svk: E = ½ (FᵀF − I) = ½ (U² − I), P = F (C : E);
    * corotational: R is the polar rotation of F, ε_c = U − I, P = R (C : ε_c).
    """
    V = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
    U = V @ np.diag([1.3, 0.8, 1.15]) @ V.T
    turn = np.radians(120.0) * np.array([1.0, 2.0, -1.0]) / np.sqrt(6.0)
    boundary = mesh.locate_entities_boundary(cube, 2, lambda x: np.full(x.shape[1], True))
    motion = AffineMotion("all", boundary, stretch=tuple(map(tuple, U)), turn=tuple(turn))
    field = MaterialField.uniform(cube, UNIT_TI)
    a = orientation.uniform(cube, ROTATED_AXIS)
    problem = ElasticityProblem(cube, field, orientation=a, model=model, degree=2, motions=[motion],
                                prefix=f"affine_{model}_", options={"snes_rtol": 1e-14})
    problem.run([LoadStep("deform", angles={"all": 1.0}, increments=4)])

    F = motion.deformation(1.0)
    np.testing.assert_allclose(F, Rotation.from_rotvec(turn).as_matrix() @ U, atol=1e-15)
    X = problem.V.tabulate_dof_coordinates()
    np.testing.assert_allclose(problem.u.x.array.reshape(-1, 3), X @ (F - np.eye(3)).T, atol=1e-11)

    C = ti_stiffness_tensor(UNIT_TI, ROTATED_AXIS)
    if model == "svk":
        P = F @ np.einsum("ijkl,kl->ij", C, 0.5 * (U @ U - np.eye(3)))
    else:
        P = Rotation.from_rotvec(turn).as_matrix() @ np.einsum("ijkl,kl->ij", C, U - np.eye(3))
    # at the quadrature points of the stress integral (where the corotational model holds R)
    points, _ = basix.make_quadrature(basix.CellType.tetrahedron, problem.quadrature_degree)
    cells = np.arange(cube.topology.index_map(3).size_local, dtype=np.int32)
    computed = fem.Expression(problem.stress, points).eval(cells).reshape(-1, 3, 3)
    assert np.abs(P).max() > 0.3 * UNIT_TI.E_l          # large stresses: the stretches are tens of percent
    assert cube.comm.allreduce(np.abs(computed - P).max(initial=0.0), op=MPI.MAX) < 1e-11 * np.abs(P).max()


# --------------------------------------------------------------------------------------------------
# Slender cantilever under gravity against beam theory (P2)
# --------------------------------------------------------------------------------------------------
def test_cantilever_small_load_models_agree_with_beam_theory():
    """A 250×15×15 mm TI cantilever (l along the beam) under 1 % of gravity, P2.

    Euler–Bernoulli: w = q L⁴ / (8 E_l I), q = ρ g A, I = h⁴/12. Shear deformation adds the Timoshenko term
    q L² / (2 κ G_l A) (κ = 5/6), here 4 E_l I / (κ G_l A L²) = 0.29 % of w; the 3D clamp and Poisson effects
    are of the same order (h/L)² = 0.36 %. So the FE tip deflection must be within 1 % of Euler–Bernoulli and
    0.5 % of Timoshenko. At w/L = 0.55 % the geometrically nonlinear models differ from the linear one by
    O((w/L)²) = 3e-5 (measured 2.4e-5): they must agree to 1e-4.
    """
    L, h, g = 0.25, 0.015, 0.01 * 9.81
    msh = mesh.create_box(MPI.COMM_WORLD, [[0, 0, 0], [L, h, h]], [40, 3, 3])
    field = MaterialField.uniform(msh, TI)
    a = orientation.uniform(msh, (1.0, 0.0, 0.0))
    tip = face(msh, 0, L)
    tip_tags = mesh.meshtags(msh, 2, np.sort(tip), np.ones(len(tip), dtype=np.int32))
    ds_tip = ufl.Measure("ds", domain=msh, subdomain_data=tip_tags)(1)
    q, I = TI.rho * g * h * h, h**4 / 12
    w_eb = q * L**4 / (8 * TI.E_l * I)
    w_timoshenko = w_eb + q * L**2 / (2 * 5 / 6 * TI.G_l * h * h)
    w = {}
    for model in ("linear", "svk", "corotational"):  # the new models: tests/test_models.py
        problem = ElasticityProblem(msh, field, orientation=a, model=model, degree=2, gravity=(0, 0, -g),
                                    motions=[RigidMotion("clamp", face(msh, 0, 0.0))], prefix=f"beam_{model}_")
        problem.run([LoadStep("gravity", gravity=1.0)])
        w[model] = -msh.comm.allreduce(fem.assemble_scalar(fem.form(problem.u[2] * ds_tip)), op=MPI.SUM) / h**2
    assert w["linear"] == pytest.approx(w_eb, rel=1e-2)
    assert w["linear"] == pytest.approx(w_timoshenko, rel=5e-3)
    for model in ("svk", "corotational"):
        assert w[model] == pytest.approx(w["linear"], rel=1e-4)


# --------------------------------------------------------------------------------------------------
# Prescribed motions, load stepping, errors
# --------------------------------------------------------------------------------------------------
def test_rotation_matrix_is_rodrigues():
    axis, angle = np.array([1.0, -2.0, 0.5]), 2.1
    expected = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
    np.testing.assert_allclose(rotation_matrix(axis, angle), expected, atol=1e-15)
    with pytest.raises(ValueError, match="finite non-zero 3-vector"):
        rotation_matrix((0, 0, 0), 1.0)


@pytest.mark.mpi
def test_prescribed_rigid_motion_of_the_whole_boundary_p2(cube):
    """Moving every boundary facet rigidly (120° about an oblique axis + translation) moves the body rigidly:
    every P2 dof, interior ones included, gets u = R(X - p) + p + t - X."""
    field = MaterialField.uniform(cube, Isotropic(E=1.0, nu=0.3))
    boundary = mesh.locate_entities_boundary(cube, 2, lambda x: np.full(x.shape[1], True))
    motion = RigidMotion("all", boundary, axis=(0.0, 1.0, 1.0), point=(0.5, 0.5, 0.0))
    problem = ElasticityProblem(cube, field, model="svk", degree=2, motions=[motion], prefix="rigid_")
    angle, t = np.radians(120.0), np.array([0.1, -0.2, 0.3])
    stats = problem.run([LoadStep("turn", angles={"all": angle}, translations={"all": t}, increments=3)])
    X = problem.V.tabulate_dof_coordinates()
    expected = motion.displacement(X, angle, t)
    np.testing.assert_allclose(problem.u.x.array.reshape(-1, 3), expected, atol=1e-10)
    assert problem.loads.angles["all"] == angle and stats[0].increments == 3


def compression_problem(cube, **kwargs):
    field = MaterialField.uniform(cube, UNIT_TI)
    a = orientation.uniform(cube, (0.0, 0.0, 1.0))
    motions = [RigidMotion("bottom", face(cube, 2, 0)), RigidMotion("top", face(cube, 2, 1))]
    return ElasticityProblem(cube, field, orientation=a, model="svk", motions=motions, **kwargs)


@pytest.mark.mpi
def test_inversion_after_cutbacks_raises_and_keeps_last_converged_state(cube):
    """SVK squeezed to 10 % of its height converges to inverted elements: detected, cut back, then reported."""
    problem = compression_problem(cube, prefix="squeeze_", max_cutbacks=2)
    with pytest.raises(ConvergenceError, match=r"load step 'squeeze' failed .* inverted element") as info:
        problem.solve_step(LoadStep("squeeze", translations={"top": (0.0, 0.0, -0.9)}, increments=2))
    error = info.value
    assert error.step == "squeeze" and 0.0 < error.load_factor < 1.0
    # The kept state is the converged one at the reported load factor: not inverted, zero residual.
    assert problem.loads.translations["top"][2] == pytest.approx(-0.9 * error.load_factor)
    assert problem.min_det_F() > 0.0
    assert residual(problem).norm() < 1e-9 * problem._bc_scale


@pytest.mark.mpi
def test_divergence_after_cutbacks_raises_with_snes_reason(cube):
    problem = compression_problem(cube, prefix="maxit_", max_cutbacks=1, options={"snes_max_it": 1})
    with pytest.raises(ConvergenceError, match="at load factor 0 of the step after 2 cut-backs: DIVERGED_MAX_IT"):
        problem.solve_step(LoadStep("squeeze", translations={"top": (0.0, 0.0, -0.2)}))
    np.testing.assert_array_equal(problem.u.x.array, 0.0)


def test_invalid_set_ups_are_refused(cube):
    iso, ti = MaterialField.uniform(cube, Isotropic(E=1.0, nu=0.3)), MaterialField.uniform(cube, UNIT_TI)
    a = orientation.uniform(cube, (0, 0, 1))
    with pytest.raises(ValueError, match="every region is isotropic: pass orientation=None"):
        ElasticityProblem(cube, iso, orientation=a)
    with pytest.raises(ValueError, match="transversely isotropic: an orientation field is required"):
        ElasticityProblem(cube, ti)
    with pytest.raises(ValueError, match="unknown model 'neo-hookean'; valid models are linear, svk, corotational"):
        ElasticityProblem(cube, iso, model="neo-hookean")
    with pytest.raises(ValueError, match="prefix must be non-empty"):
        ElasticityProblem(cube, iso, prefix="")
    with pytest.raises(ValueError, match="selects no degree of freedom"):
        ElasticityProblem(cube, iso, motions=[RigidMotion("servo", np.array([], dtype=np.int32))])
    problem = ElasticityProblem(cube, iso, model="linear", prefix="invalid_")
    with pytest.raises(ValueError, match="moves 'servo', which is not a motion of the problem"):
        problem.solve_step(LoadStep("x", angles={"servo": 1.0}))


def test_region_without_material_is_refused(cube):
    n = cube.topology.index_map(3).size_local
    tags = mesh.meshtags(cube, 3, np.arange(n, dtype=np.int32), np.where(np.arange(n) % 2, 1, 7).astype(np.int32))
    with pytest.raises(ValueError, match=r"cell\(s\) have tags \[7\] without a material"):
        MaterialField.from_regions(cube, tags, {1: UNIT_TI})


def test_options_prefix_defaults_and_command_line(cube):
    """Defaults < options= < the PETSc database (command line); our options leave the database afterwards."""
    db = PETSc.Options()
    db["opts_snes_max_it"] = 7
    try:
        problem = ElasticityProblem(cube, MaterialField.uniform(cube, Isotropic(E=1.0, nu=0.3)), model="linear",
                                    prefix="opts_", options={"snes_max_it": 11, "snes_rtol": 1e-7})
    finally:
        db.delValue("opts_snes_max_it")
    rtol, _, _, max_it = problem.snes.getTolerances()
    assert max_it == 7 and rtol == 1e-7
    assert problem.snes.getType() == "newtonls"
    assert problem.snes.getKSP().getPC().getFactorSolverType() == "mumps"
    assert not any(key.startswith("opts_") for key in db.getAll())


# --------------------------------------------------------------------------------------------------
# MPI: the same answer on any number of ranks
# --------------------------------------------------------------------------------------------------
def tripod_like_tip_displacement(comm):
    """A TI beam with a spiral l axis, hanging under gravity from a root that a servo then turns by 40°."""
    L, h = 0.1, 0.01
    msh = mesh.create_box(comm, [[0, 0, 0], [L, h, h]], [12, 2, 2])
    field = MaterialField.uniform(msh, TI)
    a = orientation.from_callable(msh, lambda x: np.column_stack([np.ones(len(x)), np.sin(40 * x[:, 0]),
                                                                  np.cos(40 * x[:, 0])]))
    servo = RigidMotion("servo", face(msh, 0, 0.0), axis=(0.0, 1.0, 0.0), point=(0.0, h / 2, h / 2))
    problem = ElasticityProblem(msh, field, orientation=a, model="corotational", motions=[servo],
                                gravity=(0.0, 0.0, -9.81 * 20), prefix="mpi_")
    problem.run([LoadStep("rest", gravity=1.0), LoadStep("turn", angles={"servo": np.radians(40)}, increments=2)])
    tip = face(msh, 0, L)
    tags = mesh.meshtags(msh, 2, np.sort(tip), np.ones(len(tip), dtype=np.int32))
    ds_tip = ufl.Measure("ds", domain=msh, subdomain_data=tags)(1)
    return np.array([comm.allreduce(fem.assemble_scalar(fem.form(problem.u[i] * ds_tip)), op=MPI.SUM)
                     for i in range(3)]) / h**2


@ONE_RANK_SKIP
@pytest.mark.mpi
def test_serial_and_parallel_tip_displacements_agree():
    parallel = tripod_like_tip_displacement(MPI.COMM_WORLD)
    serial = tripod_like_tip_displacement(MPI.COMM_SELF)
    assert np.linalg.norm(parallel) > 1e-3
    np.testing.assert_allclose(parallel, serial, rtol=1e-8, atol=1e-8 * np.linalg.norm(serial))
