"""The wall-foam resolution study's bracket comparison (studies/wall_foam.py: against_finest_bracket)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
import wall_foam  # noqa: E402


def _family(values: dict[str, float], width: float) -> tuple[list[dict], list[dict]]:
    """Sample rows (one seed) and summary rows of one γ = 1 family with the midpoint ``values[resolution]`` of
    every modulus and the relative bracket half width ``width`` at every level."""
    rows, summary = [], []
    for res, q in values.items():
        moduli = {name: q for name in wall_foam.MODULI}
        rows.append({"gamma": 1.0, "resolution": res, **moduli, **{f"bracket_{n}": width for n in wall_foam.MODULI}})
        summary.append({"gamma": 1.0, "resolution": res, "h_x": 1.0 / int(res), "aspect": 1.0, **moduli})
    return rows, summary


def test_each_level_midpoint_is_bounded_by_the_finest_bracket():
    rows, summary = _family({"32": 0.95, "48": 0.98, "64": 1.0}, width=0.1)
    out = wall_foam.against_finest_bracket(rows, summary)
    assert len(out) == 3 * len(wall_foam.MODULI)
    coarse = next(r for r in out if r["resolution"] == "32" and r["name"] == "E1")
    assert coarse["error_low"] == pytest.approx(0.95 / 1.1 - 1)
    assert coarse["error_high"] == pytest.approx(0.95 / 0.9 - 1)
    assert coarse["offset_from_finest"] == pytest.approx(-0.05)
    # any converged value inside the finest bracket puts the level's true error inside the interval
    for converged in np.linspace(0.9, 1.1, 11):
        assert coarse["error_low"] - 1e-12 <= 0.95 / converged - 1 <= coarse["error_high"] + 1e-12
    finest = next(r for r in out if r["resolution"] == "64" and r["name"] == "G12")
    assert finest["error_low"] == pytest.approx(1 / 1.1 - 1) and finest["offset_from_finest"] == 0.0


def test_a_family_of_one_level_is_not_compared():
    rows, summary = _family({"32": 1.0}, width=0.05)
    assert wall_foam.against_finest_bracket(rows, summary) == []
