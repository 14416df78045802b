"""The rotated … hex8 bracket of a foam sample (``SweepSettings(discretization="bracket")``, ``bracket_samples``)."""

import numpy as np
import pytest
from mpi4py import MPI

from foambase.errors import InputError
from homogenization import tables

SAMPLES = [tables.Sample(0.3, 1.0, 1)]


def _settings(kind: str) -> tables.SweepSettings:
    return tables.SweepSettings(n_cells=3, resolution=12, tol=1e-7, discretization=kind, pore_modulus=0.01)


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    return {kind: tables.run_sweep(SAMPLES, _settings(kind), cache, MPI.COMM_SELF, progress=False)
            for kind in ("rotated", "hex8", "bracket")}


def test_a_bracket_sweep_is_the_mean_of_the_two_discretizations_and_brackets_them(sweeps):
    combined = tables.bracket_samples(sweeps["rotated"], sweeps["hex8"])
    for lo, hi, mid, both in zip(sweeps["rotated"], sweeps["hex8"], sweeps["bracket"], combined, strict=True):
        assert mid["discretization"] == "bracket" and tables.settings_from_row(mid) == _settings("bracket")
        for name in tables.C_ENTRIES:  # one sweep computing both = two sweeps combined
            assert mid[name] == pytest.approx(0.5 * (lo[name] + hi[name]), rel=1e-12, abs=1e-15)
            assert both[name] == pytest.approx(mid[name], rel=1e-12, abs=1e-15)
        for q in tables.BRACKETED:
            assert min(lo[q], hi[q]) <= mid[q] <= max(lo[q], hi[q])  # the midpoint's moduli lie in the bracket
            assert mid[f"bracket_{q}"] == pytest.approx(abs(hi[q] - lo[q]) / (hi[q] + lo[q]), rel=1e-12)
            assert both[f"bracket_{q}"] == pytest.approx(mid[f"bracket_{q}"], rel=1e-12)
        assert hi["E1"] > lo["E1"]  # full integration is the stiff side on the same voxels
    table = tables.aggregate(sweeps["bracket"])
    assert table[0]["bracket_E2"] == sweeps["bracket"][0]["bracket_E2"]


def test_bracket_refuses_a_missing_sample_and_other_settings_naming_them(sweeps):
    with pytest.raises(InputError, match="density 0.3, gamma 1.0, seed 1 has no hex8 row"):
        tables.bracket_samples(sweeps["rotated"], [])
    other = [dict(r, tol=1e-6) for r in sweeps["hex8"]]
    with pytest.raises(InputError, match="density 0.3, gamma 1.0, seed 1 was computed at other settings"):
        tables.bracket_samples(sweeps["rotated"], other)
    with pytest.raises(InputError, match="lower rows must be rotated"):
        tables.bracket_samples(sweeps["hex8"], sweeps["hex8"])


def test_bracket_tables_writes_the_bracket_table_from_two_table_directories(sweeps, tmp_path):
    for kind in ("rotated", "hex8"):
        tables.write_tables(sweeps[kind], tmp_path / kind, {"kind": kind}, _settings(kind).name)
    paths = tables.bracket_tables(tmp_path / "rotated", tmp_path / "hex8", tmp_path / "out")
    assert paths["table"].name == "foam_table_cube_bracket_pores0p01.csv"
    rows = tables.read_samples(paths["samples"])
    np.testing.assert_allclose([r["E1"] for r in rows], [r["E1"] for r in sweeps["bracket"]], rtol=1e-12)


def test_the_hex8_estimate_keeps_the_hex8_sample_with_the_bracket_widths_and_reads_back_as_hex8(sweeps, tmp_path):
    """``estimate="hex8"``: each row is the hex8 sample (settings and stiffness) plus the midpoint row's bracket
    widths, with the midpoint rows' columns (so it merges with them); its provenance reads back as hex8."""
    rows = tables.bracket_samples(sweeps["rotated"], sweeps["hex8"], estimate="hex8")
    mid = tables.bracket_samples(sweeps["rotated"], sweeps["hex8"])
    for row, hi, m in zip(rows, sweeps["hex8"], mid, strict=True):
        assert tables.settings_from_row(row) == _settings("hex8") and list(row) == list(m)
        assert all(row[name] == hi[name] for name in tables.C_ENTRIES + ("E1", "G12", "ti_E_t"))
        assert all(row[f"bracket_{q}"] == m[f"bracket_{q}"] for q in tables.BRACKETED)
    with pytest.raises(InputError, match="estimate must be one of .*'upper'"):
        tables.bracket_samples(sweeps["rotated"], sweeps["hex8"], estimate="upper")
    for kind in ("rotated", "hex8"):
        per_node = {"density=0.3,gamma=1": tables.settings_dict(_settings(kind))}
        tables.write_tables(sweeps[kind], tmp_path / kind, {"settings_per_node": per_node}, _settings(kind).name)
    paths = tables.bracket_tables(tmp_path / "rotated", tmp_path / "hex8", tmp_path / "out", estimate="hex8")
    name = paths["table"].name.removeprefix("foam_table_").removesuffix(".csv")
    assert name == "cube_hex8_pores0p01"
    assert tables.recorded_settings(name, tmp_path / "out", nodes=True) == {(0.3, 1.0): _settings("hex8")}
