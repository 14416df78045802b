"""Probes: scalar measurements of a displacement field, as the paper reports them (SI, angles in degrees).

Units as everywhere in the project (docs/conventions.md).

Each probe is a small object built once for a function space and a set of tags (forms compiled, node sets
located), then called on any displacement :class:`dolfinx.fem.Function` of that space, every load step:

* :class:`TipDeflection` — beam: mean displacement of the tip face along a direction (m, signed),
  ``∫_tip u·d̂ ds / ∫_tip ds`` over the reference face.
* :class:`CenterHeight` — Tripod: height of the deformed central region's centroid (m),
  ``∫_Ω_c (X + u)_z dx / ∫_Ω_c dx`` over the reference region.
* :class:`CenterRotation` — Tripod: rotation about the vertical axis of the best-fit rigid rotation of the
  central ring's nodes (degrees, counter-clockwise seen from above (+z) positive).
* :class:`CenterTilt` — Tripod: tilt of the same best-fit rotation about the x or the y axis (degrees), read from
  the ring's turned normal ``n = R e_z``: about x ``atan2(−n_y, n_z)``, about y ``atan2(n_x, n_z)``.

Probes of any named group (a facet group or a cell region), the scene probes ``"KIND:GROUP"``; vectors are
numpy arrays of 3 components:

* :class:`MeanDisplacement` — mean displacement of the group (m): ``∫ u dA / ∫ dA`` over a facet group,
  ``∫ u dX / ∫ dX`` over a cell region (reference measure).
* :class:`BestFitRotation` — rotation vector of the best-fit rigid rotation of the group's nodes (degrees; its
  direction the axis, its length the angle, in [0°, 180°]), Kabsch as :class:`CenterRotation`.
* :class:`EnclosedVolume` — volume enclosed by a closed facet group in the deformed configuration (m³),
  ``|⅓ ∫ x · n da| = |⅓ ∫ (X + u) · cof(F) N dA|`` (a chamber's volume, for pressure–volume curves).
* :class:`ReactionForce` — the force the supports exert on a prescribed group (N): the sum of the assembled
  ``internal − external`` nodal forces of :class:`fenicsfoam.solver.ElasticityProblem` over the group's
  prescribed nodes.

Every value is summed over ranks (``comm.allreduce``), so all ranks return the same number under ``mpirun``.
The functions :func:`tip_deflection`, :func:`center_height` and :func:`center_rotation` build the probe and
call it once, for one-off use.

Every probe also has ``gradient(u)``: the derivative of its value with respect to the displacement's degrees of
freedom (the owned ones, in the dof layout of ``u.x.array``), exact for the discrete functional (the best-fit
rotation differentiated through its polar decomposition, :func:`kabsch_rotation_gradient`); sensitivities
(:mod:`fenicsfoam.sensitivity`) use it as the right-hand side of the adjoint equations. Its forms are compiled
at the first call, so a probe that is only evaluated costs nothing more.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from foambase.errors import InputError

__all__ = [
    "BestFitRotation",
    "CenterHeight",
    "CenterRotation",
    "CenterTilt",
    "EnclosedVolume",
    "MeanDisplacement",
    "ReactionForce",
    "TipDeflection",
    "center_height",
    "center_rotation",
    "kabsch_rotation",
    "kabsch_rotation_gradient",
    "tilt_angle",
    "tip_deflection",
    "twist_angle",
]

logger = logging.getLogger(__name__)

Tags = int | Sequence[int]


def _as_tag_tuple(tags: Tags) -> tuple[int, ...]:
    """``tags`` as a non-empty tuple of ints (a single int allowed)."""
    values = (tags,) if isinstance(tags, int | np.integer) else tuple(tags)
    if not values or not all(isinstance(t, int | np.integer) for t in values):
        raise InputError(f"tags must be an int or a non-empty sequence of ints, got {tags!r}")
    return tuple(int(t) for t in values)


def _check_tags(
    meshtags: dolfinx.mesh.MeshTagsMetaClass, tags: Tags, mesh: dolfinx.mesh.Mesh, dim: int, kind: str
) -> tuple[int, ...]:
    """Raise ``InputError`` unless ``meshtags`` marks ``dim``-entities of ``mesh`` and each tag marks some entity."""
    tags = _as_tag_tuple(tags)
    if meshtags.mesh is not mesh._mesh:
        raise InputError(f"the {kind} tags belong to another mesh than the displacement's")
    if meshtags.dim != dim:
        raise InputError(f"{kind} tags must mark entities of dimension {dim}, got tags of dimension {meshtags.dim}")
    comm = mesh.comm
    counts = np.array([meshtags.find(tag).size for tag in tags], dtype=np.int64)
    total = np.empty_like(counts)
    comm.Allreduce(counts, total, op=MPI.SUM)
    missing = [tag for tag, n in zip(tags, total) if n == 0]
    if missing:
        available = sorted(set().union(*comm.allgather(set(np.unique(meshtags.values).tolist()))))
        raise InputError(f"{kind} tag(s) {missing} mark no entity of the mesh; available {kind} tags: {available}")
    return tags


def _check_displacement_space(V: dolfinx.fem.FunctionSpace) -> None:
    """Raise ``InputError`` unless ``V`` is a 3-component Lagrange space on a 3D mesh."""
    element = V.ufl_element()
    if element.family() not in ("Lagrange", "Q") or V.dofmap.index_map_bs != 3 or V.mesh.geometry.dim != 3:
        raise InputError(
            f"probes need a 3D vector Lagrange displacement space, got {element} with block size "
            f"{V.dofmap.index_map_bs} on a mesh of geometric dimension {V.mesh.geometry.dim}"
        )


def _check_same_space(u: dolfinx.fem.Function, V: dolfinx.fem.FunctionSpace) -> None:
    """Raise ``InputError`` unless ``u`` lives on the mesh and element of the probe's space ``V``."""
    if u.function_space.mesh is not V.mesh or u.function_space.ufl_element() != V.ufl_element():
        raise InputError(f"displacement in {u.function_space.ufl_element()} on another mesh or element than "
                         f"the probe's {V.ufl_element()}")


