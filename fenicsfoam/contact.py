"""Frictionless contact of a facet group of the body with a rigid obstacle (plane, sphere, box), by Nitsche's method.

The obstacle is described by its signed distance ``d(x)`` (positive outside the obstacle) and its outward unit
normal ``n(x)`` (the direction in which ``d`` grows). For a point ``X`` of the contact group, ``x = X + u`` its
position, the gap is ``g(u) = d(x − s m)``: an obstacle moved by ``s m`` (``m`` the obstacle's displacement at
factor 1, ``s`` its factor, set by the steps like a load factor). Frictionless contact asks, on the group,

    g ≥ 0,   p ≥ 0,   p g = 0,   P N = p n,

``p`` the contact pressure (per unit reference area), ``P N`` the traction on the body. The three conditions on
``g`` and ``p`` are equivalent to ``p = [p − γ g]₊`` for any ``γ > 0``. Nitsche's method (Chouly & Hild, 2013,
the variant θ = 0 of their family) replaces ``p`` by the body's own normal traction ``t_n(u) = (P(u) N) · n``:

    R(u) ∋ − ∫_Γc [t_n(u) − γ g(u)]₊ n · v dA,     γ = θ_N M / h,

``M = λ + 2μ`` the P-wave modulus of the cell under the facet (``λ + 2 max(μ_T, μ_L)`` for a transversely
isotropic region), ``h`` the cell's diameter and ``θ_N`` a dimensionless parameter (default 10). The exact solution
satisfies this equation for every ``γ`` (the method is *consistent*): unlike a penalty, the discrete gap tends to
zero with the mesh for a fixed ``θ_N``, and the contact force does not depend on ``θ_N`` to the discretisation
error. The term is a UFL form, so the solver's Jacobian (``ufl.derivative``) includes its exact tangent and Newton
converges quadratically once the contact set settles; the positive part's kink makes the tangent switch where a
point enters or leaves contact, which the solver's load-step cut-back handles like any other nonlinearity.

Why Nitsche: it needs no extra unknowns (no multiplier field, no outer augmented-Lagrangian loop), works for any
obstacle given by a distance function (a plane, a sphere, a box, moving), and under ``mpirun`` it is a facet
integral like the follower pressure. PETSc's SNES VI solvers would need bounds per degree of freedom, which only an
axis-aligned plane gives.

*Traction*: ``P`` is the model's first Piola–Kirchhoff stress on the facet (``linear``: ``σ(ε)``, ``svk``:
``F S``). The corotational model's rotation field lives at the cells' quadrature points, which a facet integral
cannot read; for it the traction in the Nitsche term is the St-Venant–Kirchhoff stress of the same elastic
constants, which agrees with the corotational stress to first order in the strain. The difference changes the
gap only by (that difference)/γ, second order in the strain.

The contact force on the body is ``F = ∫_Γc [t_n − γ g]₊ n dA`` (N), the contact area the reference area where the
bracket is positive (evaluated at the facet quadrature points), and the penetration the largest ``−g`` over the
nodes of the group (:meth:`Contact.penetration`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import ufl
from dolfinx import cpp, fem
from mpi4py import MPI

from fenicsfoam.loads import Load, surface_group
from foambase.errors import InputError

__all__ = ["NITSCHE", "OBSTACLES", "Contact", "Obstacle"]

#: Default dimensionless Nitsche parameter θ_N (γ = θ_N M / h).
NITSCHE = 10.0
#: Obstacle shapes and their parameters.
OBSTACLES = {"plane": ("point", "normal"), "sphere": ("center", "radius"), "box": ("min", "max")}


@dataclass(frozen=True)
class Obstacle:
    """A rigid obstacle: ``shape`` in :data:`OBSTACLES` and its parameters; ``motion`` its displacement at factor 1.

    * plane: ``point`` on it and ``normal`` (pointing out of the obstacle, towards the body); the obstacle is the
      half-space behind the plane.
    * sphere: ``center`` and ``radius``.
    * box: ``min`` and ``max`` corners (axis-aligned), the body outside it.
    """

    shape: str
    point: Sequence[float] | None = None
    normal: Sequence[float] | None = None
    center: Sequence[float] | None = None
    radius: float | None = None
    min: Sequence[float] | None = None
    max: Sequence[float] | None = None
    motion: Sequence[float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.shape not in OBSTACLES:
            raise InputError(f"obstacle: unknown shape {self.shape!r}; valid: {', '.join(OBSTACLES)}")
        for key in OBSTACLES[self.shape]:
            if getattr(self, key) is None:
                raise InputError(f"obstacle {self.shape}: give {' and '.join(OBSTACLES[self.shape])} (missing {key})")
        if self.shape == "plane" and not np.linalg.norm(self.normal) > 0:
            raise InputError(f"obstacle plane: the normal must be a non-zero vector, got {list(self.normal)}")
        if self.shape == "sphere" and not self.radius > 0:
            raise InputError(f"obstacle sphere: the radius must be > 0 (m), got {self.radius!r}")
        if self.shape == "box" and not np.all(np.asarray(self.max) > np.asarray(self.min)):
            raise InputError(f"obstacle box: max {list(self.max)} must exceed min {list(self.min)} in every component")

    def moved(self, shift) -> Obstacle:
        """The obstacle translated by ``shift`` (m), at rest (its ``motion`` zero)."""
        from dataclasses import replace
        d = np.asarray(shift, dtype=float)
        moved = {k: tuple((np.asarray(getattr(self, k), float) + d).tolist()) for k in ("point", "center", "min", "max")
                 if getattr(self, k) is not None}
        return replace(self, motion=(0.0, 0.0, 0.0), **moved)

    # ----------------------------------------------------------------------------------------------
    def distance(self, x):
        """UFL signed distance ``d(x)`` and outward normal ``n(x)`` of the obstacle at rest, for a UFL point ``x``."""
        if self.shape == "plane":
            n = np.asarray(self.normal, float) / np.linalg.norm(self.normal)
            normal = ufl.as_vector(n.tolist())
            return ufl.dot(x - ufl.as_vector(list(map(float, self.point))), normal), normal
        if self.shape == "sphere":
            r = x - ufl.as_vector(list(map(float, self.center)))
            length = ufl.sqrt(ufl.dot(r, r) + (1e-12 * float(self.radius)) ** 2)  # finite at the centre
            return length - float(self.radius), r / length
        lo, hi = np.asarray(self.min, float), np.asarray(self.max, float)
        c, half = ufl.as_vector(((lo + hi) / 2).tolist()), ((hi - lo) / 2).tolist()
        r = x - c
        sign = [ufl.sign(r[i]) for i in range(3)]
        q = [abs(r[i]) - half[i] for i in range(3)]
        outside = [ufl.max_value(q[i], 0.0) for i in range(3)]
        out_length = ufl.sqrt(sum(o * o for o in outside) + 1e-300)
        q_max = ufl.max_value(ufl.max_value(q[0], q[1]), q[2])
        inside_normal = ufl.as_vector([ufl.conditional(ufl.And(ufl.ge(q[i], q[(i + 1) % 3]),
                                                               ufl.ge(q[i], q[(i + 2) % 3])), sign[i], 0.0)
                                       for i in range(3)])
        out = ufl.gt(q_max, 0.0)
        distance = ufl.conditional(out, out_length, q_max)
        normal = ufl.conditional(out, ufl.as_vector([sign[i] * outside[i] / out_length for i in range(3)]),
                                 inside_normal)
        return distance, normal

    def distance_numpy(self, x: np.ndarray) -> np.ndarray:
        """Signed distance of the points ``x`` (n, 3) to the obstacle at rest."""
        if self.shape == "plane":
            n = np.asarray(self.normal, float) / np.linalg.norm(self.normal)
            return (x - np.asarray(self.point, float)) @ n
        if self.shape == "sphere":
            return np.linalg.norm(x - np.asarray(self.center, float), axis=1) - float(self.radius)
        lo, hi = np.asarray(self.min, float), np.asarray(self.max, float)
        q = np.abs(x - (lo + hi) / 2) - (hi - lo) / 2
        return np.where(q.max(axis=1) > 0, np.linalg.norm(np.maximum(q, 0.0), axis=1), q.max(axis=1))


def _modulus(material) -> ufl.core.expr.Expr:
    """The P-wave modulus ``λ + 2μ`` of the DG0 material (``λ + 2 max(μ_T, μ_L)`` if transversely isotropic)."""
    m = material.moduli
    if material.isotropic:
        return m["lmbda"] + 2.0 * m["mu"]
    return m["lmbda"] + 2.0 * ufl.max_value(m["mu_T"], m["mu_L"])


def cell_diameter(mesh) -> fem.Function:
    """DG0 cell diameter (largest vertex distance) of every local cell, owned and ghost."""
    tdim = mesh.topology.dim
    imap = mesh.topology.index_map(tdim)
    cells = np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)
    h = fem.Function(fem.FunctionSpace(mesh, ("DG", 0)), name="h")
    dofs = h.function_space.dofmap.list.array.reshape(-1)[cells]
    h.x.array[dofs] = cpp.mesh.h(getattr(mesh, "_mesh", mesh), tdim, cells)  # the C++ mesh
    return h


class Contact(Load):
    """Frictionless contact of the facet group ``tags`` with a rigid :class:`Obstacle` (module docstring).

    The load factor moves the obstacle by ``factor · obstacle.motion``; at factor 0 it is where it was declared.
    The solver calls :meth:`setup` and :meth:`bind_stress` before it asks for the :meth:`residual`.
    """

    def __init__(self, name: str, mesh, facet_tags, tags: int | Sequence[int], obstacle: Obstacle,
                 nitsche: float = NITSCHE):
        if not (np.isfinite(nitsche) and nitsche > 0):
            raise InputError(f"contact {name!r}: the Nitsche parameter must be a finite number > 0, got {nitsche!r}")
        motion = np.asarray(obstacle.motion, dtype=float)
        if motion.shape != (3,) or not np.all(np.isfinite(motion)):
            raise InputError(f"contact {name!r}: the obstacle's motion must be a finite 3-vector, got {motion!r}")
        self.name, self.mesh, self.facet_tags, self.obstacle, self.nitsche = name, mesh, facet_tags, obstacle, nitsche
        self.tags = (tags,) if isinstance(tags, int | np.integer) else tuple(int(t) for t in tags)
        _, self.area = surface_group(name, mesh, facet_tags, self.tags)
        self._model = None

    def setup(self, V) -> None:
        """Note the displacement's degree (the quadrature of the contact terms is ``2 degree + 2``)."""
        self._degree = V.ufl_element().degree()

    def bind_stress(self, model, material, orientation) -> None:
        """Take the model's stress for the traction ``t_n`` and the modulus for ``γ`` (called by the solver)."""
        from fenicsfoam.constitutive import MODELS
        self._model = MODELS["svk"] if model.needs_rotation else model
        self._material, self._orientation = material, orientation
        self._h = cell_diameter(self.mesh)
        # One quadrature rule for the residual, the force and the area, fine enough to resolve a narrow contact
        # strip: the force is then exactly what the residual applies.
        self.ds = ufl.Measure("ds", domain=self.mesh, subdomain_data=self.facet_tags, subdomain_id=self.tags,
                              metadata={"quadrature_degree": 2 * self._degree + 2})
        self._gamma = self.nitsche * _modulus(material) / self._h

    def _bracket(self, u, factor):
        """UFL ``[t_n − γ g]₊`` (the contact pressure per unit reference area) and the obstacle normal."""
        if self._model is None:
            raise InputError(f"contact {self.name!r}: bind_stress must be called before the residual")
        X = ufl.SpatialCoordinate(self.mesh)
        shift = factor * ufl.as_vector(np.asarray(self.obstacle.motion, float).tolist())
        gap, normal = self.obstacle.distance(X + u - shift)
        P = self._model.first_piola_kirchhoff(u, self._material, self._orientation, None)
        traction = ufl.dot(ufl.dot(P, ufl.FacetNormal(self.mesh)), normal)
        bracket = traction - self._gamma * gap
        # ≥, not >: a point exactly touching at rest (g = t_n = 0) carries the contact tangent, so a body that
        # rests on the obstacle and nothing else is not singular at the first Newton step.
        return ufl.conditional(ufl.ge(bracket, 0.0), bracket, 0.0), normal, gap

    def residual(self, u, v, factor, finite_strain):
        """``− ∫_Γc [t_n − γ g]₊ n · v dA``."""
        self._u, self._factor = u, factor
        pressure, normal, gap = self._bracket(u, factor)
        self._pressure, self._normal, self._gap = pressure, normal, gap
        self._force_forms = [fem.form(pressure * normal[i] * self.ds) for i in range(3)]
        self._area_form = fem.form(ufl.conditional(ufl.gt(pressure, 0.0), 1.0, 0.0) * self.ds)
        return -pressure * ufl.inner(normal, v) * self.ds

    # ----------------------------------------------------------------------------------------------
    def _sum(self, form) -> float:
        return self.mesh.comm.allreduce(fem.assemble_scalar(form), op=MPI.SUM)

    def force(self) -> np.ndarray:
        """The total force (N) the obstacle exerts on the body at the current state (collective)."""
        return np.array([self._sum(f) for f in self._force_forms])

    def force_gradient(self, component: int) -> np.ndarray:
        """Derivative of the force's ``component`` with respect to the owned dofs of ``u`` (collective)."""
        from dolfinx.fem.petsc import assemble_vector
        from petsc4py import PETSc
        forms = self.__dict__.setdefault("_force_gradient_forms", {})
        if component not in forms:
            V = self._u.function_space
            functional = self._pressure * self._normal[component] * self.ds
            forms[component] = fem.form(ufl.derivative(functional, self._u, ufl.TestFunction(V)))
        b = assemble_vector(forms[component])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        gradient = b.array.copy()
        b.destroy()
        return gradient

    def contact_area(self) -> float:
        """The reference area (m²) of the group where the contact pressure is positive (collective)."""
        return float(self._sum(self._area_form))

    def penetration(self) -> float:
        """The largest penetration ``max(−g, 0)`` (m) over the nodes of the group at the current state (collective)."""
        V = self._u.function_space
        fdim = self.mesh.topology.dim - 1
        facets = np.concatenate([self.facet_tags.find(t) for t in self.tags])
        nodes = fem.locate_dofs_topological(V, fdim, facets)  # block (node) indices, owned and ghost
        x = V.tabulate_dof_coordinates()[nodes] + self._u.x.array.reshape(-1, 3)[nodes]
        shift = float(self._factor.value) * np.asarray(self.obstacle.motion, float)
        local = float(np.max(-self.obstacle.distance_numpy(x - shift), initial=0.0))
        return self.mesh.comm.allreduce(local, op=MPI.MAX)
