"""Strong-ellipticity margin of each finite-strain model under homogeneous deformations, for a TI foam.

For uniaxial stretches λ along l and across l and simple shears γ (l ⊗ t), prints the acoustic margin
``min_n λ_min(sym Q(n))`` (kPa, :func:`fenicsfoam.stability.ellipticity_margin`) of ``corotational`` (exact
tangent), ``corotational_sofa`` (frozen-R tangent) and ``bonet_burton``, for the paper's foam
(``tripod_models.PAPER_FOAM``) or the shipped case B plate (``--foam table``). Negative: strong ellipticity lost.

Run: `python studies/ellipticity_models.py [--foam paper|table]` (≈ 1 min, serial).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from dolfinx import fem, mesh
from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tripod_models import PAPER_FOAM  # noqa: E402
from tripod_twist import scene_materials  # noqa: E402

from fenicsfoam import orientation  # noqa: E402
from fenicsfoam.constitutive import MaterialField  # noqa: E402
from fenicsfoam.materials import TransverseIsotropic  # noqa: E402
from fenicsfoam.stability import ellipticity_margin  # noqa: E402

MODELS = ("corotational", "corotational_sofa", "bonet_burton")
STRETCHES = (0.6, 0.7, 0.8, 0.9, 0.95, 0.98, 1.01, 1.02, 1.05, 1.1, 1.2)
SHEARS = (0.02, 0.05, 0.1, 0.2)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--foam", choices=["paper", "table"], default="paper")
    args = parser.parse_args()
    foam = TransverseIsotropic(**PAPER_FOAM) if args.foam == "paper" else scene_materials()["plate"]
    cube = mesh.create_unit_cube(MPI.COMM_SELF, 1, 1, 1)
    V = fem.VectorFunctionSpace(cube, ("CG", 1))
    u = fem.Function(V)
    field = MaterialField.uniform(cube, foam)
    a = orientation.uniform(cube, (1.0, 0.0, 0.0))  # l = x, t = y
    l, t = np.eye(3)[0], np.eye(3)[1]
    rows = [(f"stretch {s:g} along l", np.eye(3) + (s - 1) * np.outer(l, l)) for s in STRETCHES]
    rows += [(f"stretch {s:g} across l", np.eye(3) + (s - 1) * np.outer(t, t)) for s in STRETCHES]
    rows += [(f"shear {g:g} (l ⊗ t)", np.eye(3) + g * np.outer(l, t)) for g in SHEARS]
    print(f"{foam}\nmargin (kPa)" + "".join(f"{m:>20s}" for m in MODELS))
    for label, F in rows:
        H = F - np.eye(3)
        u.interpolate(lambda x, H=H: H @ x)
        margins = [ellipticity_margin(u, m, field, a).min_margin / 1e3 for m in MODELS]
        print(f"{label:24s}" + "".join(f"{v:20.2f}" for v in margins), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
