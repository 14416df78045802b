"""External loads on named facet groups: dead tractions and total forces, follower pressure, cables (tendons).

Every load has a name and a load factor ``s`` set by :class:`fenicsfoam.solver.LoadStep` (``factors``), starting at
0; its contribution to the residual ``R(u) = internal − external forces`` is scaled by ``s``. A solver adds what a
problem declares and nothing else (no forms, no coefficients for a problem without loads).

* :class:`SurfaceTraction` — a dead load on the reference surface: a traction ``t`` (Pa, per unit reference area)
  or a total force ``F`` (N) spread uniformly over the group's reference area ``A₀`` (``t = F / A₀``):
  ``R ∋ −s ∫_Γ t · v dA``.
* :class:`FollowerPressure` — a pressure ``p`` (Pa) on the deformed surface, along the body's inward normal (a
  chamber inflated by ``p > 0`` pushes its walls outwards of the chamber): by Nanson's formula
  ``n da = cof(F) N dA``, ``R ∋ +s p ∫_Γ cof(F) N · v dA``. The consistent tangent is ``ufl.derivative`` of this
  term (the solver differentiates the whole residual); it is not symmetric on an open surface. ``cof(F) = J F⁻ᵀ``
  is written by columns, ``cof(F) e_i = F e_j × F e_k`` (i, j, k cyclic), a polynomial of ``∇u``, so the
  quadrature is exact and the net force of a pressure on a closed cavity vanishes to round-off.
* :class:`Cable` — a tendon of constant tension ``T`` (N) through via points attached to the body, optionally
  ending at a pull point fixed in space (the motor). Force mode of SOFA SoftRobots' ``CableConstraint``: its
  potential is ``s T L(x)``, ``L`` the length of the polyline through the deformed via points ``x_i`` (and the pull
  point), so the via points are pulled along the deformed route (``f_i = s T (e_{i,i−1} + e_{i,i+1})``, ``e`` the
  unit vectors towards the neighbours) and the tangent is ``s T ∂²L/∂x²`` (per segment ``(I − e eᵀ)/l``). A via
  point is a weighted mean of mesh nodes, ``x_i = Σ_k w_ik (X_k + u_k)`` with ``Σ_k w_ik = 1``: the nearest node
  to a given point (weight 1), or the nodes of a facet group with the consistent weights ``w_k = ∫ φ_k dA / A₀``
  (the force is then spread uniformly over the group, like :class:`SurfaceTraction`).

*Geometrically linear models* (``Model.finite_strain`` false, the ``linear`` model) see every load on the reference
configuration: the pressure along the reference normal ``N dA``, the cable along its reference route (constant
forces, no load tangent), consistent with the small-displacement assumption of the model.

*Parallel*: the surface integrals run over exterior facets, each owned by exactly one rank; a cable's via
positions are summed over ranks (``Allreduce``) and each rank adds the forces and tangent blocks of the nodes it
owns, so nothing is counted twice under ``mpirun``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import assemble_vector
from dolfinx.mesh import exterior_facet_indices
from mpi4py import MPI
from petsc4py import PETSc

from foambase.errors import InputError

__all__ = ["Cable", "Facets", "FollowerPressure", "Load", "SurfaceTraction", "cofactor", "surface_group"]

logger = logging.getLogger(__name__)


def cofactor(F: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """``cof F = det(F) F⁻ᵀ`` of a 3×3 UFL tensor, by columns ``F e_j × F e_k``: a polynomial in ``F``."""
    c = [F[:, i] for i in range(3)]
    return ufl.as_matrix([[ufl.cross(c[1], c[2])[r], ufl.cross(c[2], c[0])[r], ufl.cross(c[0], c[1])[r]]
                          for r in range(3)])


def _as_tags(tags: int | Sequence[int]) -> tuple[int, ...]:
    values = (tags,) if isinstance(tags, int | np.integer) else tuple(tags)
    if not values or not all(isinstance(t, int | np.integer) for t in values):
        raise InputError(f"facet tags must be an int or a non-empty sequence of ints, got {tags!r}")
    return tuple(int(t) for t in values)


def surface_group(name: str, mesh, facet_tags, tags: int | Sequence[int]) -> tuple[ufl.Measure, float]:
    """The ``ds`` measure of a boundary facet group and its reference area (m²), checked (collective).

    Raises
    ------
    InputError
        A tag marks no facet, a facet of the group is interior (surface loads act on the boundary), or the group
        has zero area.

    """
    tags = _as_tags(tags)
    comm = mesh.comm
    tdim = mesh.topology.dim
    if facet_tags.dim != tdim - 1:
        raise InputError(f"load {name!r}: facet tags of dimension {tdim - 1} expected, got {facet_tags.dim}")
    mesh.topology.create_connectivity(tdim - 1, tdim)
    n_owned = mesh.topology.index_map(tdim - 1).size_local
    exterior = exterior_facet_indices(mesh.topology)
    counts = []
    for tag in tags:
        facets = facet_tags.find(tag)
        facets = facets[facets < n_owned]
        counts.append((facets.size, int(np.count_nonzero(~np.isin(facets, exterior)))))
    total = np.array(comm.allreduce(np.array(counts, dtype=np.int64), op=MPI.SUM)).reshape(-1, 2)
    for tag, (n, interior) in zip(tags, total):
        if n == 0:
            raise InputError(f"load {name!r}: facet tag {tag} marks no facet of the mesh")
        if interior:
            raise InputError(f"load {name!r}: {interior} of the {n} facets of tag {tag} are interior facets; surface "
                             "loads act on boundary facets (a chamber must be a cavity of the mesh, not a meshed "
                             "volume)")
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=facet_tags, subdomain_id=tags)
    area = comm.allreduce(fem.assemble_scalar(fem.form(fem.Constant(mesh, 1.0) * ds)), op=MPI.SUM)
    if not area > 0:
        raise InputError(f"load {name!r}: facet tags {list(tags)} have zero area")
    return ds, area


class Load:
    """A named external load; the solver owns its factor (a ``fem.Constant`` for UFL loads)."""

    name: str

    def residual(self, u: fem.Function, v: ufl.Argument, factor: fem.Constant, finite_strain: bool):
        """Its UFL term of ``R(u)`` (internal − external forces) at factor 1 × ``factor``; ``None`` if not UFL."""
        return None

    def net_force(self) -> np.ndarray | None:
        """The total force (N) of the load at factor 1 if it does not depend on the deformation, else ``None``."""
        return None

    def setup(self, V: fem.FunctionSpace) -> None:
        """Attach the load to the displacement space (called by the solver; nothing to do for UFL loads)."""


@dataclass
class SurfaceTraction(Load):
    """A dead traction on a boundary facet group: ``traction`` (Pa) or a total ``force`` (N) over its area.

    Give exactly one of ``traction`` and ``force``. ``area`` (m², reference) is known after construction.
    """

    name: str
    mesh: object
    facet_tags: object
    tags: int | Sequence[int]
    traction: Sequence[float] | None = None
    force: Sequence[float] | None = None

    def __post_init__(self):
        if (self.traction is None) == (self.force is None):
            raise InputError(f"load {self.name!r}: give exactly one of traction (Pa) and force (N)")
        vector = np.asarray(self.traction if self.force is None else self.force, dtype=float)
        if vector.shape != (3,) or not np.all(np.isfinite(vector)):
            raise InputError(f"load {self.name!r}: expected a finite 3-vector, got {vector.tolist()}")
        self.ds, self.area = surface_group(self.name, self.mesh, self.facet_tags, self.tags)
        self.vector = vector / self.area if self.force is not None else vector  # the traction (Pa)

    def residual(self, u, v, factor, finite_strain):
        """``−s ∫ t · v dA``."""
        return -factor * ufl.inner(ufl.as_vector(self.vector.tolist()), v) * self.ds

    def net_force(self) -> np.ndarray:
        """``t A₀`` (N)."""
        return self.vector * self.area


@dataclass
class FollowerPressure(Load):
    """A pressure (Pa) on a boundary facet group, on the deformed surface (finite-strain models).

    Positive pressure pushes the surface into the body (along ``−n``, ``n`` the body's outward normal): for a
    chamber (a cavity of the mesh) it inflates the chamber.
    """

    name: str
    mesh: object
    facet_tags: object
    tags: int | Sequence[int]
    pressure: float

    def __post_init__(self):
        if not np.isfinite(self.pressure):
            raise InputError(f"load {self.name!r}: pressure must be finite, got {self.pressure!r}")
        self.ds, self.area = surface_group(self.name, self.mesh, self.facet_tags, self.tags)

    def residual(self, u, v, factor, finite_strain):
        """``s p ∫ cof(F) N · v dA`` (finite strain) or ``s p ∫ N · v dA`` (geometrically linear)."""
        N = ufl.FacetNormal(self.mesh)
        if finite_strain:
            normal = cofactor(ufl.Identity(3) + ufl.grad(u)) * N  # n da / dA
        else:
            normal = N
        return factor * float(self.pressure) * ufl.inner(normal, v) * self.ds


@dataclass(frozen=True)
class Facets:
    """A via point of a :class:`Cable` spread over a boundary facet group (its tags)."""

    tags: int | tuple[int, ...]


class Cable(Load):
    """A tendon of tension ``tension`` (N) through via points on the body, optionally to a fixed ``pull_point``.

    The solver attaches it to the displacement space (:meth:`setup`) when the problem is built.

    Parameters
    ----------
    name
        The load's name (its factor scales the tension).
    via
        The via points in order along the cable: each a point ``(x, y, z)`` (attached to the nearest node) or
        :class:`Facets` (the nodes of that boundary facet group, area weights). At least two entries without a
        pull point, one with it.
    tension
        The tension at factor 1 (N), ≥ 0 (a cable cannot push).
    pull_point
        A point fixed in space where the cable leaves towards its motor, or ``None``.
    facet_tags
        The mesh's facet tags (needed if a via point is a facet group).

    Attributes
    ----------
    reference_points
        (n, 3) reference positions of the via points (the nearest nodes' positions for given points), once set up.

    """

    def __init__(self, name: str, via: Sequence, tension: float, pull_point: Sequence[float] | None = None,
                 facet_tags=None):
        self.name = name
        if not (np.isfinite(tension) and tension >= 0):
            raise InputError(f"cable {name!r}: tension must be a finite number >= 0 (N), got {tension!r}")
        self.tension = float(tension)
        self.pull_point = None if pull_point is None else np.asarray(pull_point, dtype=float).reshape(3)
        if len(via) < (1 if self.pull_point is not None else 2):
            raise InputError(f"cable {name!r}: needs at least two via points, or one and a pull point")
        for i, entry in enumerate(via):
            if isinstance(entry, Facets):
                if facet_tags is None:
                    raise InputError(f"cable {name!r}: via point {i} is a facet group but no facet tags were given")
                continue
            point = np.asarray(entry, dtype=float) if not isinstance(entry, str) else None
            if point is None or point.shape != (3,) or not np.all(np.isfinite(point)):
                raise InputError(f"cable {name!r}: via point {i} must be (x, y, z) or Facets(tags), got {entry!r}")
        self.via, self.facet_tags = list(via), facet_tags
        self.V = None

    def setup(self, V: fem.FunctionSpace) -> None:
        """Attach the via points to the nodes of the displacement space ``V`` (collective)."""
        self.V = V
        mesh = V.mesh
        self._comm = mesh.comm
        self._bs = V.dofmap.index_map_bs
        index_map = V.dofmap.index_map
        self._n_owned = index_map.size_local
        owned = V.tabulate_dof_coordinates()[: self._n_owned]
        #: per via point: (owned local nodes, their weights) on this rank
        self._local: list[tuple[np.ndarray, np.ndarray]] = []
        for i, entry in enumerate(self.via):
            if isinstance(entry, Facets):
                self._local.append(self._group_weights(i, _as_tags(entry.tags)))
            else:
                self._local.append(self._nearest_node(i, np.asarray(entry, dtype=float), owned))
        self._X = np.array([self._sum(w @ owned[n]) for n, w in self._local])  # reference via positions
        self.reference_points = self._X.copy()
        route = self._route(self._X)
        lengths = np.linalg.norm(np.diff(route, axis=0), axis=1)
        if np.any(lengths <= 1e-9 * np.ptp(route, axis=0).max()):
            raise InputError(f"cable {self.name!r}: two consecutive points coincide (segment lengths "
                             f"{lengths.tolist()} m)")
        # Global node numbers of every via point's nodes, with their weights (the tangent's rows and columns).
        self._global_owned = index_map.local_to_global(np.arange(self._n_owned, dtype=np.int32)).astype(np.int64)
        gathered = self._comm.allgather([(self._global_owned[n], w) for n, w in self._local])
        self._global = [(np.concatenate([g[i][0] for g in gathered]).astype(PETSc.IntType),
                         np.concatenate([g[i][1] for g in gathered])) for i in range(len(self.via))]
        self.set_constrained(np.empty(0, dtype=np.int64))  # until the solver gives its Dirichlet nodes

    # ---------------------------------------------------------------------------------------------
    def _sum(self, local: np.ndarray) -> np.ndarray:
        local = np.ascontiguousarray(local, dtype=float)
        total = np.empty_like(local)
        self._comm.Allreduce(local, total, op=MPI.SUM)
        return total

    def _nearest_node(self, i: int, p: np.ndarray, owned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.linalg.norm(owned - p, axis=1)
        k = int(np.argmin(d)) if d.size else -1
        best = (float(d[k]) if d.size else np.inf, self._comm.rank)
        winner = min(self._comm.allgather(best))
        logger.info("cable %s: via point %d %s attached to the node %.3g m away", self.name, i, p.tolist(),
                    winner[0])
        if self._comm.rank == winner[1]:
            return np.array([k], dtype=np.int32), np.ones(1)
        return np.empty(0, dtype=np.int32), np.empty(0)

    def _group_weights(self, i: int, tags: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        ds, area = surface_group(f"{self.name}[{i}]", self.V.mesh, self.facet_tags, tags)
        v = ufl.TestFunction(self.V)
        b = assemble_vector(fem.form(v[0] * ds))
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        integrals = b.array.reshape(-1, self._bs)[:, 0].copy()
        b.destroy()
        largest = self._comm.allreduce(float(np.abs(integrals).max(initial=0.0)), op=MPI.MAX)
        nodes = np.flatnonzero(np.abs(integrals) > 1e-12 * largest).astype(np.int32)  # P2: vertices weigh 0
        return nodes, integrals[nodes] / area

    def _route(self, points: np.ndarray) -> np.ndarray:
        return points if self.pull_point is None else np.vstack([points, self.pull_point])

    # ---------------------------------------------------------------------------------------------
    def positions(self, u: fem.Function | None) -> np.ndarray:
        """(n, 3) via point positions ``x_i = Σ w_ik (X_k + u_k)`` for ``u`` (``None``: reference); collective."""
        if u is None:
            return self._X.copy()
        values = u.x.array.reshape(-1, self._bs)
        return self._X + np.array([self._sum(w @ values[n]) for n, w in self._local])

    def length(self, u: fem.Function | None) -> float:
        """Length of the cable (m) through the via points (and the pull point) for ``u``; collective."""
        return float(np.linalg.norm(np.diff(self._route(self.positions(u)), axis=0), axis=1).sum())

    def _gradient(self, points: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int, np.ndarray]]]:
        """``∂L/∂x_i`` (n, 3) and the tangent blocks ``(i, j, ∂²L/∂x_i∂x_j)`` of the via points."""
        route = self._route(points)
        n = len(points)
        gradient = np.zeros((n, 3))
        blocks = []
        for a in range(len(route) - 1):
            d = route[a + 1] - route[a]
            length = np.linalg.norm(d)
            e = d / length
            K = (np.eye(3) - np.outer(e, e)) / length
            b = a + 1
            gradient[a] -= e
            blocks.append((a, a, K))
            if b < n:  # not the pull point
                gradient[b] += e
                blocks += [(b, b, K), (a, b, -K), (b, a, -K)]
        return gradient, blocks

    def add_residual(self, b: PETSc.Vec, u: fem.Function, factor: float, follow: bool) -> None:
        """Add ``factor · T ∂L/∂u`` to the owned entries of the assembled vector ``b`` (collective)."""
        points = self.positions(u if follow else None)
        gradient, _ = self._gradient(points)
        scale = factor * self.tension
        with b.localForm() as local:
            array = local.array.reshape(-1, self._bs)
            for (nodes, weights), g in zip(self._local, gradient):
                array[nodes] += scale * np.outer(weights, g)

    def set_constrained(self, global_nodes: np.ndarray, components: np.ndarray | None = None) -> None:
        """Leave the prescribed (Dirichlet) rows and columns out of the tangent (collective).

        ``global_nodes`` are global node numbers, ``components`` (n, 3) booleans say which of their components are
        prescribed (default: all).
        """
        nodes = np.asarray(global_nodes, dtype=np.int64)
        masks = np.ones((len(nodes), 3), dtype=bool) if components is None else np.asarray(components, dtype=bool)
        lookup = dict(zip(nodes.tolist(), masks))
        free = np.ones(3, dtype=bool)
        owned = set(self._global_owned.tolist())
        _, blocks = self._gradient(self._X)
        #: per tangent block (i, j): kept rows (owned, not fully prescribed), their weights and free components,
        #: kept columns, their weights and free components
        self._blocks = []
        for i, j in dict.fromkeys((i, j) for i, j, _ in blocks):
            rows, row_w = self._global[i]
            cols, col_w = self._global[j]
            row_free = np.array([~lookup.get(int(r), ~free) for r in rows], dtype=bool).reshape(-1, 3)
            col_free = np.array([~lookup.get(int(c), ~free) for c in cols], dtype=bool).reshape(-1, 3)
            keep_rows = np.array([int(r) in owned for r in rows], dtype=bool) & row_free.any(axis=1)
            keep_cols = col_free.any(axis=1)
            self._blocks.append((i, j, rows[keep_rows], row_w[keep_rows], row_free[keep_rows], cols[keep_cols],
                                 col_w[keep_cols], col_free[keep_cols]))

    def coupling(self) -> dict[int, np.ndarray]:
        """Global node → the global nodes its tangent row couples to (owned free rows, as set up)."""
        columns: dict[int, list[np.ndarray]] = {}
        for _, _, rows, _, _, cols, _, _ in self._blocks:
            for r in rows.tolist():
                columns.setdefault(r, []).append(cols)
        return {r: np.unique(np.concatenate(c)) for r, c in columns.items()}

    def add_jacobian(self, A: PETSc.Mat, u: fem.Function, factor: float, follow: bool) -> None:
        """Add ``factor · T ∂²L/∂u²`` to ``A`` (rows of owned free nodes, free columns; collective).

        Dead forces (``follow`` false) have no tangent; nothing is added.
        """
        if not follow:
            return
        points = self.positions(u)
        _, blocks = self._gradient(points)
        K = {}
        for i, j, block in blocks:
            K[i, j] = K.get((i, j), 0.0) + block
        scale = factor * self.tension
        for i, j, rows, row_w, row_free, cols, col_w, col_free in self._blocks:
            if rows.size and cols.size:
                values = scale * np.einsum("a,b,ij->aibj", row_w, col_w, K[i, j])
                values *= row_free[:, :, None, None] & col_free[None, None, :, :]  # prescribed components: none
                values = values.reshape(3 * rows.size, 3 * cols.size)
                A.setValuesBlocked(rows.astype(PETSc.IntType), cols.astype(PETSc.IntType), values,
                                   addv=PETSc.InsertMode.ADD_VALUES)
