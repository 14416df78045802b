"""A calibration file (``calibration.json``, written by ``fenicsfoam calibrate``) as a scene reads it.

The scene key ``E_solid = {calibration = "calibration.json"}`` takes a foam region's modulus from such a file;
:mod:`fenicsfoam.calibrate` writes them and re-exports both names.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from foambase.errors import InputError

__all__ = ["CalibrationError", "read_calibration"]


class CalibrationError(InputError):
    """A calibration cannot be done: bad input, or a target no ``E_solid`` reaches; the message says which value.

    An :class:`~foambase.errors.InputError` (a ``ValueError``): the command line exits with status 2.
    """


def read_calibration(path: str | os.PathLike) -> float:
    """``E_solid`` (Pa) of a ``calibration.json``; :class:`CalibrationError` names the file and what is wrong."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise CalibrationError(f"cannot read calibration file {str(path)!r}: {exc.strerror}") from exc
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"calibration file {str(path)!r} is not valid JSON: {exc}") from exc
    E = data.get("E_solid") if isinstance(data, dict) else None
    if isinstance(E, bool) or not isinstance(E, int | float) or not (math.isfinite(E) and E > 0):
        raise CalibrationError(f"calibration file {str(path)!r}: 'E_solid' must be a positive modulus in Pa, "
                               f"got {E!r}")
    return float(E)
