"""UFL constitutive models: strain measures × the (transversely) isotropic quadratic energy.

Material data are DG0 fields (:class:`MaterialField`): one form serves every cell, heterogeneous regions are
data. The quadratic energy of a symmetric strain ``e`` is

* isotropic:  ``ψ(e) = λ/2 tr(e)² + μ e:e``;
* transversely isotropic, with the unit *l* axis ``a`` (DG0 orientation field) and ``A = a⊗a``
  (Spencer's structural-tensor form, moduli of :meth:`fenicsfoam.materials.TransverseIsotropic.spencer_moduli`):
  ``ψ(e) = λ/2 tr(e)² + μ_T e:e + α tr(Ae) tr(e) + 2(μ_L - μ_T) tr(A e²) + β/2 tr(Ae)²``,
  whose derivative is ``σ = λ tr(e) I + 2μ_T e + α (tr(Ae) I + tr(e) A) + 2(μ_L - μ_T)(Ae + eA) + β tr(Ae) A``.

Stresses are ``ufl.diff`` of ψ with respect to the strain made a ``ufl.variable``. The models
(first Piola–Kirchhoff stress ``P`` of the displacement ``u``, ``F = I + ∇u``):

* ``linear``: ``ε = sym ∇u``, ``P = σ(ε)`` (small strain, not frame invariant);
* ``svk``: St-Venant–Kirchhoff, ``E = (FᵀF - I)/2``, ``S = ∂ψ/∂E``, ``P = F S``;
* ``corotational``: ``ε_c = sym(RᵀF) - I`` with ``R`` the rotation of the polar decomposition ``F = R U``,
  ``P = R σ(ε_c)``. ``R`` is a quadrature field (:class:`PolarRotation`) recomputed from the current ``u``
  before every residual evaluation, and held fixed in the tangent (as SOFA's corotational elements do).
  For an isotropic material ``R σ(U - I)`` is exactly ``∂ψ(U - I)/∂F``; for a TI material it differs from
  it by terms of order ``|ε_c| |σ|`` (σ and U do not commute), the corotational model of the paper.
  Writing R in UFL by polar iterations so that the tangent is exact was measured and rejected
  (README, "Macro FEM": 13 min of FFCx/gcc compilation and 8× the assembly time for 3 iterations).
  Its exact tangent contains ``R Ω σ``, a geometric stiffness of order ``|σ|``: with a TI foam whose ``G_l`` is
  small against its other moduli it loses strong ellipticity once ``|σ| ≈ G_l`` (:mod:`fenicsfoam.stability`).
* ``corotational_sofa``: SOFA's corotational tetrahedron (the paper's TetrahedronAnisotropicForceField),
  ``P = R σ(sym(RᵀF) - I)`` with ``R`` the frame of the element's current edges relative to its rest frame
  (:class:`EdgeRotation`, SOFA's "large" method: Gram–Schmidt of the edges 0→1 and 0→2, not the polar
  decomposition) and the tangent taken at frozen ``R`` (``R C Rᵀ``, as SOFA assembles it). The nodal forces are
  SOFA's ``R K (Rᵀx - x₀)`` for P1. Unlike ``corotational``: ``R`` differs from the polar rotation by a rotation
  of the order of the element's shear strain and depends on which edges the element numbers first (dolfinx's
  vertex order here, the mesh file's in SOFA), and the tangent has no rotation terms, so it never loses
  ellipticity (margin ``min(G_l, …)`` of the linear law at every deformation) but is not the derivative of the
  residual: Newton converges linearly (default ``snes_max_it`` raised, :class:`fenicsfoam.solver.ElasticityProblem`)
  and adjoint sensitivities refuse it. The residual is not the gradient of an energy; ``energy`` reports
  ``½ ε_c:C:ε_c``.
* ``bonet_burton``: hyperelastic, the transversely isotropic extension of a compressible neo-Hookean energy of
  Bonet and Burton (Comput. Methods Appl. Mech. Engrg. 162, 1998), ``P = ∂ψ/∂F`` with the exact tangent,

      ψ = μ_T/2 (I₁ - 3) - μ_T ln J + λ/2 (J - 1)² + [a + b ln J + c (I₄ - 1)](I₄ - 1) - a/2 (I₅ - 1),

  ``I₁ = tr C``, ``I₄ = a·C a``, ``I₅ = a·C² a``, ``C = FᵀF``, ``J = det F``, and ``a = μ_T - μ_L``, ``b = α/2``,
  ``c = β/8`` from the Spencer moduli: its second-order expansion in ``E`` is exactly the quadratic energy
  above, so the tangent at ``F = I`` is the linear TI stiffness with all five constants. (Bonet and Burton's
  volumetric term is ``λ/2 (ln J)²``; ``(J - 1)²`` has the same small-strain limit and is convex in ``J``.) It is
  not polyconvex: the term ``-a/2 I₅`` with ``a = μ_T - μ_L > 0`` softens the material under stretch along and
  across ``l`` and under shear, and for the project's foams (``μ_L`` a few per cent of ``μ_T``) strong
  ellipticity is lost at a 1–2 % stretch or a 2–5 % shear (``tests/test_models.py``,
  ``studies/ellipticity_models.py``), where ``corotational`` stays elliptic; ``corotational`` loses it first in
  compression across ``l``.

No polyconvex energy built from the usual TI invariants (``I₁``, ``I₂ = tr cof C``, ``J``, ``I₄``,
``K₃ = a·cof C a``, ``|F(I - A)|²``, ``|cof F (I - A)|²`` through convex non-decreasing functions, and convex
functions of ``J``) reproduces such a foam: a stress-free reference needs the positive first-order terms of
these invariants cancelled by ``h(J)`` with ``h'(1) < 0``, which adds ``|h'(1)| E:E`` to every shear, and matching
the second-order terms then requires ``μ_T <= 2 μ_L`` (the paper's foam has ``μ_T = 34 μ_L``). A polyconvex law
would have to raise ``G_l`` (or lower the in-plane shear modulus ``E_t / (2(1 + ν_t))``) by an order of magnitude,
which changes the twist it is meant to predict; none is offered.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import basix
import numpy as np
import ufl
from dolfinx import fem
from dolfinx.mesh import Mesh, MeshTagsMetaClass

from fenicsfoam.materials import Isotropic, Material, TransverseIsotropic
from fenicsfoam.orientation import UNTAGGED, cell_function, owned_cell_tags
from foambase.cells import num_owned_cells
from foambase.errors import InputError

__all__ = [
    "MODELS",
    "BonetBurton",
    "Corotational",
    "CorotationalSOFA",
    "EdgeRotation",
    "Linear",
    "Model",
    "SaintVenantKirchhoff",
    "as_model",
    "bonet_burton_energy",
    "corotational_rotation_tangent",
    "edge_frame",
    "MaterialField",
    "PolarRotation",
    "deformation_gradient",
    "first_piola_kirchhoff",
    "green_lagrange",
    "polar_rotation",
    "quadratic_energy",
    "small_strain",
    "strain_energy_density",
    "stress",
]

logger = logging.getLogger(__name__)

_ISOTROPIC_MODULI = ("lmbda", "mu")
_TI_MODULI = ("lmbda", "mu_T", "mu_L", "alpha", "beta")


# --------------------------------------------------------------------------------------------------
# Material data as DG0 fields
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MaterialField:
    """Piecewise-constant material data: DG0 moduli and density, one value per cell.

    If every region is :class:`~fenicsfoam.materials.Isotropic`, ``moduli`` holds the Lamé fields
    ``lmbda``, ``mu`` and the isotropic energy is used (no orientation field is needed); otherwise it holds
    the five Spencer moduli ``lmbda, mu_T, mu_L, alpha, beta`` (isotropic regions get ``μ_T = μ_L = μ``,
    ``α = β = 0``, for which the orientation has no effect) and an orientation field is required.

    Build with :meth:`uniform` or :meth:`from_regions`.
    """

    materials: Mapping[int, Material]      #: the regions, ``{cell tag: material}``
    isotropic: bool                        #: every region is isotropic
    moduli: Mapping[str, fem.Function]     #: DG0 moduli (Pa) by name
    rho: fem.Function                      #: DG0 mass density (kg/m³)

    @classmethod
    def uniform(cls, mesh: Mesh, material: Material) -> MaterialField:
        """The same material in every cell."""
        return cls._build(mesh, {0: material}, np.zeros(num_owned_cells(mesh), dtype=np.int64))

    @classmethod
    def from_regions(cls, mesh: Mesh, cell_tags: MeshTagsMetaClass, materials: Mapping[int, Material]
                     ) -> MaterialField:
        """One material per cell tag; every cell must carry a tag present in ``materials``."""
        for tag, material in materials.items():
            if not isinstance(material, (Isotropic, TransverseIsotropic)):
                raise InputError(f"region {tag}: expected Isotropic or TransverseIsotropic, got {material!r}")
        tags = owned_cell_tags(mesh, cell_tags)
        unknown = ~np.isin(tags, list(materials))
        n_unknown = mesh.comm.allreduce(int(unknown.sum()))
        if n_unknown:
            local = {("untagged" if t == UNTAGGED else int(t)) for t in np.unique(tags[unknown])}
            missing = sorted(set().union(*mesh.comm.allgather(local)), key=str)
            raise InputError(f"{n_unknown} cell(s) have tags {missing} without a material "
                             f"(materials given for tags {sorted(materials)})")
        return cls._build(mesh, dict(materials), tags)

    @classmethod
    def _build(cls, mesh: Mesh, materials: dict[int, Material], tags: np.ndarray) -> MaterialField:
        isotropic = all(isinstance(m, Isotropic) for m in materials.values())
        names = _ISOTROPIC_MODULI if isotropic else _TI_MODULI
        table = {tag: (dict(zip(_ISOTROPIC_MODULI, m.lame)) if isotropic else m.spencer_moduli())
                 for tag, m in materials.items()}
        values = np.zeros((len(names), tags.size))
        rho = np.zeros(tags.size)
        for tag, moduli in table.items():
            cells = tags == tag
            values[:, cells] = np.array([moduli[name] for name in names])[:, None]
            rho[cells] = materials[tag].rho
        moduli = {name: cell_function(mesh, v, name=name) for name, v in zip(names, values)}
        return cls(materials=materials, isotropic=isotropic, moduli=moduli, rho=cell_function(mesh, rho, name="rho"))


# --------------------------------------------------------------------------------------------------
# Kinematics and the quadratic energy
# --------------------------------------------------------------------------------------------------
def deformation_gradient(u: fem.Function) -> ufl.core.expr.Expr:
    """``F = I + ∇u`` (gradient with respect to the reference coordinates)."""
    return ufl.Identity(len(u)) + ufl.grad(u)


def green_lagrange(F: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Green–Lagrange strain ``E = (FᵀF - I)/2``."""
    return 0.5 * (F.T * F - ufl.Identity(F.ufl_shape[0]))


