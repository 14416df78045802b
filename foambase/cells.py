"""The cells a rank owns on a dolfinx mesh: their number and their tags (no dolfinx import here)."""

from __future__ import annotations

import numpy as np

from foambase.errors import InputError

__all__ = ["num_owned_cells", "owned_cell_tags"]


def num_owned_cells(mesh) -> int:
    """Number of cells this rank owns (ghosts excluded): the local indices ``0 … n-1``."""
    return mesh.topology.index_map(mesh.topology.dim).size_local


def owned_cell_tags(mesh, cell_tags, untagged: int) -> np.ndarray:
    """The tag of every cell this rank owns, ``untagged`` where ``cell_tags`` has none."""
    tdim = mesh.topology.dim
    if cell_tags.dim != tdim:
        raise InputError(f"cell_tags must tag cells (dimension {tdim}), got entities of dimension {cell_tags.dim}")
    n = num_owned_cells(mesh)
    tags = np.full(n, untagged, dtype=np.int64)
    owned = cell_tags.indices < n
    tags[cell_tags.indices[owned]] = cell_tags.values[owned]
    return tags
