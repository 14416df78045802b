"""Errors of the mesh builders that more than one module raises (their family: :mod:`foambase.errors`)."""

from foambase.errors import InputError

__all__ = ["FoamParameterError"]


class FoamParameterError(InputError):
    """A foam parameter (n_cells, density, gamma, seed, strut shape, resolution) is outside its valid range."""