def small_strain(u: fem.Function) -> ufl.core.expr.Expr:
    """Small strain ``ε = sym ∇u``."""
    return ufl.sym(ufl.grad(u))


def quadratic_energy(e: ufl.core.expr.Expr, material: MaterialField, orientation: fem.Function | None
                     ) -> ufl.core.expr.Expr:
    """``ψ(e) = ½ e:C:e`` for a symmetric strain ``e`` (isotropic or TI Spencer form, module docstring)."""
    m = material.moduli
    if material.isotropic:
        return 0.5 * m["lmbda"] * ufl.tr(e) ** 2 + m["mu"] * ufl.inner(e, e)
    if orientation is None:
        raise InputError("a transversely isotropic material needs an orientation field (the unit l axis per cell)")
    A = ufl.outer(orientation, orientation)
    tr_Ae = ufl.inner(A, e)
    return (0.5 * m["lmbda"] * ufl.tr(e) ** 2 + m["mu_T"] * ufl.inner(e, e) + m["alpha"] * tr_Ae * ufl.tr(e)
            + 2.0 * (m["mu_L"] - m["mu_T"]) * ufl.inner(A, e * e) + 0.5 * m["beta"] * tr_Ae ** 2)


def stress(e: ufl.core.expr.Expr, material: MaterialField, orientation: fem.Function | None) -> ufl.core.expr.Expr:
    """``σ = ∂ψ/∂e`` of :func:`quadratic_energy`, by ``ufl.diff`` with ``e`` made a ``ufl.variable``."""
    e = ufl.variable(e)
    return ufl.diff(quadratic_energy(e, material, orientation), e)


