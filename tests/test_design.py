"""Design optimisation (fenicsfoam.design.optimize_probe) on a small Tripod case: L-BFGS-B over a per-cell
orientation field improves its objective monotonically; SLSQP over the offset angle and densities improves the twist
within the height bound; the gradient-free search reaches the same optimum; bad requests are refused."""

import tomllib
from pathlib import Path

import numpy as np
import pytest

from fenicsfoam.design import SceneDesign, optimize_probe
from fenicsfoam.scene import parse_scene

pytestmark = pytest.mark.mpi

ROOT = Path(__file__).resolve().parents[1]
BOUNDS = {"orientation.offset_deg": (0.0, 90.0), "density:arms": (0.22, 0.34), "density:centre": (0.12, 0.22)}
SCALES = {"orientation.offset_deg": 45.0, "density:arms": 0.1, "density:centre": 0.1}


def case_a() -> SceneDesign:
    data = tomllib.loads((ROOT / "demos" / "scenes" / "tripod_case_a.toml").read_text())
    data["geometry"]["h"] = 0.01
    data["outputs"] = {"png": False, "xdmf": False}
    data["orientation"]["offset_deg"] = 30.0
    return SceneDesign(parse_scene(data))


def test_lbfgs_over_a_per_cell_field_improves_monotonically():
    design = case_a()
    result = optimize_probe(design, "center_rotation", ["orientation"], {"orientation": (-60.0, 60.0)},
                            maximize=False, bound=1e-3, method="L-BFGS-B", maxiter=3, scales={"orientation": 30.0})
    penalised = np.array([it["penalised"] for it in result.history.iterates])
    assert len(penalised) == 4 and np.all(np.diff(penalised) < 0), penalised
    assert result.objective > result.initial_objective + 1.0 and abs(result.change) <= 1e-3
    # the design is left at the best feasible point: a fresh solve gives its twist
    assert -design.solve()["center_rotation"] == pytest.approx(result.objective, rel=1e-9)


def test_slsqp_and_cobyla_agree_on_the_offset_and_densities():
    slsqp = optimize_probe(case_a(), "center_rotation", list(BOUNDS), BOUNDS, maximize=False, bound=1e-3,
                           method="SLSQP", maxiter=15, scales=SCALES)
    assert slsqp.objective > slsqp.initial_objective + 3.0
    assert abs(slsqp.change) <= 1e-3 * (1 + 1e-9) and abs(slsqp.change) > 0.99e-3  # the bound is active
    assert slsqp.parameters["density:arms"] == pytest.approx(0.22, abs=1e-6)  # at its lower bound
    cobyla = optimize_probe(case_a(), "center_rotation", list(BOUNDS), BOUNDS, maximize=False, bound=1e-3,
                            method="COBYLA", maxiter=60, scales=SCALES)
    assert cobyla.objective == pytest.approx(slsqp.objective, rel=2e-3)
    assert cobyla.parameters["orientation.offset_deg"] == pytest.approx(slsqp.parameters["orientation.offset_deg"],
                                                                        abs=0.5)
    level = slsqp.objective * (1 - 1e-3)
    assert slsqp.history.solves_to_reach(level) < cobyla.history.solves_to_reach(level)


def test_bad_requests_are_refused():
    design = case_a()
    with pytest.raises(ValueError, match="method must be"):
        optimize_probe(design, "center_rotation", ["density:arms"], BOUNDS, method="nelder-mead")
    with pytest.raises(ValueError, match="has no bounds"):
        optimize_probe(design, "center_rotation", ["E_solid"], BOUNDS)
    with pytest.raises(ValueError, match="unknown parameter 'density:legs'"):
        optimize_probe(design, "center_rotation", ["density:legs"], {"density:legs": (0, 1)})
    with pytest.raises(ValueError, match="probe 'tip_deflection' is not built"):
        optimize_probe(design, "tip_deflection", ["density:arms"], BOUNDS)
    with pytest.raises(ValueError, match="outside the bounds"):
        optimize_probe(design, "center_rotation", ["density:arms"], {"density:arms": (0.31, 0.34)})
