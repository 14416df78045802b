"""Simulation of soft robots made of homogenized 3D-printed foams with FEniCSx (dolfinx 0.5).

Importing the package imports no dolfinx; its modules do. Every error the public API raises derives from
:class:`FenicsfoamError` (:mod:`fenicsfoam.errors`).
"""

from foambase.errors import FenicsfoamError

__all__ = ["FenicsfoamError", "__version__"]

__version__ = "0.1.0"