class _ScalarProbe:
    """A probe ``∫ f(u) dμ / ∫ dμ`` with both forms compiled once for a private copy of ``u``; ``size = ∫ dμ``."""

    def __init__(self, V: dolfinx.fem.FunctionSpace, integrand, measure: ufl.Measure) -> None:
        self._u = dolfinx.fem.Function(V)
        self._comm = V.mesh.comm
        self._functional = integrand(self._u) * measure
        self._form = dolfinx.fem.form(self._functional)
        self._gradient_form = None  # compiled at the first gradient()
        self.size = self._assemble(dolfinx.fem.form(dolfinx.fem.Constant(V.mesh, 1.0) * measure))

    def _assemble(self, form: dolfinx.fem.Form) -> float:
        return self._comm.allreduce(dolfinx.fem.assemble_scalar(form), op=MPI.SUM)

    def __call__(self, u: dolfinx.fem.Function) -> float:
        """The probe's value for the displacement ``u`` (a Function of the space the probe was built for)."""
        V = self._u.function_space
        _check_same_space(u, V)
        n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self._u.x.array[:n_owned] = u.x.array[:n_owned]
        self._u.x.scatter_forward()
        return self._assemble(self._form) / self.size

    def gradient(self, u: dolfinx.fem.Function) -> np.ndarray:
        """Derivative of the value with respect to the owned dofs of ``u`` (the form's derivative, assembled)."""
        V = self._u.function_space
        _check_same_space(u, V)
        self(u)  # copies u into the form's coefficient
        if self._gradient_form is None:
            self._gradient_form = dolfinx.fem.form(
                ufl.derivative(self._functional, self._u, ufl.TestFunction(V)))
        b = dolfinx.fem.petsc.assemble_vector(self._gradient_form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        gradient = b.array.copy() / self.size
        b.destroy()
        return gradient


class TipDeflection(_ScalarProbe):
    """Mean displacement of a face along a direction: ``δ = ∫_tip u·d̂ ds / ∫_tip ds`` (m, signed).

    The integrals are over the reference (undeformed) face. The sign follows ``direction``: with gravity
    ``g = −g e_z``, ``direction = (0, 0, 1)`` gives the paper's convention (a sagging tip is negative, Fig. 6:
    −48 mm), ``direction = g/|g|`` gives the sag as a positive number.

    Parameters
    ----------
    V : dolfinx.fem.FunctionSpace
        The displacement space (3D vector Lagrange).
    facet_tags : MeshTags
        Facet tags of the mesh.
    tip_tag : int
        Tag of the tip face (``meshes.beam.TIP_FACE``); must lie on the exterior boundary.
    direction : sequence of 3 floats
        Direction of measurement, normalised here.

    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, facet_tags, tip_tag: int, direction: Sequence[float]) -> None:
        _check_displacement_space(V)
        tdim = V.mesh.topology.dim
        tags = _check_tags(facet_tags, tip_tag, V.mesh, tdim - 1, "facet")
        d = np.asarray(direction, dtype=float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise InputError(f"direction must be a non-zero finite 3-vector, got {direction!r}")
        d_hat = ufl.as_vector((d / np.linalg.norm(d)).tolist())
        ds = ufl.Measure("ds", domain=V.mesh, subdomain_data=facet_tags, subdomain_id=tags)
        super().__init__(V, lambda u: ufl.inner(u, d_hat), ds)
        if self.size <= 0:
            raise InputError(f"facet tag {tip_tag} has zero area on the exterior boundary: not a boundary face")


class CenterHeight(_ScalarProbe):
    """Height of the deformed centroid of a region: ``z_c = ∫_Ω_c (X + u)_z dx / ∫_Ω_c dx`` (m).

    The region is given in the reference configuration; its reference volume weights the points. For the Tripod
    use ``meshes.tripod.RING`` (the probe ring) or ``meshes.tripod.REGIONS["centre"]``.

    Parameters
    ----------
    V : dolfinx.fem.FunctionSpace
        The displacement space (3D vector Lagrange).
    cell_tags : MeshTags
        Cell tags of the mesh.
    center_tag : int or sequence of int
        Cell tag(s) of the region.

    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, cell_tags, center_tag: Tags) -> None:
        _check_displacement_space(V)
        tags = _check_tags(cell_tags, center_tag, V.mesh, V.mesh.topology.dim, "cell")
        X = ufl.SpatialCoordinate(V.mesh)
        dx = ufl.Measure("dx", domain=V.mesh, subdomain_data=cell_tags, subdomain_id=tags)
        super().__init__(V, lambda u: X[2] + u[2], dx)


