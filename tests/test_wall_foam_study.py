"""The wall-foam resolution study's bracket comparison (studies/wall_foam.py: against_finest_bracket)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
import wall_foam  # noqa: E402


def _levels(values: dict[str, float]) -> list[dict]:
    """Seed-mean rows of one γ = 1 family, every modulus ``values[resolution]`` at its level."""
    return [{"gamma": 1.0, "resolution": res, "h_x": 1.0 / int(res), "aspect": 1.0,
             **{name: q for name in wall_foam.MODULI}} for res, q in values.items()]


def _family():
    """Rotated 0.8, 0.9, 0.95 and hex8 1.2, 1.1, 1.05 on grids 32, 48, 64; the midpoints 1.0 at every level."""
    return (_levels({"32": 1.0, "48": 1.0, "64": 1.0}), _levels({"32": 0.8, "48": 0.9, "64": 0.95}),
            _levels({"32": 1.2, "48": 1.1, "64": 1.05}))


def test_each_level_estimate_is_bounded_by_the_finest_bracket():
    out = wall_foam.against_finest_bracket(*_family())
    assert len(out) == 3 * 2 * len(wall_foam.MODULI)
    coarse_hex8 = next(r for r in out if (r["resolution"], r["name"], r["estimate"]) == ("32", "E1", "hex8"))
    assert coarse_hex8["value"] == 1.2 and coarse_hex8["offset"] == pytest.approx(0.2)
    assert coarse_hex8["error_low"] == pytest.approx(1.2 / 1.05 - 1)
    assert coarse_hex8["error_high"] == pytest.approx(1.2 / 0.95 - 1)
    # any converged value inside the finest bracket puts the estimate's true error inside its interval
    for converged in np.linspace(0.95, 1.05, 11):
        assert coarse_hex8["error_low"] - 1e-12 <= 1.2 / converged - 1 <= coarse_hex8["error_high"] + 1e-12
    mid = next(r for r in out if (r["resolution"], r["name"], r["estimate"]) == ("64", "G12", "midpoint"))
    assert mid["offset"] == pytest.approx(0.0) and mid["error_low"] == pytest.approx(1 / 1.05 - 1)


def test_a_family_of_one_level_is_not_compared():
    one = [rows[:1] for rows in _family()]
    assert wall_foam.against_finest_bracket(*one) == []