# --------------------------------------------------------------------------------------------------
# The rotation of the polar decomposition, at quadrature points
# --------------------------------------------------------------------------------------------------
def _cofactor(M: np.ndarray) -> np.ndarray:
    """Cofactor matrices ``cof(M) = det(M) M⁻ᵀ`` of a stack (n, 3, 3): columns are cross products of columns."""
    c0, c1, c2 = M[:, :, 0], M[:, :, 1], M[:, :, 2]
    return np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=2)


def polar_rotation(F: np.ndarray, tol: float = 1e-14, max_iterations: int = 30) -> np.ndarray:
    """Orthogonal factor ``R`` of the polar decomposition ``F = R U`` for a stack of matrices (n, 3, 3).

    Scaled Newton iteration (Higham 1986), ``R₀ = F``,

        R_{k+1} = ½ (ζ_k R_k + ζ_k⁻¹ R_k⁻ᵀ),   ζ_k = |det R_k|^(-1/3),   R_k⁻ᵀ = cof(R_k) / det R_k,

    until ``max |R_{k+1} - R_k| <= tol`` (4–5 iterations for principal stretches in [0.5, 2]). ``R`` is a
    rotation when ``det F > 0`` (a reflection when ``det F < 0``; NaN when ``det F = 0``).
    """
    R = np.array(F, dtype=float)
    for _ in range(max_iterations):
        cof = _cofactor(R)
        det = np.einsum("nij,nij->n", R, cof) / 3.0
        zeta = np.abs(det) ** (-1.0 / 3.0)
        R_next = 0.5 * (zeta[:, None, None] * R + (1.0 / (zeta * det))[:, None, None] * cof)
        change = np.max(np.abs(R_next - R), initial=0.0)
        R = R_next
        if not change > tol:  # also stops on NaN
            break
    return R


