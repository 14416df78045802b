"""Prescribed rigid motions of mesh regions: clamps and servo horns as Dirichlet conditions.

A region (facets from facet tags, or any mesh entities) is carried rigidly:

    x(X) = R(θ) (X - p) + p + t,   u(X) = x(X) - X,

a rotation by the angle θ about the axis ``n`` through the point ``p`` (Rodrigues:
``R = I + sin θ K + (1 - cos θ) K²``, ``K`` the cross-product matrix of the unit axis) followed by a
translation ``t``. A clamp is a motion that no load step moves (θ = 0, t = 0). Angles are in radians.
A motion may prescribe only some components of ``u`` (``components``, e.g. ``(2,)``: a support that blocks
the vertical motion and lets the region slide and turn otherwise, like a load cell under a fingertip).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from dolfinx import fem

from foambase.errors import InputError

__all__ = ["MotionBC", "RigidMotion", "rotation_matrix"]


def rotation_matrix(axis: Sequence[float], angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the unit vector along ``axis``: ``R = I + sin θ K + (1 - cos θ) K²``."""
    n = np.asarray(axis, dtype=float)
    norm = np.linalg.norm(n)
    if n.shape != (3,) or not np.isfinite(norm) or norm == 0.0:
        raise InputError(f"a rotation axis must be a finite non-zero 3-vector, got {np.asarray(axis).tolist()}")
    n = n / norm
    K = np.array([[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


@dataclass(frozen=True)
class RigidMotion:
    """A mesh region moved rigidly by a rotation about ``axis`` through ``point`` and a translation.

    Parameters
    ----------
    name
        Key of the motion in :class:`fenicsfoam.solver.LoadStep` (``angles``, ``translations``).
    entities
        Local indices of the mesh entities of dimension ``dim`` whose degrees of freedom are prescribed,
        e.g. ``facet_tags.find(tag)``.
    dim
        Topological dimension of ``entities``; ``None`` means facets.
    axis, point
        The rotation axis (any non-zero 3-vector) and a point on it (m).
    components
        The components of ``u`` prescribed (0: x, 1: y, 2: z); the others are free.
    where
        Instead of ``entities``: a marker of points (3, n) → bools; every node of the space at a marked point
        is prescribed (e.g. a box, as a servo's clamp box selects the nodes inside it). All components.

    """

    name: str
    entities: np.ndarray
    dim: int | None = None
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    components: tuple[int, ...] = (0, 1, 2)
    where: Callable[[np.ndarray], np.ndarray] | None = None

    def __post_init__(self):
        rotation_matrix(self.axis, 0.0)  # validates the axis
        if np.asarray(self.point, dtype=float).shape != (3,):
            raise InputError(f"motion {self.name!r}: point must be a 3-vector, got {self.point}")
        components = tuple(self.components)
        if not components or len(set(components)) != len(components) or not set(components) <= {0, 1, 2}:
            raise InputError(f"motion {self.name!r}: components must be distinct values among 0, 1, 2, got "
                             f"{self.components!r}")
        if self.where is not None and components != (0, 1, 2):
            raise InputError(f"motion {self.name!r}: a motion selected by a marker (where) prescribes every "
                             f"component, got components {self.components!r}")

    def displacement(self, X: np.ndarray, angle: float, translation: Sequence[float]) -> np.ndarray:
        """``u(X) = R(θ)(X - p) + p + t - X`` for reference points ``X`` of shape (n, 3)."""
        p = np.asarray(self.point, dtype=float)
        R = rotation_matrix(self.axis, angle)
        return (X - p) @ R.T + p + np.asarray(translation, dtype=float) - X


class MotionBC:
    """The Dirichlet conditions of a :class:`RigidMotion` on a vector space ``V``, updated by :meth:`set`.

    The prescribed values are written directly at the constrained degrees of freedom from their
    coordinates (exact for any Lagrange degree, since a rigid motion is affine). ``bcs`` holds one condition
    for the whole vector (all components) or one per prescribed component (on the sub-spaces of ``V``).

    Attributes
    ----------
    dofs
        Local indices of the nodes of the region (blocks of ``V``), whatever the components prescribed.
    components
        The prescribed components.

    """

    def __init__(self, V: fem.FunctionSpace, motion: RigidMotion):
        mesh = V.mesh
        dim = mesh.topology.dim - 1 if motion.dim is None else motion.dim
        mesh.topology.create_connectivity(dim, mesh.topology.dim)
        self.motion = motion
        self.components = tuple(sorted(motion.components))
        entities = np.asarray(motion.entities, dtype=np.int32)
        if motion.where is not None:
            self.dofs = fem.locate_dofs_geometrical(V, motion.where)
        else:
            self.dofs = fem.locate_dofs_topological(V, dim, entities)
        n_owned = V.dofmap.index_map.size_local
        if mesh.comm.allreduce(int(np.sum(self.dofs < n_owned))) == 0:
            raise InputError(f"motion {motion.name!r} selects no degree of freedom (empty region?)")
        self._X = V.tabulate_dof_coordinates()[self.dofs]
        if self.components == (0, 1, 2):
            self.value = fem.Function(V, name=f"motion_{motion.name}")
            self.bcs = [fem.dirichletbc(self.value, self.dofs)]
            self._parts = None
            return
        self._parts = []  # (component, value on the collapsed sub-space, its dofs there, the nodes' rows in _X)
        self.bcs = []
        for c in self.components:
            Vc, _ = V.sub(c).collapse()
            dofs = fem.locate_dofs_topological((V.sub(c), Vc), dim, entities)
            value = fem.Function(Vc, name=f"motion_{motion.name}_{'xyz'[c]}")
            # the parent's unrolled index bs·node + c gives the node, hence its row in _X
            rows = np.searchsorted(self.dofs, dofs[0] // V.dofmap.index_map_bs)
            self._parts.append((c, value, dofs[1], rows))
            self.bcs.append(fem.dirichletbc(value, dofs, V.sub(c)))

    @property
    def bc(self):
        """The Dirichlet condition when every component is prescribed (the usual case)."""
        if len(self.bcs) != 1 or self._parts is not None:
            raise InputError(f"motion {self.motion.name!r} prescribes components {self.components}: use .bcs")
        return self.bcs[0]

    def constrained(self) -> np.ndarray:
        """(len(dofs), 3) booleans: which components of each node of ``dofs`` are prescribed."""
        mask = np.zeros((len(self.dofs), 3), dtype=bool)
        mask[:, list(self.components)] = True
        return mask

    def set(self, angle: float, translation: Sequence[float]) -> None:
        """Prescribe the motion by ``angle`` (rad) and ``translation`` (m)."""
        u = self.motion.displacement(self._X, angle, translation)
        if self._parts is None:
            bs = self.value.function_space.dofmap.index_map_bs
            self.value.x.array.reshape(-1, bs)[self.dofs] = u
            return
        for c, value, dofs, rows in self._parts:
            value.x.array[dofs] = u[rows, c]