def kabsch_rotation(H: np.ndarray) -> np.ndarray:
    """Best-fit rotation from a cross-covariance ``H = Σ (X − X̄)(x − x̄)ᵀ`` (Kabsch).

    ``R = argmin_{R ∈ SO(3)} Σ |R (X − X̄) − (x − x̄)|²``: with the SVD ``H = U S Vᵀ``,
    ``R = V diag(1, 1, sign det(V Uᵀ)) Uᵀ``.
    """
    U, _, Vt = np.linalg.svd(np.asarray(H, dtype=float))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    return Vt.T @ np.diag([1.0, 1.0, d]) @ U.T


def _axial(M: np.ndarray) -> np.ndarray:
    """Axial vector of the skew part of ``M``: ``[axial(M)]× = (M − Mᵀ)/2``."""
    return 0.5 * np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])


def _cross_matrix(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def kabsch_rotation_gradient(H: np.ndarray, dfdR: np.ndarray, R: np.ndarray | None = None) -> np.ndarray:
    """``∂f/∂H`` of a function ``f(R)`` of the best-fit rotation ``R = kabsch_rotation(H)``, given ``∂f/∂R``.

    ``R`` is the rotation of the polar decomposition ``Hᵀ = R P`` (``P = Rᵀ Hᵀ`` symmetric positive
    definite). A change ``dH`` turns it by ``dR = R [ω]×`` with ``(tr P I − P) ω = 2 axial(Rᵀ dHᵀ)`` (the skew
    part of ``Rᵀ dHᵀ = [ω]× P + dP``), hence ``df = ∂f/∂R : dR = 4 a · axial(Rᵀ dHᵀ)`` with
    ``a = (tr P I − P)⁻¹ axial(Rᵀ ∂f/∂R)``, i.e. ``∂f/∂H = −2 [a]× Rᵀ``. Defined when the best fit is proper
    (``det H > 0``) and the points are not collinear (``tr P I − P`` invertible).
    """
    H = np.asarray(H, dtype=float)
    R = kabsch_rotation(H) if R is None else R
    P = R.T @ H.T
    P = 0.5 * (P + P.T)
    B = np.trace(P) * np.eye(3) - P
    a = np.linalg.solve(B, _axial(R.T @ np.asarray(dfdR, dtype=float)))
    return -2.0 * _cross_matrix(a) @ R.T


def _atan2_gradient(s: float, c: float) -> tuple[float, float, float]:
    """``atan2(s, c)`` and its partial derivatives with respect to ``s`` and ``c``."""
    r2 = s * s + c * c
    return math.atan2(s, c), c / r2, -s / r2


def twist_angle(R: np.ndarray) -> float:
    """Twist (rad) about e_z of a rotation, from its swing–twist decomposition ``R = R_swing R_twist``.

    ``R_twist`` turns by ψ about e_z, ``R_swing`` about a horizontal axis. With ``R``'s unit quaternion
    ``(w, v)``, ``ψ = 2 atan2(v_z, w)``; since ``R₁₀ − R₀₁ = 4 w v_z`` and ``R₀₀ + R₁₁ = 2 (w² − v_z²)``,
    ``ψ = atan2(R₁₀ − R₀₁, R₀₀ + R₁₁) ∈ (−π, π]``. Undefined when ``w = v_z = 0`` (e_z turned upside down).
    """
    s, c = R[1, 0] - R[0, 1], R[0, 0] + R[1, 1]
    if math.hypot(s, c) < 1e-10:
        raise InputError("twist about z undefined: the rotation turns e_z upside down (swing of 180°)")
    return math.atan2(s, c)


def _twist_and_gradient(R: np.ndarray) -> tuple[float, np.ndarray]:
    """:func:`twist_angle` (rad) and its derivative with respect to ``R``."""
    psi = twist_angle(R)
    _, ds, dc = _atan2_gradient(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1])
    G = np.zeros((3, 3))
    G[1, 0], G[0, 1], G[0, 0], G[1, 1] = ds, -ds, dc, dc
    return psi, G