class PolarRotation:
    """The rotation ``R`` of ``F = R U`` at the quadrature points of the stress integral, as a UFL coefficient.

    ``R`` lives in a tensor quadrature space of degree ``quadrature_degree`` (one point per cell for P1,
    where ``F`` is constant per cell); :meth:`update` evaluates ``F = I + ∇u`` at the quadrature points of
    every local cell (owned and ghost, so no communication) and writes :func:`polar_rotation` of it.
    The stress integral must use the same quadrature degree (``dx(metadata={"quadrature_degree": q})``).
    """

    def __init__(self, u: fem.Function, quadrature_degree: int):
        mesh = u.function_space.mesh
        element = ufl.TensorElement("Quadrature", mesh.ufl_cell(), degree=quadrature_degree, quad_scheme="default")
        Q = fem.FunctionSpace(mesh, element)
        points, _ = basix.make_quadrature(basix.cell.string_to_type(mesh.topology.cell_name()), quadrature_degree)
        self.R = fem.Function(Q, name="rotation")
        self._points = points
        self._F = fem.Expression(deformation_gradient(u), points)
        imap = mesh.topology.index_map(mesh.topology.dim)
        self._cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
        self._dofs = Q.dofmap.list.array  # block index per (cell, point), in the order of Expression.eval
        self.R.x.array.reshape(-1, 9)[:] = np.eye(3).ravel()

    def update(self) -> None:
        """Recompute ``R`` from the current displacement (its ghost values must be up to date)."""
        F = self._F.eval(self._cells).reshape(-1, 3, 3)
        self.R.x.array.reshape(-1, 9)[self._dofs] = self.rotation_of(F).reshape(-1, 9)

    def rotation_of(self, F: np.ndarray) -> np.ndarray:
        """The rotations (n, 3, 3) of the deformation gradients ``F`` (n, 3, 3) at the points, in ``update``'s order."""
        return polar_rotation(F)


def edge_frame(e0: np.ndarray, e1: np.ndarray) -> np.ndarray:
    """Orthonormal frames (n, 3, 3) of pairs of edges (n, 3), the Gram–Schmidt frame of SOFA's tetrahedra.

    Columns ``x = e0/|e0|``, ``z = x × e1 / |x × e1|``, ``y = z × x``: the first edge and the plane of the first two.
    """
    x = e0 / np.linalg.norm(e0, axis=1, keepdims=True)
    z = np.cross(x, e1)
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=2)


