"""Parameters in one form: a parsed scene varied by vary_scene equals the scene parsed with the new value, every
variation is checked before any work, and --uncertainty refuses a scene it cannot vary before its nominal run."""

import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI
from scipy.interpolate import PchipInterpolator

from fenicsfoam.calibrate import scene_with_E_solid
from fenicsfoam.materials import foam_material
from fenicsfoam.scene import SceneError, parse_scene, vary_scene
from fenicsfoam.uncertainty import UncertaintyError, run_with_uncertainty
from foambase.errors import FenicsfoamError
from homogenization.tables import read_csv, resolve_table

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"


def scene_dict(name):
    return tomllib.loads((SCENES / f"{name}.toml").read_text())


def test_a_varied_scene_equals_the_scene_parsed_with_the_new_value():
    data = scene_dict("tripod_case_a")
    scene = parse_scene(data)
    varied = vary_scene(scene, {"E_solid": 20e6, "density:arms": 0.26})
    data["regions"]["arms"]["density"] = 0.26
    parsed = parse_scene(scene_with_E_solid(data, 20e6))
    assert varied.regions == parsed.regions
    assert varied.raw["regions"] == parsed.raw["regions"]
    assert scene.regions[0].parameters["E_solid"] == 12e6  # the scene varied is left as it was
    assert scene.raw["regions"]["arms"]["density"] == 0.30


@pytest.mark.parametrize("changes, message", [
    ({"E_solid": -1.0}, r"^regions\.arms\.E_solid: -1\.0 is not a modulus in \(0, 1e\+13\] Pa"),
    ({"density:centre": 0.5}, r"^regions\.centre\.density.*outside the tabulated range \[0\.09, 0\.35\] of the "
                              r"foam table"),
    ({"gamma:arms": 0.0}, r"^regions\.arms\.gamma: 0\.0 is not an anisotropy ratio in \(0, 1\]"),
    ({"fit": "iso"}, r"^regions\.arms\.fit: expected one of \('transverse', 'isotropic', 'paper'\)"),
    ({"table": "missing.csv"}, r"^regions\.arms\.table: no foam table file 'missing\.csv'"),
    ({"E": 1e6}, r"^parameter 'E': no region of scene 'tripod_case_a' has it"),
    ({"density:legs": 0.2}, r"^parameter 'density:legs': no region"),
])
def test_a_variation_is_checked_naming_the_key(changes, message):
    with pytest.raises(SceneError, match=message):
        vary_scene(parse_scene(scene_dict("tripod_case_a")), changes)


@pytest.mark.mpi
def test_uncertainty_refuses_a_graded_scene_before_any_work(mpi_tmp_path):
    """The per-seed tables cannot replace the table graded fields read: refused before the nominal run."""
    data = scene_dict("tripod_case_a_graded")
    with pytest.raises(UncertaintyError, match="graded foam fields .* read the default foam table only") as info:
        run_with_uncertainty(data, mpi_tmp_path / "out", comm=MPI.COMM_WORLD)
    assert isinstance(info.value, FenicsfoamError) and info.value.exit_code == 2
    assert not (mpi_tmp_path / "out").exists()


def test_foam_material_interpolates_as_scipy_pchip_between_nodes():
    """The one interpolation (FoamTable) against SciPy's PCHIP of the table, in density then log γ."""
    table = read_csv(resolve_table(None)[1])  # the default table
    gammas = np.unique(table["gamma"])

    def scipy_column(name, density, gamma):
        per_gamma = []
        for g in gammas:
            rows = np.flatnonzero(table["gamma"] == g)
            rows = rows[np.argsort(table["density"][rows])]
            per_gamma.append(PchipInterpolator(table["density"][rows], np.log(table[name][rows]))(density))
        return float(np.exp(PchipInterpolator(np.log(gammas), per_gamma)(np.log(gamma))))

    for density, gamma in ((0.2, 0.2), (0.1, 0.95), (0.33, 0.12)):
        m = foam_material(density, gamma, 1.0, 0.3)
        assert m.E_t == pytest.approx(scipy_column("ti_E_t", density, gamma), rel=1e-13)
        assert m.G_l == pytest.approx(scipy_column("ti_G_l", density, gamma), rel=1e-13)