def tilt_angle(R: np.ndarray, axis: str) -> float:
    """Tilt (rad) about the x or y axis of a rotation, read from the turned normal ``n = R e_z``.

    About x: ``atan2(−n_y, n_z)``; about y: ``atan2(n_x, n_z)`` (a rotation by α about x, resp. y, tilts by α;
    a twist about e_z does not tilt). Undefined when ``n`` is horizontal along the other axis.
    """
    return _tilt_and_gradient(R, axis)[0]


def _tilt_and_gradient(R: np.ndarray, axis: str) -> tuple[float, np.ndarray]:
    """:func:`tilt_angle` (rad) and its derivative with respect to ``R``."""
    if axis not in ("x", "y"):
        raise InputError(f"tilt axis must be 'x' or 'y', got {axis!r}")
    row, sign = (1, -1.0) if axis == "x" else (0, 1.0)
    s, c = sign * R[row, 2], R[2, 2]
    if math.hypot(s, c) < 1e-10:
        raise InputError(f"tilt about {axis} undefined: the normal R e_z lies along the other horizontal axis")
    angle, ds, dc = _atan2_gradient(s, c)
    G = np.zeros((3, 3))
    G[row, 2], G[2, 2] = sign * ds, dc
    return angle, G


class _NodeFit:
    """The owned dof nodes of a group (entities of ``meshtags``' dimension), for a best-fit rotation (Kabsch)."""

    def __init__(self, V: dolfinx.fem.FunctionSpace, meshtags, tags: Tags, kind: str) -> None:
        _check_displacement_space(V)
        tags = _check_tags(meshtags, tags, V.mesh, meshtags.dim, kind)
        self._comm = V.mesh.comm
        entities = np.concatenate([meshtags.find(tag) for tag in tags])
        V.mesh.topology.create_connectivity(meshtags.dim, V.mesh.topology.dim)
        # remote=True (the default) also returns the dofs this rank owns on the group's entities of other ranks.
        dofs = dolfinx.fem.locate_dofs_topological(V, meshtags.dim, entities, remote=True)
        self._nodes = dofs[dofs < V.dofmap.index_map.size_local]
        X = V.tabulate_dof_coordinates()[self._nodes]
        sums = np.append(X.sum(axis=0), len(self._nodes))
        total = np.empty_like(sums)
        self._comm.Allreduce(sums, total, op=MPI.SUM)
        self.n_nodes = int(total[3])
        self._X_mean = total[:3] / total[3]
        self._dX = X - self._X_mean
        spread = self._allreduce(self._dX.T @ self._dX)
        if np.linalg.matrix_rank(spread, tol=1e-10 * np.trace(spread)) < 2:
            raise InputError(f"the {self.n_nodes} nodes of {kind} tag(s) {list(tags)} are collinear: rotation "
                             "undefined")
        self._V = V

    def _allreduce(self, local: np.ndarray) -> np.ndarray:
        total = np.empty_like(local)
        self._comm.Allreduce(np.ascontiguousarray(local), total, op=MPI.SUM)
        return total

    def rotation_matrix(self, u: dolfinx.fem.Function) -> np.ndarray:
        """The best-fit rotation ``R`` (3×3) of the nodes for the displacement ``u``, same on every rank."""
        return kabsch_rotation(self._cross_covariance(u))

    def _cross_covariance(self, u: dolfinx.fem.Function) -> np.ndarray:
        _check_same_space(u, self._V)
        x = self._dX + u.x.array.reshape(-1, 3)[self._nodes]
        return self._allreduce(self._dX.T @ x)


