"""Elastic materials of the macro model: the public names of :mod:`fenicsfoam.material`.

:class:`Isotropic` and :class:`TransverseIsotropic` constants (:mod:`fenicsfoam.material.constants`) and
:func:`foam_material`, the constants of a foam from the shipped table (:mod:`fenicsfoam.material.foam`). The foam
kind's resolver reads :func:`foam_material` from this module when it runs.
"""

from fenicsfoam.material.constants import InadmissibleMaterialError, Isotropic, Material, TransverseIsotropic
from fenicsfoam.material.foam import foam_material
from fenicsfoam.material.table import FOAM_FITS

__all__ = ["FOAM_FITS", "InadmissibleMaterialError", "Isotropic", "Material", "TransverseIsotropic", "foam_material"]
