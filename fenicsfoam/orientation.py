"""Cell-wise (DG0) fields on a dolfinx mesh, and the orientation field of the material *l* axis.

The orientation field is a DG0 vector function whose value in each cell is the unit *l* axis (local axis 3
of :class:`fenicsfoam.materials.TransverseIsotropic`) in global coordinates, in the reference configuration.
Three constructors cover the scene files: :func:`uniform`, :func:`per_tag` and :func:`from_callable`
(e.g. the in-plane spiral :func:`spiral_directions`, evaluated at cell midpoints). Each normalises the
directions and refuses zero or non-finite vectors.

Values are computed on the cells this rank owns and copied to ghost cells by ``scatter_forward``, so the
field is the same whatever the partition. :func:`cell_function` and :func:`owned_cell_tags` are the
building blocks shared with :class:`fenicsfoam.constitutive.MaterialField`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from dolfinx import fem
from dolfinx.mesh import Mesh, MeshTagsMetaClass, compute_midpoints

from foambase.cells import num_owned_cells
from foambase.cells import owned_cell_tags as _owned_cell_tags
from foambase.errors import InputError

__all__ = [
    "HANDEDNESS",
    "OrientationError",
    "cell_function",
    "cell_values",
    "from_callable",
    "owned_cell_tags",
    "per_tag",
    "set_cell_values",
    "spiral_directions",
    "uniform",
]

logger = logging.getLogger(__name__)

#: Tag reported by :func:`owned_cell_tags` for a cell that ``cell_tags`` does not mark.
UNTAGGED = np.iinfo(np.int32).min
#: Sign ``h`` of the tangential part of a :func:`spiral_directions` fibre, by handedness.
HANDEDNESS = {"counterclockwise": 1.0, "clockwise": -1.0}


class OrientationError(InputError):
    """An orientation field cannot be built: zero or non-finite directions, or cells without a direction."""


def cell_function(mesh: Mesh, values: np.ndarray, name: str | None = None) -> fem.Function:
    """A DG0 function with the given values on the cells this rank owns; ghost cells by ``scatter_forward``.

    Parameters
    ----------
    mesh
        The mesh.
    values
        Shape ``(n_owned,)`` for a scalar field or ``(n_owned, k)`` for a k-vector field, row *i* being the
        value in owned cell *i* (local index).
    name
        Name of the function (shown in output files).

    """
    values = np.asarray(values, dtype=float)
    n = num_owned_cells(mesh)
    if values.shape[0] != n or values.ndim not in (1, 2):
        raise InputError(f"expected values of shape ({n},) or ({n}, k) for the {n} owned cells, got {values.shape}")
    if values.ndim == 1:
        V = fem.FunctionSpace(mesh, ("DG", 0))
    else:
        V = fem.VectorFunctionSpace(mesh, ("DG", 0), dim=values.shape[1])
    f = fem.Function(V, name=name)
    set_cell_values(f, values)
    return f


def cell_values(f: fem.Function) -> np.ndarray:
    """The values of a DG0 function on the owned cells: ``(n_owned,)`` or ``(n_owned, k)`` (inverse of the above)."""
    V = f.function_space
    n = num_owned_cells(V.mesh)
    bs = V.dofmap.index_map_bs
    dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[:n, 0]
    values = f.x.array.reshape(-1, bs)[dofs]
    return values[:, 0].copy() if bs == 1 else values.copy()


def set_cell_values(f: fem.Function, values: np.ndarray) -> None:
    """Write ``values`` (one row per owned cell) into the DG0 function ``f``; ghost cells by ``scatter_forward``."""
    V = f.function_space
    n = num_owned_cells(V.mesh)
    bs = V.dofmap.index_map_bs
    values = np.asarray(values, dtype=float)
    if values.size != n * bs:
        raise InputError(f"expected {n} x {bs} values for the {n} owned cells, got shape {values.shape}")
    dofs = V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)[:n, 0]
    f.x.array.reshape(-1, bs)[dofs] = values.reshape(n, bs)
    f.x.scatter_forward()


def owned_cell_tags(mesh: Mesh, cell_tags: MeshTagsMetaClass) -> np.ndarray:
    """The tag of every cell this rank owns, :data:`UNTAGGED` where ``cell_tags`` has none."""
    return _owned_cell_tags(mesh, cell_tags, UNTAGGED)


def _normalised(comm, directions: np.ndarray, what: str) -> np.ndarray:
    """Rows of ``directions`` divided by their norms; :class:`OrientationError` on zero or non-finite rows.

    The check is collective: every rank raises, with the number of bad cells over all ranks.
    """
    norms = np.linalg.norm(directions, axis=1)
    bad = ~np.isfinite(norms) | (norms == 0.0)
    n_bad = comm.allreduce(int(bad.sum()))
    if n_bad:
        examples = [row for rows in comm.allgather(directions[bad][:1].tolist()) for row in rows]
        raise OrientationError(f"{what}: {n_bad} cell(s) have a zero or non-finite direction (e.g. {examples[0]}); "
                               "directions must be finite and non-zero")
    return directions / norms[:, None]


def _as_direction(d: Sequence[float], what: str) -> np.ndarray:
    d = np.asarray(d, dtype=float)
    if d.shape != (3,):
        raise OrientationError(f"{what}: a direction is a 3-vector, got {d.tolist()}")
    return d


def uniform(mesh: Mesh, direction: Sequence[float]) -> fem.Function:
    """The same unit *l* axis ``direction / |direction|`` in every cell."""
    d = _as_direction(direction, "uniform")
    norm = np.linalg.norm(d)
    if not (np.isfinite(norm) and norm > 0.0):
        raise OrientationError(f"uniform: the direction must be finite and non-zero, got {d.tolist()}")
    return cell_function(mesh, np.tile(d / norm, (num_owned_cells(mesh), 1)), name="orientation")


def per_tag(mesh: Mesh, cell_tags: MeshTagsMetaClass, directions: Mapping[int, Sequence[float]],
            default: Sequence[float] | None = None) -> fem.Function:
    """The *l* axis per cell tag: ``directions[tag]`` normalised, in every cell with that tag.

    Parameters
    ----------
    mesh, cell_tags
        The mesh and its cell tags (e.g. from ``dolfinx.io.gmshio.model_to_mesh``).
    directions
        ``{tag: direction}``; each direction a finite non-zero 3-vector.
    default
        Direction for cells whose tag is not in ``directions`` (e.g. isotropic regions, where the axis has no
        effect). Without it, such cells are an error.

    """
    tags = owned_cell_tags(mesh, cell_tags)
    table = {int(t): _as_direction(d, f"per_tag, tag {t}") for t, d in directions.items()}
    values = np.empty((tags.size, 3))
    known = np.isin(tags, list(table))
    for t, d in table.items():
        values[tags == t] = d
    n_unknown = mesh.comm.allreduce(int((~known).sum()))
    if n_unknown:
        if default is None:
            local = {("untagged" if t == UNTAGGED else int(t)) for t in np.unique(tags[~known])}
            missing = sorted(set().union(*mesh.comm.allgather(local)), key=str)
            raise OrientationError(f"per_tag: {n_unknown} cell(s) have tags {missing} without a direction "
                                   f"(directions given for tags {sorted(table)}); add them or pass default=")
        values[~known] = _as_direction(default, "per_tag, default")
    return cell_function(mesh, _normalised(mesh.comm, values, "per_tag"), name="orientation")


def from_callable(mesh: Mesh, f: Callable[[np.ndarray], np.ndarray]) -> fem.Function:
    """The *l* axis from a function of position, evaluated at cell midpoints and normalised.

    Parameters
    ----------
    mesh
        The mesh.
    f
        Maps the midpoints of the owned cells, shape ``(n, 3)``, to directions, shape ``(n, 3)``; e.g. a
        spiral ``d(x) = (cos(φ) cos(θ(x)), cos(φ) sin(θ(x)), sin(φ))``.

    """
    tdim = mesh.topology.dim
    midpoints = compute_midpoints(mesh, tdim, np.arange(num_owned_cells(mesh), dtype=np.int32))
    directions = np.asarray(f(midpoints))
    if np.iscomplexobj(directions):
        raise OrientationError(f"from_callable: f returned complex directions (e.g. {directions.ravel()[:1]}); "
                               "it must return real numbers")
    directions = np.asarray(directions, dtype=float)
    if directions.shape != midpoints.shape:
        raise OrientationError(f"from_callable: f must map points of shape {midpoints.shape} to directions of "
                               f"the same shape, got {directions.shape}")
    return cell_function(mesh, _normalised(mesh.comm, directions, "from_callable"), name="orientation")


def spiral_directions(points: np.ndarray, pitch_deg: float, handedness: str,
                      center: Sequence[float] = (0.0, 0.0)) -> np.ndarray:
    """In-plane spiral fibre directions at ``points`` (n, 3): ``d = sin p e_r + h cos p e_θ``.

    ``e_r`` is the horizontal unit vector from the vertical axis through ``center`` to the point,
    ``e_θ = e_z × e_r``, ``p`` the pitch angle (0: circles, 90°: radial), and ``h = +1`` for
    ``"counterclockwise"`` (the fibre traced outwards turns counter-clockwise seen from +z), ``-1`` for
    ``"clockwise"`` (:data:`HANDEDNESS`). A mirror image (y → −y) of one handedness is the other. Points on the
    axis get a zero vector (refused by the orientation builders). For :func:`from_callable`::

        from_callable(mesh, lambda x: spiral_directions(x, 45.0, "clockwise"))
    """
    h = HANDEDNESS[handedness]
    p = math.radians(pitch_deg)
    r = np.asarray(points, dtype=float)[:, :2] - np.asarray(center, dtype=float)
    norm = np.linalg.norm(r, axis=1, keepdims=True)
    e_r = np.divide(r, norm, out=np.zeros_like(r), where=norm > 0)
    e_theta = np.column_stack([-e_r[:, 1], e_r[:, 0]])
    d = math.sin(p) * e_r + h * math.cos(p) * e_theta
    return np.column_stack([d, np.zeros(len(d))])
