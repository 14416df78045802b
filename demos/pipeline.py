"""The main job of `make demo`: the largest part of the fenicsfoam pipeline that exists.

Stage 1 (foundation): the tensor layer. A transversely isotropic material with its l axis along the
foam's soft x axis, its engineering constants, and the TI/isotropic projections that later stages
apply to homogenized stiffnesses.
"""

import argparse
import json
from pathlib import Path

import numpy as np

from homogenization.tensors import (
    closest_isotropic,
    closest_transverse_isotropic,
    engineering_constants,
    rotate_voigt,
    rotation_from_axis,
    transverse_isotropic_voigt,
)


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    ti = dict(E_t=0.02, E_l=0.004, nu_t=0.3, nu_tl=0.1, G_l=0.003)
    C = rotate_voigt(transverse_isotropic_voigt(**ti), rotation_from_axis([1.0, 0.0, 0.0]))
    c = engineering_constants(C)
    fit_ti = closest_transverse_isotropic(C, axis=0)
    fit_iso = closest_isotropic(C)
    print("TI material, l axis along x (normalised by E_solid = 1):")
    print("  " + "  ".join(f"{k}={c[k]:.4g}" for k in ("E1", "E2", "E3", "G23", "G13", "G12", "nu23", "nu21")))
    print(f"  TI fit along x: error {fit_ti.error:.2e};  isotropic fit: E={fit_iso.E:.4g} error {fit_iso.error:.2e}")
    assert fit_ti.error < 1e-12 and np.isclose(c["E1"], ti["E_l"])
    (out / "pipeline.json").write_text(json.dumps({"engineering_constants": c, "ti_fit_error": fit_ti.error}, indent=2))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out"))
    parser.add_argument("--ci", action="store_true", help="fast size for the test suite (no effect at this stage)")
    main(parser.parse_args().out)
