"""Richardson extrapolation and GCI (homogenization.convergence) on synthetic q0 + c h^p."""

import numpy as np
import pytest

from foambase.errors import InputError
from homogenization.convergence import fit_power_law, gci, observed_order, richardson, richardson_two_level

TIGHT = 1e-9


def model(h, q0=0.0273, c=-0.41, p=1.0):
    return q0 + c * np.asarray(h, dtype=float) ** p


@pytest.mark.parametrize("p", [1.0, 2.0, 0.7, 1.5, 3.2])
@pytest.mark.parametrize("h", [[1 / 20, 1 / 40, 1 / 80],                    # ratio 2
                               [1 / 34, 1 / 43, 1 / 54, 1 / 68],             # ratios 1.26, 1.26, 1.26
                               [0.3, 0.21, 0.1, 0.083]])                    # non-uniform: 1.43, 2.1, 1.2
def test_three_level_recovers_q0_and_order(h, p):
    q0, c = 0.0273, -0.41
    est = richardson(h, model(h, q0, c, p))
    assert est.asymptotic and est.reason == ""
    assert est.order == pytest.approx(p, rel=TIGHT)
    assert est.value == pytest.approx(q0, rel=TIGHT)
    assert est.coefficient == pytest.approx(c, rel=1e-7)
    assert est.safety_factor == 1.25
    # bias of the levels used and, from the model, at a spacing not computed
    assert est.bias() == pytest.approx(c * np.asarray(h[-3:]) ** p / q0, rel=1e-7)
    assert est.bias(0.05) == pytest.approx(c * 0.05**p / q0, rel=1e-7)


def test_only_the_three_finest_levels_are_used():
    h = np.array([0.5, 0.2, 0.1, 0.05, 0.025])
    q = model(h, p=2.0)
    q[0] += 1.0                       # a pre-asymptotic coarse level must not change the estimate
    est = richardson(h, q)
    assert est.h == tuple(h[-3:]) and est.value == pytest.approx(0.0273, rel=TIGHT)


def test_increasing_quantity_and_positive_coefficient():
    h = [0.1, 0.05, 0.025]
    est = richardson(h, model(h, q0=-3.0, c=+7.0, p=1.3))
    assert est.value == pytest.approx(-3.0, rel=TIGHT) and est.order == pytest.approx(1.3, rel=TIGHT)


def test_two_level_formula():
    # exact for the model at the given order, elementwise on arrays
    hc, hf = 1 / 48, 1 / 64
    for p in (1.0, 2.0, 0.6):
        assert richardson_two_level(model(hc, p=p), model(hf, p=p), hc / hf, p) == pytest.approx(0.0273, rel=TIGHT)
    coarse, fine = np.array([1.0, 2.0]), np.array([1.5, 2.5])
    np.testing.assert_allclose(richardson_two_level(coarse, fine, 2.0), [2.0, 3.0])       # p = 1: f + (f − c)
    np.testing.assert_allclose(richardson_two_level(coarse, fine, 2.0, 2.0), fine + 0.5 / 3)


def test_gci_is_the_safety_factor_times_the_fine_error_of_the_model():
    h = [0.1, 0.05, 0.025]
    q = model(h, q0=1.0, c=0.8, p=2.0)
    est = richardson(h, q)
    true_error = abs(q[-1] - 1.0) / abs(q[-1])
    assert est.gci == pytest.approx(1.25 * true_error, rel=1e-9)
    assert gci(q[1], q[2], 2.0, 2.0, safety_factor=3.0) == pytest.approx(3.0 * true_error, rel=1e-9)
    lo, hi = est.interval
    assert lo < 1.0 < hi and hi - lo == pytest.approx(2 * 1.25 * abs(q[-1] - 1.0), rel=1e-9)


def test_not_monotone_is_flagged_and_falls_back_to_the_assumed_order():
    h = [0.1, 0.05, 0.025]
    q = [1.0, 1.2, 1.1]                        # increments +0.2 then −0.1: oscillating
    est = richardson(h, q)
    assert not est.asymptotic and "not monotone" in est.reason
    assert est.order == 1.0 and est.safety_factor == 3.0
    assert est.value == pytest.approx(1.1 + (1.1 - 1.2) / (2 - 1))
    est2 = richardson(h, q, fallback_order=2.0)
    assert est2.order == 2.0 and est2.value == pytest.approx(1.1 - 0.1 / 3)