class EdgeRotation(PolarRotation):
    """The element rotation of SOFA's corotational tetrahedra ("large" method), at the stress quadrature points.

    ``R = G(F E₀, F E₁) G(E₀, E₁)ᵀ`` with :func:`edge_frame` ``G``, ``E₀ = x₁ − x₀`` and ``E₁ = x₂ − x₀`` the
    reference cell's first two edges (the columns of the geometry Jacobian ``∂x/∂ξ``, in dolfinx's vertex order)
    and ``F`` the deformation gradient at the point: for P1 exactly the frame of the current edges
    ``x₁ − x₀``, ``x₂ − x₀`` relative to the rest frame. ``R(QF) = Q R(F)`` for every rotation ``Q``, ``R(I) = I``;
    unlike the polar rotation it depends on which edges the element numbers first, and ``RᵀF`` is not symmetric.
    """

    def __init__(self, u: fem.Function, quadrature_degree: int):
        super().__init__(u, quadrature_degree)
        mesh = u.function_space.mesh
        jacobian = fem.Expression(ufl.Jacobian(mesh), self._points).eval(self._cells).reshape(-1, 3, 3)
        self._edges = jacobian[:, :, :2]
        self._rest = edge_frame(self._edges[:, :, 0], self._edges[:, :, 1])

    def rotation_of(self, F: np.ndarray) -> np.ndarray:
        """``G(F E₀, F E₁) G(E₀, E₁)ᵀ`` at every point."""
        current = F @ self._edges
        return edge_frame(current[:, :, 0], current[:, :, 1]) @ self._rest.transpose(0, 2, 1)


