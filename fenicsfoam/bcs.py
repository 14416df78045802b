"""Prescribed rigid motions of mesh regions: clamps and servo horns as Dirichlet conditions.

A region (facets from facet tags, or any mesh entities) is carried rigidly:

    x(X) = R(θ) (X - p) + p + t,   u(X) = x(X) - X,

a rotation by the angle θ about the axis ``n`` through the point ``p`` (Rodrigues:
``R = I + sin θ K + (1 - cos θ) K²``, ``K`` the cross-product matrix of the unit axis) followed by a
translation ``t``. A clamp is a motion that no load step moves (θ = 0, t = 0). Angles are in radians.
"""

from __future__ import annotations

from collections.abc import Sequence
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

    """

    name: str
    entities: np.ndarray
    dim: int | None = None
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        rotation_matrix(self.axis, 0.0)  # validates the axis
        if np.asarray(self.point, dtype=float).shape != (3,):
            raise InputError(f"motion {self.name!r}: point must be a 3-vector, got {self.point}")

    def displacement(self, X: np.ndarray, angle: float, translation: Sequence[float]) -> np.ndarray:
        """``u(X) = R(θ)(X - p) + p + t - X`` for reference points ``X`` of shape (n, 3)."""
        p = np.asarray(self.point, dtype=float)
        R = rotation_matrix(self.axis, angle)
        return (X - p) @ R.T + p + np.asarray(translation, dtype=float) - X


class MotionBC:
    """The Dirichlet condition of a :class:`RigidMotion` on a vector space ``V``, updated by :meth:`set`.

    The prescribed values are written directly at the constrained degrees of freedom from their
    coordinates (exact for any Lagrange degree, since a rigid motion is affine).
    """

    def __init__(self, V: fem.FunctionSpace, motion: RigidMotion):
        mesh = V.mesh
        dim = mesh.topology.dim - 1 if motion.dim is None else motion.dim
        mesh.topology.create_connectivity(dim, mesh.topology.dim)
        self.motion = motion
        self.dofs = fem.locate_dofs_topological(V, dim, np.asarray(motion.entities, dtype=np.int32))
        n_owned = V.dofmap.index_map.size_local
        if mesh.comm.allreduce(int(np.sum(self.dofs < n_owned))) == 0:
            raise InputError(f"motion {motion.name!r} selects no degree of freedom (empty region?)")
        self._X = V.tabulate_dof_coordinates()[self.dofs]
        self.value = fem.Function(V, name=f"motion_{motion.name}")
        self.bc = fem.dirichletbc(self.value, self.dofs)

    def set(self, angle: float, translation: Sequence[float]) -> None:
        """Prescribe the motion by ``angle`` (rad) and ``translation`` (m)."""
        bs = self.value.function_space.dofmap.index_map_bs
        self.value.x.array.reshape(-1, bs)[self.dofs] = self.motion.displacement(self._X, angle, translation)
