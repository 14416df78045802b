"""Foam tables (homogenization.tables) and foam_material (fenicsfoam.materials)."""

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.materials import Isotropic, TransverseIsotropic, foam_material
from homogenization import tables

E_TPU = 12e6


@pytest.fixture(scope="module")
def table():
    return tables.read_csv(tables.TABLE_CSV)


def test_shipped_table_covers_the_sweep(table):
    samples = tables.read_csv(tables.SAMPLES_CSV)
    assert len(samples["density"]) == len(tables.grid())
    points = set(zip(table["density"], table["gamma"], strict=True))
    assert points == {(d, g) for d in tables.DENSITIES for g in tables.GAMMAS}
    assert np.all(table["n_seeds"] >= 3)
    # every sample reached its target density (VoronoiFoam's measured solid fraction, tolerance 0.002)
    assert np.all(np.abs(samples["measured_density"] - samples["density"]) < 0.002)


@pytest.mark.parametrize("fit", ["transverse", "isotropic"])
def test_interpolation_is_exact_at_table_nodes(table, fit):
    for d, g, i in zip(table["density"], table["gamma"], range(len(table["density"])), strict=True):
        m = foam_material(d, g, E_TPU, 0.3, fit=fit)
        if fit == "transverse":
            got = [m.E_t, m.E_l, m.nu_t, m.nu_tl, m.G_l]
            want = [E_TPU * table["ti_E_t"][i], E_TPU * table["ti_E_l"][i], table["ti_nu_t"][i],
                    table["ti_nu_tl"][i], E_TPU * table["ti_G_l"][i]]
        else:
            got, want = [m.E, m.nu], [E_TPU * table["iso_E"][i], table["iso_nu"][i]]
        np.testing.assert_allclose(got, want, rtol=1e-10)


@pytest.mark.parametrize("gamma", [1.0, 0.4, 0.1])
def test_moduli_increase_monotonically_with_density(gamma):
    densities = np.linspace(min(tables.DENSITIES), max(tables.DENSITIES), 60)
    E_t = [foam_material(d, gamma, 1.0, 0.3).E_t for d in densities]
    E_l = [foam_material(d, gamma, 1.0, 0.3).E_l for d in densities]
    assert np.all(np.diff(E_t) > 0) and np.all(np.diff(E_l) > 0)


def test_mass_density_and_linear_scaling_with_E_solid():
    a = foam_material(0.2, 0.3, 1.0, 0.3, rho_solid=1190.0)
    b = foam_material(0.2, 0.3, E_TPU, 0.3, rho_solid=1190.0)
    assert a.rho == pytest.approx(0.2 * 1190.0)
    np.testing.assert_allclose(b.voigt(), E_TPU * a.voigt(), rtol=1e-12)


def test_gamma_one_is_nearly_isotropic_and_gamma_point_one_strongly_anisotropic(table):
    iso = table["gamma"] == 1.0
    # seed-averaged moduli along x, y, z agree within a few seed scatters
    E = np.column_stack([table["E1"], table["E2"], table["E3"]])[iso]
    assert np.all(np.ptp(E, axis=1) / E.mean(axis=1) < 0.15)
    for d in tables.DENSITIES:
        m = foam_material(d, 0.1, E_TPU, 0.3)
        assert m.E_t / m.E_l > 3
        p = foam_material(d, 0.1, E_TPU, 0.3, fit="paper")
        assert isinstance(p, TransverseIsotropic) and p.E_t / p.E_l > 3
    assert isinstance(foam_material(0.18, 1.0, E_TPU, 0.3, fit="paper"), Isotropic)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"density": 0.05}, r"density = 0.05 is outside the tabulated range \[0.09, 0.34\]"),
    ({"density": 0.5}, r"density = 0.5 is outside"),
    ({"gamma": 0.05}, r"gamma = 0.05 is outside the tabulated range \[0.1, 1\]"),
    ({"nu_solid": 0.45}, r"nu_solid = 0.45: the foam table was computed for a solid with nu = 0.3"),
    ({"fit": "orthotropic"}, r"fit must be one of"),
    ({"E_solid": -1.0}, r"E_solid must be > 0"),
])
def test_foam_material_rejects_bad_input(kwargs, match):
    args = {"density": 0.18, "gamma": 0.1, "E_solid": E_TPU, "nu_solid": 0.3} | kwargs
    fit = args.pop("fit", "transverse")
    with pytest.raises(ValueError, match=match):
        foam_material(**args, fit=fit)


TINY = tables.SweepSettings(n_cells=3, resolution=16, tol=1e-5)


def _strip_time(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def test_sweep_resumes_after_interruption(tmp_path):
    samples = tables.grid((0.25, 0.3), (1.0,), (1,))
    comm = MPI.COMM_SELF
    assert tables.run_sweep(samples, TINY, tmp_path / "a", comm, progress=False, stop_after=1) is None
    assert len(list((tmp_path / "a").glob("*.json"))) == 1
    mtime = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "a").glob("*.json")}
    resumed = tables.run_sweep(samples, TINY, tmp_path / "a", comm, progress=False)
    # the sample done before the interruption was read back, not recomputed
    assert all((tmp_path / "a" / name).stat().st_mtime_ns == t for name, t in mtime.items())
    straight = tables.run_sweep(samples, TINY, tmp_path / "b", comm, progress=False)
    assert _strip_time(resumed) == _strip_time(straight)
    assert [(r["density"], r["seed"]) for r in resumed] == [(0.25, 1), (0.3, 1)]


