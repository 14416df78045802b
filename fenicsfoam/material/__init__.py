"""The material room: material kinds, their constants, the foam table and the moduli of the UFL energy.

* :mod:`~fenicsfoam.material.kinds` — the registry :data:`MATERIAL_KINDS` (isotropic, transverse_isotropic, foam):
  each kind's scene keys and checks, its resolver and its per-cell data; the schema, the builder, the per-cell
  materials, calibration, uncertainty and design loop over it;
* :mod:`~fenicsfoam.material.constants` — :class:`Isotropic` and :class:`TransverseIsotropic` constants;
* :mod:`~fenicsfoam.material.table` — :class:`FoamTable`, the one interpolation of the foam table (PCHIP with
  derivatives) for uniform regions, graded fields, uncertainty and design;
* :mod:`~fenicsfoam.material.foam` — the foam kind: :func:`foam_material` (one density and γ) and
  :class:`FoamCells` (per cell, with derivatives);
* :mod:`~fenicsfoam.material.moduli` — elastic constants → Lamé or Spencer moduli, with tangents.

:mod:`fenicsfoam.materials` re-exports the public names (the contract). Nothing here imports dolfinx.
"""

from fenicsfoam.material.constants import (
    MAX_MODULUS,
    InadmissibleMaterialError,
    Isotropic,
    Material,
    TransverseIsotropic,
)
from fenicsfoam.material.foam import FoamCells, foam_material
from fenicsfoam.material.kinds import GRADED_KEYS, MATERIAL_KINDS, Key, MaterialKind, tabulated_regions
from fenicsfoam.material.moduli import MODULI_NAMES, isotropic_moduli, spencer_moduli
from fenicsfoam.material.table import FOAM_FITS, FoamTable, foam_table

__all__ = [
    "FOAM_FITS",
    "GRADED_KEYS",
    "MATERIAL_KINDS",
    "MAX_MODULUS",
    "MODULI_NAMES",
    "FoamCells",
    "FoamTable",
    "InadmissibleMaterialError",
    "Isotropic",
    "Key",
    "Material",
    "MaterialKind",
    "TransverseIsotropic",
    "foam_material",
    "foam_table",
    "isotropic_moduli",
    "spencer_moduli",
    "tabulated_regions",
]