def test_increments_that_do_not_shrink_are_not_asymptotic():
    h = [1 / 100, 1 / 120, 1 / 150]
    q = [0.0220, 0.0226, 0.0235]               # +0.0006 then +0.0009 for smaller steps: p < 0.25
    p, reason = observed_order(h, q)
    assert p is None and "not yet asymptotic" in reason
    est = richardson(h, q)
    assert not est.asymptotic and est.order == 1.0
    assert est.value == pytest.approx(0.0235 + 0.0009 / (150 / 120 - 1))


def test_too_fast_and_degenerate_increments_are_flagged():
    h = [0.1, 0.05, 0.025]
    assert "faster than order" in observed_order(h, model(h, p=6.0))[1]
    assert "equal" in observed_order(h, [2.0, 2.0, 2.0])[1]
    est = richardson(h, [2.0, 2.0, 2.0])
    assert est.value == 2.0 and not est.asymptotic
    assert "zero" in observed_order(h, [1.0, 2.0, 2.0])[1]


@pytest.mark.parametrize("p", [1.0, 2.0, 0.6, 2.7])
def test_least_squares_fit_recovers_q0_and_order(p):
    h = np.array([1 / 34, 1 / 43, 1 / 54, 1 / 68, 1 / 85, 1 / 107])
    fit = fit_power_law(h, model(h, p=p))
    assert fit.asymptotic and fit.order_fitted
    assert fit.order == pytest.approx(p, rel=1e-6) and fit.value == pytest.approx(0.0273, rel=1e-7)
    assert fit.coefficient == pytest.approx(-0.41, rel=1e-5) and fit.residual_std < 1e-12


def test_least_squares_fit_reduces_to_the_richardson_formulas():
    h = [0.3, 0.21, 0.1]
    q = model(h, p=1.4)
    q[0] += 0.003                                      # any three values with an order in the bounds
    three = richardson(h, q)
    fit = fit_power_law(h, q)
    assert three.asymptotic and fit.order == pytest.approx(three.order, rel=1e-6)
    assert fit.value == pytest.approx(three.value, rel=1e-7) and np.isnan(fit.residual_std)
    two = fit_power_law(h[1:], q[1:], order=2.0)
    assert two.value == pytest.approx(richardson_two_level(q[1], q[2], 2.1, 2.0), rel=1e-12)


def test_least_squares_fit_of_scattered_levels():
    """Levels scattered about the model: the fixed-order fit's residual std and standard error are those of the
    linear regression (cross-check with numpy.polyfit), and the known q0 lies within a few standard errors."""
    h = 1 / np.array([34, 43, 54, 68, 85, 107], dtype=float)
    noise = np.array([+1, -1, +1, -1, +1, -1]) * 2e-4
    q = model(h, p=1.0) + noise
    fit = fit_power_law(h, q, order=1.0)
    coef, cov = np.polyfit(h, q, 1, cov="unscaled")
    residual = q - np.polyval(coef, h)
    sigma = np.sqrt(residual @ residual / 4)
    assert fit.value == pytest.approx(coef[1], rel=1e-10) and fit.residual_std == pytest.approx(sigma, rel=1e-8)
    assert fit.value_stderr == pytest.approx(sigma * np.sqrt(cov[1, 1]), rel=1e-8)
    assert abs(fit.value - 0.0273) < 3 * fit.value_stderr
    np.testing.assert_allclose(fit.bias(), (q - fit.value) / fit.value)


def test_least_squares_fit_flags_an_order_on_the_bound():
    h = [0.1, 0.05, 0.025, 0.0125]
    fit = fit_power_law(h, [1.0, 1.2, 1.1, 1.15])       # alternating increments: no order fits
    assert not fit.asymptotic and "bound" in fit.reason
    with pytest.raises(InputError, match=r"at least 3 levels, got 2"):
        fit_power_law([0.1, 0.05], [1.0, 2.0])
    with pytest.raises(InputError, match=r"order must be > 0 and finite, got nan"):
        fit_power_law([0.1, 0.05], [1.0, 2.0], order=float("nan"))