class BestFitRotation(_NodeFit):
    """Rotation vector (degrees) of the best-fit rigid rotation of a group's nodes.

    The nodes are the dof points of the displacement's Lagrange space on the group's entities (facets of a facet
    group, cells of a region), owned dofs only, equal weights; ``R`` as :meth:`CenterRotation.rotation_matrix`
    (Kabsch), returned as its rotation vector ``θ â`` in degrees (``scipy``'s ``as_rotvec``), 0 ≤ θ ≤ 180°.

    Parameters
    ----------
    V : dolfinx.fem.FunctionSpace
        The displacement space (3D vector Lagrange).
    meshtags : MeshTags
        Facet tags or cell tags of the mesh.
    tags : int or sequence of int
        The group's tag(s).

    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, meshtags, tags: Tags) -> None:
        super().__init__(V, meshtags, tags, "facet" if meshtags.dim == V.mesh.topology.dim - 1 else "cell")

    def __call__(self, u: dolfinx.fem.Function) -> np.ndarray:
        """Rotation vector (degrees, 3 components) for the displacement ``u``."""
        from scipy.spatial.transform import Rotation
        return Rotation.from_matrix(self.rotation_matrix(u)).as_rotvec(degrees=True)


class CenterRotation(_NodeFit):
    """Rotation about the vertical axis of a region's nodes (deg, counter-clockwise seen from +z positive).

    The nodes are the dof points of the displacement's Lagrange space on the region's cells (the vertices for
    P1, vertices and edge midpoints for P2), each counted once (owned dofs only), with equal weights. With
    reference positions X and deformed positions x = X + u, the cross-covariance
    ``H = Σ (X − X̄)(x − x̄)ᵀ = Σ (X − X̄)(x − X̄)ᵀ`` (as ``Σ (X − X̄) = 0``) is summed over ranks;
    every rank then computes the same best-fit rotation :func:`kabsch_rotation` and returns its twist about e_z
    (:func:`twist_angle`), in degrees, in (−180°, 180°]. The ring's translation and tilt (swing) do not change
    the value.

    Parameters
    ----------
    V : dolfinx.fem.FunctionSpace
        The displacement space (3D vector Lagrange).
    cell_tags : MeshTags
        Cell tags of the mesh.
    ring_tag : int or sequence of int
        Cell tag(s) of the region, e.g. ``meshes.tripod.RING``.

    Attributes
    ----------
    n_nodes : int
        Global number of nodes in the fit.

    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, cell_tags, ring_tag: Tags) -> None:
        if cell_tags.dim != V.mesh.topology.dim:
            raise InputError(f"cell tags must mark entities of dimension {V.mesh.topology.dim}, got tags of "
                             f"dimension {cell_tags.dim}")
        super().__init__(V, cell_tags, ring_tag, "cell")

    def _angle(self, R: np.ndarray) -> tuple[float, np.ndarray]:
        """The probe's angle (rad) of the best-fit rotation ``R``, and its derivative with respect to ``R``."""
        return _twist_and_gradient(R)

    def __call__(self, u: dolfinx.fem.Function) -> float:
        """Twist about e_z (degrees) of the best-fit rotation for the displacement ``u``."""
        return math.degrees(self._angle(self.rotation_matrix(u))[0])

    def gradient(self, u: dolfinx.fem.Function) -> np.ndarray:
        """Derivative of the angle (degrees) with respect to the owned dofs of ``u``.

        With ``H = Σ (X − X̄) xᵀ``, ``∂angle/∂u_i = (X_i − X̄)ᵀ ∂angle/∂H`` at each node of the fit
        (:func:`kabsch_rotation_gradient`), zero elsewhere.
        """
        H = self._cross_covariance(u)
        R = kabsch_rotation(H)
        _, dR = self._angle(R)
        dH = kabsch_rotation_gradient(H, dR, R)
        V = self._V
        gradient = np.zeros((V.dofmap.index_map.size_local, 3))
        gradient[self._nodes] = math.degrees(1.0) * (self._dX @ dH)
        return gradient.ravel()


