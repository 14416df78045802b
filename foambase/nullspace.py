"""The rigid-body modes of a 3D vector function space, as a PETSc near-nullspace for algebraic multigrid.

The six modes are the three translations ``e_i`` and the three rotations ``x ↦ e_k × (x − c)`` about a centre
``c``, evaluated at the owned degrees of freedom and orthonormalised (``dolfinx.la.orthonormalize``). Attached to a
stiffness matrix with ``A.setNearNullSpace(...)``, they let GAMG build coarse spaces that represent rigid motions
(``-pc_type gamg``); a direct solver ignores them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence

import numpy as np
from dolfinx import fem, la
from petsc4py import PETSc

__all__ = ["rigid_body_modes"]


def rigid_body_modes(V: fem.FunctionSpace, centre: Sequence[float] | None = None) -> PETSc.NullSpace:
    """The six orthonormalised rigid-body modes of the 3D vector space ``V``; rotations about ``centre`` (default 0)."""
    index_map, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    x = V.tabulate_dof_coordinates()[:index_map.size_local]
    if centre is not None:
        x = x - np.asarray(centre, dtype=float)
    modes = [la.create_petsc_vector(index_map, bs) for _ in range(6)]
    with contextlib.ExitStack() as stack:
        b = [stack.enter_context(m.localForm()).array.reshape(-1, bs) for m in modes]
        for i in range(3):
            b[i][:index_map.size_local, i] = 1.0
        for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):  # rotation in the (i, j) plane
            b[3 + k][:index_map.size_local, i] = -x[:, j]
            b[3 + k][:index_map.size_local, j] = x[:, i]
    la.orthonormalize(modes)
    return PETSc.NullSpace().create(vectors=modes, comm=V.mesh.comm)