@pytest.mark.parametrize("h, q, match", [
    ([0.1, 0.05], [1.0, 2.0], r"at least 3 levels, got 2"),
    ([0.1, 0.05, 0.05], [1.0, 2.0, 3.0], r"decrease strictly.*h\[1\] = 0.05 then h\[2\] = 0.05"),
    ([0.05, 0.1, 0.025], [1.0, 2.0, 3.0], r"decrease strictly.*h\[0\] = 0.05 then h\[1\] = 0.1"),
    ([0.1, 0.05, 0.025], [1.0, float("nan"), 3.0], r"every q must be finite, got nan"),
    ([0.1, float("nan"), 0.025], [1.0, 2.0, 3.0], r"every h must be positive and finite, got nan"),
    ([0.1, 0.05, -0.025], [1.0, 2.0, 3.0], r"every h must be positive and finite, got -0.025"),
    ([0.1, 0.05, 0.025], [1.0, 2.0], r"equal length"),
])
def test_bad_input_names_the_value(h, q, match):
    with pytest.raises(InputError, match=match):
        richardson(h, q)


def test_bad_two_level_and_gci_input():
    with pytest.raises(InputError, match=r"ratio .* > 1 .* got 1.0"):
        richardson_two_level(1.0, 2.0, 1.0)
    with pytest.raises(InputError, match=r"order must be > 0 .* got -1"):
        richardson_two_level(1.0, 2.0, 2.0, -1)
    with pytest.raises(InputError, match=r"q must be finite"):
        richardson_two_level(np.array([1.0, np.nan]), np.array([1.0, 2.0]), 2.0)
    with pytest.raises(InputError, match=r"safety factor must be >= 1, got 0.5"):
        gci(1.0, 1.1, 2.0, 1.0, safety_factor=0.5)
    with pytest.raises(InputError, match=r"fallback_order must be > 0 .* got 0"):
        richardson([0.1, 0.05, 0.025], [1.0, 2.0, 3.5], fallback_order=0)
    with pytest.raises(InputError, match=r"h must be positive and finite, got \[0.0\]"):
        richardson([0.1, 0.05, 0.025], model([0.1, 0.05, 0.025])).bias([0.0])


def test_resolution_study_ci(tmp_path):
    """``foam_rve_study.py resolution --ci``: three strut resolutions of one small foam, extrapolated per constant.

    Each level reaches its voxels across the strut by the smallest admissible grid (γ = 0.5: N even), every
    constant gets a finite estimate, the per-level bias is the level's distance to it, and every level's voxel
    image holds about the foam's solid fraction.
    """
    import csv
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
    import foam_rve_study

    argv = ["resolution", "--ci", "--out", str(tmp_path), "--bias-at", "3", "--voxel-fraction"]
    assert foam_rve_study.main(argv) == 0
    with open(tmp_path / "resolution_extrapolation.csv") as f:
        estimates = {r["name"]: r for r in csv.DictReader(f)}
    with open(tmp_path / "resolution_summary.csv") as f:
        levels = list(csv.DictReader(f))
    assert set(estimates) == set(foam_rve_study.RESOLVED)
    for name, est in estimates.items():
        assert np.isfinite(float(est["extrapolated"])) and np.isfinite(float(est["bias_at_3"]))
        mine = sorted((r for r in levels if r["name"] == name), key=lambda r: int(r["resolution"]))
        across = [float(r["across"]) for r in mine]
        assert [int(r["resolution"]) for r in mine] == sorted({int(r["resolution"]) for r in mine})
        for target, a, r in zip((2.5, 3.0, 3.5), across, mine):
            assert target <= a < target * (1 + 2 / int(r["resolution"])) + 1e-9   # the smallest even N reaching it
            assert abs(float(r["voxel_fraction"]) - 0.3) < 0.03                 # the voxel image of a 30 % foam
            assert float(r["bias"]) == pytest.approx(
                (float(r["value"]) - float(est["extrapolated"])) / float(est["extrapolated"]), rel=1e-9)