class CenterTilt(CenterRotation):
    """Tilt about the x or y axis of a region's best-fit rotation (deg), e.g. of the Tripod's probe ring.

    The fit is the one of :class:`CenterRotation`; the tilt is :func:`tilt_angle` of it, by the right-hand rule:
    a positive tilt about x raises the ring's +y side (its normal ``R e_z`` leans towards −y), a positive tilt
    about y lowers its +x side (the normal leans towards +x). A twist about e_z does not change either tilt.
    Parameters as :class:`CenterRotation`, plus ``axis`` (``"x"`` or ``"y"``).
    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, cell_tags, ring_tag: Tags, axis: str) -> None:
        if axis not in ("x", "y"):
            raise InputError(f"tilt axis must be 'x' or 'y', got {axis!r}")
        super().__init__(V, cell_tags, ring_tag)
        self.axis = axis

    def _angle(self, R: np.ndarray) -> tuple[float, np.ndarray]:
        return _tilt_and_gradient(R, self.axis)

    def __call__(self, u: dolfinx.fem.Function) -> float:
        """Tilt about the probe's axis (degrees) of the best-fit rotation for the displacement ``u``."""
        return math.degrees(self._angle(self.rotation_matrix(u))[0])


class _VectorProbe:
    """``∫ f(u) dμ`` (components summed over ranks) with its forms compiled once for a private copy of ``u``."""

    def __init__(self, V: dolfinx.fem.FunctionSpace, integrand, measure: ufl.Measure, size: int = 3) -> None:
        self._u = dolfinx.fem.Function(V)
        self._comm = V.mesh.comm
        value = integrand(self._u)
        self._forms = [dolfinx.fem.form((value[i] if size > 1 else value) * measure) for i in range(size)]

    def _integrals(self, u: dolfinx.fem.Function) -> np.ndarray:
        V = self._u.function_space
        _check_same_space(u, V)
        n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self._u.x.array[:n_owned] = u.x.array[:n_owned]
        self._u.x.scatter_forward()
        local = np.array([dolfinx.fem.assemble_scalar(form) for form in self._forms])
        total = np.empty(len(local))
        self._comm.Allreduce(local, total, op=MPI.SUM)
        return total