# --------------------------------------------------------------------------------------------------
# Models
# --------------------------------------------------------------------------------------------------
def _cross_matrix(w: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """``[w]×``, the skew matrix with ``[w]× v = w × v``."""
    return ufl.as_matrix([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def _axial(M: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Axial vector of the skew part of ``M``: ``[axial(M)]× = (M - Mᵀ)/2``."""
    return 0.5 * ufl.as_vector([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])


def corotational_rotation_tangent(u: fem.Function, du: ufl.Argument, material: MaterialField,
                                  orientation: fem.Function | None, rotation: PolarRotation) -> ufl.core.expr.Expr:
    """The part of the corotational tangent ``dP`` that comes from the change of ``R`` with ``F``.

    With ``F = R U``, a change ``dF = ∇du`` rotates ``R`` by ``dR = R Ω``, ``Ω = [ω]×`` skew, where
    ``ω = 2 (tr(U) I - U)⁻¹ axial(Rᵀ dF)`` (from the skew part of ``Rᵀ dF = Ω U + dU``, using
    ``Ω U + U Ω = [(tr(U) I - U) ω]×``; ``tr(U) I - U`` has eigenvalues ``λ_i + λ_j > 0``). Then

        dP = R σ(sym(Rᵀ dF))  +  R (Ω σ - σ(sym(Ω U))),

    the first term being ``ufl.derivative`` of ``P = R σ(ε_c)`` at frozen ``R`` and the second the
    expression returned here, so that the Jacobian is exact (Newton converges quadratically).
    """
    R, F = rotation.R, deformation_gradient(u)
    U = ufl.sym(R.T * F)
    omega = 2.0 * ufl.inv(ufl.tr(U) * ufl.Identity(3) - U) * _axial(R.T * ufl.grad(du))
    Omega = _cross_matrix(omega)
    sigma = stress(U - ufl.Identity(3), material, orientation)
    return R * (Omega * sigma - stress(ufl.sym(Omega * U), material, orientation))


@dataclass(frozen=True)
class Model:
    """A constitutive model: a strain measure of ``u`` and the first Piola–Kirchhoff stress of its quadratic energy.

    Subclasses define :meth:`strain` and :meth:`first_piola_kirchhoff`; the attributes say what a solver must
    provide or check. The models are :data:`MODELS`, by name; :func:`as_model` accepts a name or a model.
    """

    name: str
    needs_rotation: bool = False     #: the strain uses a rotation ``R`` of ``F`` (:meth:`rotation_field`)
    finite_strain: bool = True       #: frame invariant; an element with ``det F <= 0`` makes an increment fail
    symmetric_tangent: bool = True   #: the solver's tangent is symmetric (CG applies; else GMRES)
    exact_tangent: bool = True       #: the solver's tangent is the exact derivative of the residual (adjoints apply)

    def rotation_field(self, u: fem.Function, quadrature_degree: int) -> PolarRotation:
        """The rotation field the model's stress uses (for models with ``needs_rotation``): the polar rotation."""
        return PolarRotation(u, quadrature_degree)

    def strain(self, u: fem.Function, rotation: PolarRotation | None = None) -> ufl.core.expr.Expr:
        """The model's strain measure of ``u``."""
        raise NotImplementedError

    def first_piola_kirchhoff(self, u: fem.Function, material: MaterialField, orientation: fem.Function | None,
                              rotation: PolarRotation | None = None) -> ufl.core.expr.Expr:
        """The first Piola–Kirchhoff stress ``P`` of ``u``."""
        raise NotImplementedError

    def rotation_tangent(self, u: fem.Function, du: ufl.Argument, material: MaterialField,
                         orientation: fem.Function | None, rotation: PolarRotation | None) -> ufl.core.expr.Expr | None:
        """What ``ufl.derivative`` of ``P`` at frozen ``R`` misses of the exact tangent ``dP`` (``None``: nothing)."""
        return None

    def energy(self, u: fem.Function, material: MaterialField, orientation: fem.Function | None,
               rotation: PolarRotation | None = None) -> ufl.core.expr.Expr:
        """Energy per unit reference volume ``ψ = ½ e:C:e`` of the model's strain ``e``."""
        return quadratic_energy(self.strain(u, rotation), material, orientation)

    def __str__(self) -> str:
        return self.name


class Linear(Model):
    """Small strain: ``ε = sym ∇u``, ``P = σ(ε)`` (not frame invariant)."""

    def strain(self, u, rotation=None):
        """``ε = sym ∇u``."""
        return small_strain(u)

    def first_piola_kirchhoff(self, u, material, orientation, rotation=None):
        """``P = σ(ε)``."""
        return stress(self.strain(u), material, orientation)


class SaintVenantKirchhoff(Model):
    """St-Venant–Kirchhoff: ``E = (FᵀF - I)/2``, ``S = ∂ψ/∂E``, ``P = F S``."""

    def strain(self, u, rotation=None):
        """``E = (FᵀF - I)/2``."""
        return green_lagrange(deformation_gradient(u))

    def first_piola_kirchhoff(self, u, material, orientation, rotation=None):
        """``P = F S(E)``."""
        return deformation_gradient(u) * stress(self.strain(u), material, orientation)


class Corotational(Model):
    """Corotational: ``ε_c = sym(RᵀF) - I``, ``P = R σ(ε_c)`` with ``R`` held fixed in ``ufl.derivative``."""

    def strain(self, u, rotation=None):
        """``ε_c = sym(RᵀF) - I``."""
        if rotation is None or isinstance(rotation, EdgeRotation):
            raise InputError("the corotational model needs a PolarRotation of the displacement")
        return ufl.sym(rotation.R.T * deformation_gradient(u)) - ufl.Identity(len(u))

    def first_piola_kirchhoff(self, u, material, orientation, rotation=None):
        """``P = R σ(ε_c)``."""
        strain = self.strain(u, rotation)  # refuses a missing rotation
        return rotation.R * stress(strain, material, orientation)

    def rotation_tangent(self, u, du, material, orientation, rotation):
        """The change of ``R`` with ``u`` (:func:`corotational_rotation_tangent`)."""
        return corotational_rotation_tangent(u, du, material, orientation, rotation)


class CorotationalSOFA(Corotational):
    """SOFA's corotational tetrahedron: ``P = R σ(sym(RᵀF) - I)`` with the edge rotation ``R`` (:class:`EdgeRotation`).

    The tangent is the derivative at frozen ``R`` (``R C Rᵀ``: symmetric, positive definite, never loses
    ellipticity); it is not the exact derivative of the residual, so Newton converges linearly and adjoint
    sensitivities do not apply.
    """

    def rotation_field(self, u, quadrature_degree):
        """An :class:`EdgeRotation` of ``u``."""
        return EdgeRotation(u, quadrature_degree)

    def strain(self, u, rotation=None):
        """``ε_c = sym(RᵀF) - I`` with the edge rotation."""
        if not isinstance(rotation, EdgeRotation):
            raise InputError("the corotational_sofa model needs an EdgeRotation of the displacement "
                             "(model.rotation_field(u, quadrature_degree))")
        return ufl.sym(rotation.R.T * deformation_gradient(u)) - ufl.Identity(len(u))

    def rotation_tangent(self, u, du, material, orientation, rotation):
        """Nothing: the tangent is the derivative at frozen ``R``, as in SOFA."""
        return None


def bonet_burton_energy(F: ufl.core.expr.Expr, material: MaterialField, orientation: fem.Function | None
                        ) -> ufl.core.expr.Expr:
    """Bonet–Burton transversely isotropic neo-Hookean energy per unit reference volume (module docstring).

    ``ψ = μ_T/2 (I₁ - 3) - μ_T ln J + λ/2 (J - 1)² + [a + b ln J + c (I₄ - 1)](I₄ - 1) - a/2 (I₅ - 1)``, with
    ``C = FᵀF``, ``I₁ = tr C``, ``I₄ = a·C a``, ``I₅ = a·C² a`` and ``a = μ_T - μ_L``, ``b = α/2``, ``c = β/8`` from
    the Spencer moduli; an isotropic material (``μ_T = μ_L = μ``, ``α = β = 0``) gives the compressible neo-Hookean
    energy ``μ/2 (I₁ - 3) - μ ln J + λ/2 (J - 1)²``.
    """
    m = material.moduli
    C = F.T * F
    J = ufl.det(F)
    mu = m["mu"] if material.isotropic else m["mu_T"]
    psi = 0.5 * mu * (ufl.tr(C) - 3) - mu * ufl.ln(J) + 0.5 * m["lmbda"] * (J - 1) ** 2
    if material.isotropic:
        return psi
    if orientation is None:
        raise InputError("a transversely isotropic material needs an orientation field (the unit l axis per cell)")
    a = orientation
    I4, I5 = ufl.inner(a, C * a), ufl.inner(C * a, C * a)
    coef_a, coef_b, coef_c = m["mu_T"] - m["mu_L"], 0.5 * m["alpha"], 0.125 * m["beta"]
    return psi + (coef_a + coef_b * ufl.ln(J) + coef_c * (I4 - 1)) * (I4 - 1) - 0.5 * coef_a * (I5 - 1)


class BonetBurton(Model):
    """Hyperelastic TI neo-Hooke of Bonet and Burton: ``P = ∂ψ/∂F`` (:func:`bonet_burton_energy`), exact tangent."""

    def strain(self, u, rotation=None):
        """The Green–Lagrange strain ``E = (FᵀF - I)/2`` (what the energy is a function of)."""
        return green_lagrange(deformation_gradient(u))

    def energy(self, u, material, orientation, rotation=None):
        """:func:`bonet_burton_energy` of ``F = I + ∇u``."""
        return bonet_burton_energy(deformation_gradient(u), material, orientation)

    def first_piola_kirchhoff(self, u, material, orientation, rotation=None):
        """``P = ∂ψ/∂F`` by ``ufl.diff``."""
        F = ufl.variable(deformation_gradient(u))
        return ufl.diff(bonet_burton_energy(F, material, orientation), F)


#: The constitutive models by name.
MODELS: dict[str, Model] = {
    "linear": Linear("linear", finite_strain=False),
    "svk": SaintVenantKirchhoff("svk"),
    "corotational": Corotational("corotational", needs_rotation=True, symmetric_tangent=False),
    "bonet_burton": BonetBurton("bonet_burton"),
    "corotational_sofa": CorotationalSOFA("corotational_sofa", needs_rotation=True, exact_tangent=False),
}


def as_model(model: str | Model) -> Model:
    """The :class:`Model` named ``model`` in :data:`MODELS` (a model is returned as is)."""
    if isinstance(model, Model):
        return model
    if model not in MODELS:
        raise InputError(f"unknown model {model!r}; valid models are {', '.join(MODELS)}")
    return MODELS[model]


def strain_energy_density(model: str | Model, u: fem.Function, material: MaterialField,
                          orientation: fem.Function | None, rotation: PolarRotation | None = None
                          ) -> ufl.core.expr.Expr:
    """Energy per unit reference volume ``ψ = ½ e:C:e`` of the model's strain ``e`` (``ε``, ``E`` or ``ε_c``)."""
    return as_model(model).energy(u, material, orientation, rotation)


def first_piola_kirchhoff(model: str | Model, u: fem.Function, material: MaterialField,
                          orientation: fem.Function | None, rotation: PolarRotation | None = None
                          ) -> ufl.core.expr.Expr:
    """First Piola–Kirchhoff stress of the model: ``σ(ε)``, ``F S(E)`` or ``R σ(ε_c)`` (module docstring).

    ``rotation`` (a :class:`PolarRotation` of ``u``) is required by, and only used by, ``corotational``.
    """
    return as_model(model).first_piola_kirchhoff(u, material, orientation, rotation)