def test_sweep_reports_unreachable_density(tmp_path):
    with pytest.raises(RuntimeError, match=r"density=0.9.*FoamParameterError"):
        tables.run_sweep(tables.grid((0.9,), (1.0,), (0,)), TINY, tmp_path, MPI.COMM_SELF, progress=False)
    assert not list(tmp_path.glob("*.json"))


@pytest.mark.mpi
def test_sweep_distributed_over_ranks_matches_serial(tmp_path):
    comm = MPI.COMM_WORLD
    cache = comm.bcast(tmp_path if comm.rank == 0 else None)
    samples = tables.grid((0.3,), (1.0,), (0, 1))
    rows = tables.run_sweep(samples, TINY, cache / "mpi", comm, progress=False)
    if comm.rank == 0:
        serial = tables.run_sweep(samples, TINY, cache / "serial", MPI.COMM_SELF, progress=False)
        assert _strip_time(rows) == _strip_time(serial)


def _rows_at(table, keep):
    names = list(table)
    idx = [i for i in range(len(table["density"])) if keep(table["density"][i], table["gamma"][i])]
    return [{n: float(table[n][i]) for n in names} for i in idx]


def test_a_table_of_one_density_is_exact_at_its_nodes_and_named_tables_resolve(table, tmp_path):
    """A selectable table computed for one density only (two γ): foam_material reads it by path and returns
    the CSV row's constants; outside its one density it refuses, naming the table."""
    path = tables.to_csv(_rows_at(table, lambda d, g: d == 0.18 and g in (0.1, 1.0)), tmp_path / "t.csv")
    i = int(np.flatnonzero((table["density"] == 0.18) & (table["gamma"] == 0.1))[0])
    m = foam_material(0.18, 0.1, E_TPU, 0.3, table=path)
    np.testing.assert_allclose([m.E_t, m.E_l, m.G_l, m.nu_t], [E_TPU * table["ti_E_t"][i], E_TPU * table["ti_E_l"][i],
                                                               E_TPU * table["ti_G_l"][i], table["ti_nu_t"][i]],
                               rtol=1e-12)
    with pytest.raises(ValueError, match=r"density = 0.2 is outside the tabulated range \[0.18, 0.18\] .*t\.csv"):
        foam_material(0.2, 0.1, E_TPU, 0.3, table=path)
    assert foam_material(0.18, 0.1, E_TPU, 0.3, table="cube") == foam_material(0.18, 0.1, E_TPU, 0.3)
    assert "cube" in tables.shipped_tables()
    with pytest.raises(ValueError, match=r"table = 'no_such' is not a shipped foam table"):
        foam_material(0.18, 0.1, E_TPU, 0.3, table="no_such")


def test_a_table_that_is_not_a_full_grid_is_refused(table, tmp_path):
    path = tables.to_csv(_rows_at(table, lambda d, g: (d, g) in ((0.18, 0.1), (0.18, 1.0), (0.22, 1.0))),
                         tmp_path / "ragged.csv")
    with pytest.raises(ValueError, match=r"is not a full \(density, gamma\) grid"):
        foam_material(0.18, 1.0, E_TPU, 0.3, table=path)


def test_sweep_settings_name_their_table():
    assert tables.SweepSettings().name == "cube"
    assert tables.SweepSettings(box="equiaxed").name == "equiaxed"
    assert tables.SweepSettings(box="equiaxed", distance="polyhedral").name == "equiaxed_polyhedral"
    assert tables.table_paths("cube")["table"] == tables.TABLE_CSV
    assert tables.table_paths("equiaxed", "/d")["samples"].as_posix() == "/d/foam_table_equiaxed_samples.csv"
    with pytest.raises(ValueError, match=r"box must be 'cube' or 'equiaxed', got 'long'"):
        tables.SweepSettings(box="long")


def test_shipped_equiaxed_table_is_resolved_and_read_by_name():
    """The `equiaxed` table: 27 cells in the box (γ, 1, 1), ≥ 3 seeds per node, every strut at least 3.85 voxels
    across, every sample at its density; foam_material(table="equiaxed") returns its rows."""
    assert "equiaxed" in tables.shipped_tables()
    paths = tables.table_paths("equiaxed")
    samples, table = tables.read_csv(paths["samples"]), tables.read_csv(paths["table"])
    assert set(samples["box"]) == {"equiaxed"} and set(samples["n_cells"]) == {27}
    assert np.all(2 * samples["radius"] * samples["resolution"] >= 3.85)
    assert np.all(np.abs(samples["measured_density"] - samples["density"]) < 0.002)
    assert np.all(table["n_seeds"] >= 3)
    for i in range(len(table["density"])):
        m = foam_material(table["density"][i], table["gamma"][i], E_TPU, 0.3, table="equiaxed")
        np.testing.assert_allclose([m.E_t, m.G_l], [E_TPU * table["ti_E_t"][i], E_TPU * table["ti_G_l"][i]],
                                   rtol=1e-10)