def _group_measure(V: dolfinx.fem.FunctionSpace, meshtags, tags: Tags) -> tuple[ufl.Measure, tuple[int, ...], str]:
    """``ds`` over a boundary facet group or ``dx`` over a cell region, by the dimension of ``meshtags``."""
    tdim = V.mesh.topology.dim
    if meshtags.dim == tdim - 1:
        tags = _check_tags(meshtags, tags, V.mesh, tdim - 1, "facet")
        return ufl.Measure("ds", domain=V.mesh, subdomain_data=meshtags, subdomain_id=tags), tags, "facet"
    tags = _check_tags(meshtags, tags, V.mesh, tdim, "cell")
    return ufl.Measure("dx", domain=V.mesh, subdomain_data=meshtags, subdomain_id=tags), tags, "cell"


class MeanDisplacement(_VectorProbe):
    """Mean displacement of a group (m, 3 components): ``∫ u dA / ∫ dA`` (facets) or ``∫ u dX / ∫ dX`` (cells).

    Reference measure; a facet group must lie on the boundary (``ds``).
    """

    def __init__(self, V: dolfinx.fem.FunctionSpace, meshtags, tags: Tags) -> None:
        _check_displacement_space(V)
        measure, tags, kind = _group_measure(V, meshtags, tags)
        super().__init__(V, lambda u: u, measure)
        self._measure, self._gradient_forms = measure, {}
        self.size = self._comm.allreduce(
            dolfinx.fem.assemble_scalar(dolfinx.fem.form(dolfinx.fem.Constant(V.mesh, 1.0) * measure)), op=MPI.SUM)
        if not self.size > 0:
            raise InputError(f"{kind} tag(s) {list(tags)} have zero measure"
                             + (" on the boundary: not a boundary facet group" if kind == "facet" else ""))

    def __call__(self, u: dolfinx.fem.Function) -> np.ndarray:
        """Mean displacement (m) for ``u``."""
        return self._integrals(u) / self.size

    def gradient(self, u: dolfinx.fem.Function, component: int) -> np.ndarray:
        """Derivative of the mean's ``component`` (0, 1, 2) with respect to the owned dofs of ``u`` (it is linear)."""
        V = self._u.function_space
        _check_same_space(u, V)
        if component not in self._gradient_forms:
            self._gradient_forms[component] = dolfinx.fem.form(ufl.TestFunction(V)[component] * self._measure)
        b = dolfinx.fem.petsc.assemble_vector(self._gradient_forms[component])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        gradient = b.array.copy() / self.size
        b.destroy()
        return gradient


class EnclosedVolume(_VectorProbe):
    """Volume (m³) enclosed by a closed boundary facet group in the deformed configuration.

    ``V = |⅓ ∫ x · n da| = |⅓ ∫ (X + u) · cof(F) N dA|`` over the reference facets (a cavity's walls, whose outward
    normal points into the cavity, or a body's outer boundary). The group must be closed: ``|∫ N dA|`` at most
    1e-6 of its area (else :class:`~foambase.errors.InputError`), where the value does not depend on the origin.
    """

    #: Largest ``|∫ N dA| / ∫ dA`` accepted for a closed surface.
    CLOSED_TOL = 1e-6

    def __init__(self, V: dolfinx.fem.FunctionSpace, facet_tags, tags: Tags) -> None:
        from fenicsfoam.loads import cofactor

        _check_displacement_space(V)
        tdim = V.mesh.topology.dim
        tags = _check_tags(facet_tags, tags, V.mesh, tdim - 1, "facet")
        ds = ufl.Measure("ds", domain=V.mesh, subdomain_data=facet_tags, subdomain_id=tags)
        N = ufl.FacetNormal(V.mesh)
        X = ufl.SpatialCoordinate(V.mesh)
        normal = _VectorProbe(V, lambda u: N, ds)._integrals(dolfinx.fem.Function(V))
        area = V.mesh.comm.allreduce(
            dolfinx.fem.assemble_scalar(dolfinx.fem.form(dolfinx.fem.Constant(V.mesh, 1.0) * ds)), op=MPI.SUM)
        if not area > 0:
            raise InputError(f"facet tag(s) {list(tags)} have zero area on the boundary: not a boundary facet group")
        if np.linalg.norm(normal) > self.CLOSED_TOL * area:
            raise InputError(f"facet tag(s) {list(tags)} do not form a closed surface (|∫ N dA| = "
                             f"{np.linalg.norm(normal) / area:.3g} of its area): enclosed volume undefined")

        def flux(u):
            return ufl.inner(X + u, cofactor(ufl.Identity(3) + ufl.grad(u)) * N) / 3.0

        super().__init__(V, flux, ds, size=1)

    def __call__(self, u: dolfinx.fem.Function) -> float:
        """Enclosed volume (m³) for ``u``."""
        return float(abs(self._integrals(u)[0]))


