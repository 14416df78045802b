"""The paper's published Tripod numbers (Table I), which the demos and studies compare with and never fit to.

:data:`TABLE_I` holds, per shipped scene, the paper's simulated and real values at the three servo positions
(rest, middle, top): the centre's rotation about the vertical (deg) and its height (mm). :func:`table_i_changes`
gives the changes from rest, to the table's two decimals.
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["TABLE_I", "deltas", "table_i_changes"]

#: The paper's Table I, (simulated, real) at rest, middle, top: centre rotation (deg), centre height (mm).
TABLE_I = {
    "tripod_case_a": {"angle": ((-3.36, 4.47, 14.85), (0.0, 3.96, 20.49)),
                      "height": ((67.57, 81.95, 89.88), (71.7, 84.5, 92.9))},
    "tripod_case_b": {"angle": ((-9.31, 8.15, 27.21), (0.0, 5.53, 22.1)),
                      "height": ((68.67, 80.73, 87.0), (73.5, 85.8, 94.0))},
}
# The flat-plate simplifications of the same robots (``tripod_case_a_flat.toml``, ``tripod_case_b_flat.toml``).
TABLE_I.update({f"{name}_flat": values for name, values in list(TABLE_I.items())})


def deltas(values: Iterable[float]) -> tuple[float, float]:
    """(middle − rest, top − rest) of the values at (rest, middle, top)."""
    values = tuple(values)
    return values[1] - values[0], values[2] - values[0]


def table_i_changes(scene: str) -> dict[str, tuple[tuple[float, float], tuple[float, float]]]:
    """``{"height" | "angle": ((sim middle, sim top), (real middle, real top))}``: changes from rest (mm, deg)."""
    return {quantity: tuple(tuple(round(d, 2) for d in deltas(v)) for v in values)
            for quantity, values in TABLE_I[scene].items()}