class ReactionForce:
    """The force (N, 3 components) the supports exert on a prescribed group, from the residual.

    ``R = Σ_k r_k`` over the group's nodes, ``r`` the assembled internal − external nodal forces of the problem
    (:meth:`fenicsfoam.solver.ElasticityProblem.internal_minus_external`) at its current state, owned nodes only,
    summed over ranks. At equilibrium the reactions of all supports balance the applied loads:
    ``Σ R + ∫ ρ g dX + Σ loads = 0`` (the internal forces sum to zero). The force the body exerts on the support
    (a blocked force, a load cell's reading) is ``−R``. Nodes shared by two prescribed groups count in both.

    Parameters
    ----------
    problem : fenicsfoam.solver.ElasticityProblem
        The problem whose motions prescribe the group.
    meshtags : MeshTags
        Facet tags or cell tags of the mesh.
    tags : int or sequence of int
        The group's tag(s); every node of the group must be prescribed by a motion of ``problem``.

    """

    def __init__(self, problem, meshtags, tags: Tags) -> None:
        V = problem.V
        kind = "facet" if meshtags.dim == V.mesh.topology.dim - 1 else "cell"
        tags = _check_tags(meshtags, tags, V.mesh, meshtags.dim, kind)
        V.mesh.topology.create_connectivity(meshtags.dim, V.mesh.topology.dim)
        entities = np.concatenate([meshtags.find(tag) for tag in tags])
        dofs = dolfinx.fem.locate_dofs_topological(V, meshtags.dim, entities, remote=True)
        self._nodes = dofs[dofs < V.dofmap.index_map.size_local]
        prescribed = np.concatenate([m.dofs for m in problem.motions.values()]) if problem.motions else np.empty(0)
        free = int(np.count_nonzero(~np.isin(self._nodes, prescribed)))
        free = V.mesh.comm.allreduce(free, op=MPI.SUM)
        if free:
            raise InputError(f"{free} node(s) of {kind} tag(s) {list(tags)} are not prescribed: a reaction force is "
                             "defined on clamped or moved groups only")
        self._problem, self._comm = problem, V.mesh.comm

    def __call__(self, u: dolfinx.fem.Function | None = None) -> np.ndarray:
        """The reaction (N) at the problem's current state (``u`` must be the problem's displacement, or None)."""
        if u is not None and u is not self._problem.u:
            raise InputError("ReactionForce reads the problem's own state: pass problem.u or nothing")
        b = self._problem.internal_minus_external()
        local = b.array.reshape(-1, 3)[self._nodes].sum(axis=0)
        b.destroy()
        total = np.empty(3)
        self._comm.Allreduce(np.ascontiguousarray(local), total, op=MPI.SUM)
        return total


def tip_deflection(u: dolfinx.fem.Function, facet_tags, tip_tag: int, direction: Sequence[float]) -> float:
    """One-off :class:`TipDeflection` of ``u`` (compiles its forms: build the class once for repeated calls)."""
    return TipDeflection(u.function_space, facet_tags, tip_tag, direction)(u)


def center_height(u: dolfinx.fem.Function, cell_tags, center_tag: Tags) -> float:
    """One-off :class:`CenterHeight` of ``u`` (compiles its forms: build the class once for repeated calls)."""
    return CenterHeight(u.function_space, cell_tags, center_tag)(u)


def center_rotation(u: dolfinx.fem.Function, cell_tags, ring_tag: Tags) -> float:
    """One-off :class:`CenterRotation` of ``u`` in degrees."""
    return CenterRotation(u.function_space, cell_tags, ring_tag)(u)
