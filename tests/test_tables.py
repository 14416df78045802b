"""Foam tables (homogenization.tables) and foam_material (fenicsfoam.materials)."""

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.materials import Isotropic, TransverseIsotropic, foam_material
from homogenization import tables

ONE_RANK_SKIP = pytest.mark.skipif(
    MPI.COMM_WORLD.size < 2,
    reason="compares a COMM_WORLD run with a COMM_SELF run: on one rank they are the same computation "
           "(runs under mpirun -n 2)")

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


# --------------------------------------------------------------------------------------------------
# foam_material against a synthetic table with closed-form columns
# --------------------------------------------------------------------------------------------------
SYN_DENSITIES, SYN_GAMMAS = (0.1, 0.2, 0.3), (1.0, 0.5, 0.2)


def synthetic_ti(d: float, g: float) -> dict[str, float]:
    """TI constants (over E_s) whose interpolants are exact: moduli exp-linear in density and power laws in γ,
    Poisson's ratios linear in density and in log γ (PCHIP reproduces linear data exactly, and foam_material
    interpolates log(moduli) over density then over log γ). Soft along l for γ < 1, as the foams."""
    lg = np.log(g)
    return {"E_t": 0.05 * np.exp(6 * d) * g**-0.2, "E_l": 0.05 * np.exp(6 * d) * g,
            "G_l": 0.02 * np.exp(5 * d) * g**0.5, "nu_t": 0.3 + 0.1 * d + 0.05 * lg, "nu_tl": 0.2 + 0.2 * d - 0.02 * lg}


def synthetic_iso(d: float, g: float) -> dict[str, float]:
    return {"E": 0.04 * np.exp(6 * d) * g**0.3, "nu": 0.25 + 0.1 * d - 0.01 * np.log(g)}


def engineering_of_ti_along_x(c: dict[str, float]) -> dict[str, float]:
    """Engineering constants of a TI solid with its l axis along x, by the definitions in docs/conventions.md
    (ν_ij: contraction in j under extension in i; ν_lt = ν_tl E_l / E_t), written out here independently of
    homogenization.tensors."""
    nu_lt = c["nu_tl"] * c["E_l"] / c["E_t"]
    return {"E1": c["E_l"], "E2": c["E_t"], "E3": c["E_t"], "G12": c["G_l"], "G13": c["G_l"],
            "G23": c["E_t"] / (2 * (1 + c["nu_t"])), "nu21": c["nu_tl"], "nu31": c["nu_tl"], "nu12": nu_lt,
            "nu13": nu_lt, "nu23": c["nu_t"], "nu32": c["nu_t"]}


@pytest.fixture(scope="module")
def synthetic_table(tmp_path_factory):
    rows = []
    for d in SYN_DENSITIES:
        for g in SYN_GAMMAS:
            ti, iso = synthetic_ti(d, g), synthetic_iso(d, g)
            rows.append({"density": d, "gamma": g, "n_seeds": 3, **engineering_of_ti_along_x(ti),
                         **{f"ti_{k}": v for k, v in ti.items()}, "ti_error": 0.0,
                         "iso_E": iso["E"], "iso_nu": iso["nu"], "iso_error": 0.0})
    return tables.to_csv(rows, tmp_path_factory.mktemp("table") / "synthetic.csv")


# on the nodes, between them, and at the ends of both ranges
SYN_POINTS = [(0.2, 0.5), (0.13, 0.7), (0.27, 0.31), (0.1, 0.2), (0.3, 1.0), (0.16, 0.9)]


@pytest.mark.parametrize(("d", "g"), SYN_POINTS)
def test_interpolation_is_exact_for_data_it_reproduces(synthetic_table, d, g):
    """The three fits against the closed forms the synthetic table was written from, on and off its nodes."""
    ti, iso = synthetic_ti(d, g), synthetic_iso(d, g)
    m = foam_material(d, g, E_TPU, 0.3, fit="transverse", table=synthetic_table)
    np.testing.assert_allclose([m.E_t, m.E_l, m.nu_t, m.nu_tl, m.G_l],
                               [E_TPU * ti["E_t"], E_TPU * ti["E_l"], ti["nu_t"], ti["nu_tl"], E_TPU * ti["G_l"]],
                               rtol=1e-12)
    m = foam_material(d, g, E_TPU, 0.3, fit="isotropic", table=synthetic_table)
    np.testing.assert_allclose([m.E, m.nu], [E_TPU * iso["E"], iso["nu"]], rtol=1e-12)


@pytest.mark.parametrize(("d", "g"), [p for p in SYN_POINTS if p[1] != 1.0])
def test_paper_fit_of_an_exactly_ti_table_returns_its_constants(synthetic_table, d, g):
    """The paper's averaging (E_l = E1, E_t = mean(E2, E3), ν_t = mean(ν23, ν32), ν_tl = mean(ν21, ν31),
    G_l = mean(G12, G13)) of the engineering constants of a TI solid with l along x gives back its constants."""
    ti = synthetic_ti(d, g)
    m = foam_material(d, g, E_TPU, 0.3, fit="paper", table=synthetic_table)
    assert isinstance(m, TransverseIsotropic)
    np.testing.assert_allclose([m.E_t, m.E_l, m.nu_t, m.nu_tl, m.G_l],
                               [E_TPU * ti["E_t"], E_TPU * ti["E_l"], ti["nu_t"], ti["nu_tl"], E_TPU * ti["G_l"]],
                               rtol=1e-12)


def test_paper_fit_of_the_shipped_table_averages_its_engineering_columns(table):
    """At the table's nodes (γ < 1) the "paper" fit is the documented average of the engineering columns."""
    for i in np.flatnonzero(table["gamma"] < 1):
        d, g = table["density"][i], table["gamma"][i]
        m = foam_material(d, g, E_TPU, 0.3, fit="paper", table="cube")
        col = {k: table[k][i] for k in tables.ENGINEERING}
        np.testing.assert_allclose(
            [m.E_l, m.E_t, m.nu_t, m.nu_tl, m.G_l],
            [E_TPU * col["E1"], E_TPU * (col["E2"] + col["E3"]) / 2, (col["nu23"] + col["nu32"]) / 2,
             (col["nu21"] + col["nu31"]) / 2, E_TPU * (col["G12"] + col["G13"]) / 2], rtol=1e-10)


# --------------------------------------------------------------------------------------------------
# The table pipeline: one sample, the shipped samples, the aggregation
# --------------------------------------------------------------------------------------------------
def test_sample_row_fits_ti_about_the_foams_x_axis():
    """A small γ = 0.1 sample: its ti_* columns are the closest TI stiffness to its own C with l along x (the
    foam's distinct axis, docs/conventions.md), and that axis is the soft one (E_l < E_t, E1 < E2, E3)."""
    from homogenization.tensors import closest_transverse_isotropic

    row = tables.homogenize_sample(tables.Sample(0.3, 0.1, 0), tables.SweepSettings(8, 16, 1e-4), threads=1)
    C = tables.row_stiffness(row)
    fit = closest_transverse_isotropic(C, axis=(1.0, 0.0, 0.0))
    np.testing.assert_allclose([row[f"ti_{k}"] for k in ("E_t", "E_l", "nu_t", "nu_tl", "G_l", "error")],
                               [fit.E_t, fit.E_l, fit.nu_t, fit.nu_tl, fit.G_l, fit.error], rtol=1e-12)
    S = np.linalg.inv(C)
    np.testing.assert_allclose([row["E1"], row["E2"], row["E3"]], 1 / np.diag(S)[:3], rtol=1e-12)
    assert row["ti_E_l"] < row["ti_E_t"] / 3
    assert row["E1"] < min(row["E2"], row["E3"]) / 3


@pytest.mark.parametrize("name", ["cube", tables.DEFAULT_TABLE])
def test_shipped_samples_are_the_x_axis_fit_of_their_stiffness(name):
    """Every sample's ti_* columns are the closest TI stiffness about x of its C, its E1 and ν21 those of its
    compliance (the `cube` table and the default, whose rows are the rotated … hex8 midpoint)."""
    samples = tables.read_csv(tables.table_paths(name)["samples"])
    from homogenization.tensors import closest_transverse_isotropic

    for i in range(len(samples["density"])):
        C = tables.row_stiffness({k: samples[k][i] for k in tables.C_ENTRIES})
        fit = closest_transverse_isotropic(C, axis=0)
        np.testing.assert_allclose([samples[f"ti_{k}"][i] for k in ("E_t", "E_l", "nu_t", "nu_tl", "G_l")],
                                   [fit.E_t, fit.E_l, fit.nu_t, fit.nu_tl, fit.G_l], rtol=1e-9)
        S = np.linalg.inv(C)
        np.testing.assert_allclose([samples["E1"][i], samples["nu21"][i]], [1 / S[0, 0], -S[1, 0] / S[1, 1]],
                                   rtol=1e-9)


def test_aggregate_is_the_mean_and_sample_std_over_seeds():
    rows = []
    values = {(0.1, 1.0): [1.0, 2.0, 6.0], (0.2, 0.5): [4.0, 8.0]}
    for (d, g), vs in values.items():
        for seed, v in enumerate(vs):
            rows.append({"density": d, "gamma": g, "seed": seed, **{k: v * (j + 1) for j, k in
                                                                    enumerate(tables.AGGREGATED)}})
    table = {(t["density"], t["gamma"]): t for t in tables.aggregate(rows[::-1])}
    assert set(table) == set(values)
    for key, vs in values.items():
        t = table[key]
        assert t["n_seeds"] == len(vs)
        for j, name in enumerate(tables.AGGREGATED):
            scaled = [v * (j + 1) for v in vs]
            mean = sum(scaled) / len(scaled)
            std = (sum((v - mean) ** 2 for v in scaled) / (len(scaled) - 1)) ** 0.5
            assert t[name] == pytest.approx(mean, rel=1e-14) and t[f"{name}_std"] == pytest.approx(std, rel=1e-14)


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
    ({"density": 0.05}, r"density = 0.05 is outside the tabulated range \[0.09, 0.35\] of the foam table "
                        r"'paper_foam'"),
    ({"density": 0.5}, r"density = 0.5 is outside"),
    ({"gamma": 0.05}, r"gamma = 0.05 is outside the tabulated range \[0.1, 1\]"),
    ({"nu_solid": 0.45}, r"nu_solid = 0.45: the foam table was computed for a solid with nu = 0.3"),
    ({"fit": "orthotropic"}, r"fit must be one of"),
    ({"E_solid": -1.0}, r"E_solid must be a modulus in \(0, 1e\+13\] Pa"),
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


@ONE_RANK_SKIP
@pytest.mark.mpi
def test_sweep_distributed_over_ranks_matches_serial(tmp_path):
    comm = MPI.COMM_WORLD
    cache = comm.bcast(tmp_path if comm.rank == 0 else None)
    samples = tables.grid((0.3,), (1.0,), (0, 1))
    rows = tables.run_sweep(samples, TINY, cache / "mpi", comm, progress=False)
    if comm.rank == 0:
        serial = tables.run_sweep(samples, TINY, cache / "serial", MPI.COMM_SELF, progress=False)
        assert _strip_time(rows) == _strip_time(serial)


@ONE_RANK_SKIP
@pytest.mark.mpi
def test_sweep_with_each_sample_distributed_matches_serial(tmp_path):
    """distribute="fft": every sample computed by all ranks together (slabs of the FFT grid) gives the serial
    row to the solver's round-off, and one cache entry per sample; a bad mode is refused."""
    comm = MPI.COMM_WORLD
    cache = comm.bcast(tmp_path if comm.rank == 0 else None)
    samples = tables.grid((0.3,), (1.0,), (0, 1))
    rows = tables.run_sweep(samples, TINY, cache / "fft", comm, progress=False, distribute="fft")
    if comm.rank == 0:
        assert len(list((cache / "fft").glob("*.json"))) == 2
        serial = tables.run_sweep(samples, TINY, cache / "serial", MPI.COMM_SELF, progress=False)
        for got, want in zip(rows, serial, strict=True):
            np.testing.assert_allclose([got[c] for c in tables.C_ENTRIES], [want[c] for c in tables.C_ENTRIES],
                                       rtol=0, atol=1e-9 * want["C11"])
    with pytest.raises(ValueError, match=r"distribute must be 'samples' or 'fft', got 'ranks'"):
        tables.run_sweep(samples, TINY, cache / "fft", comm, progress=False, distribute="ranks")


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
    assert foam_material(0.18, 0.1, E_TPU, 0.3, table=tables.DEFAULT_TABLE) == foam_material(0.18, 0.1, E_TPU, 0.3)
    assert "cube" in tables.shipped_tables()
    with pytest.raises(ValueError, match=r"table = 'no_such' is not a shipped foam table"):
        foam_material(0.18, 0.1, E_TPU, 0.3, table="no_such")


def test_a_table_that_is_not_a_full_grid_is_refused(table, tmp_path):
    path = tables.to_csv(_rows_at(table, lambda d, g: (d, g) in ((0.18, 0.1), (0.18, 1.0), (0.22, 1.0))),
                         tmp_path / "ragged.csv")
    with pytest.raises(ValueError, match=r"is not a full \(density, gamma\) grid"):
        foam_material(0.18, 1.0, E_TPU, 0.3, table=path)


def test_sweep_settings_name_their_table():
    """The rotated scheme's tables keep the shipped names; the default (hex8) ones carry their voxels' name."""
    rotated = {"discretization": "rotated"}
    assert tables.SweepSettings(**rotated).name == "cube"
    assert tables.SweepSettings(box="equiaxed", **rotated).name == "equiaxed"
    assert tables.SweepSettings(box="equiaxed", distance="polyhedral", **rotated).name == "equiaxed_polyhedral"
    assert tables.SweepSettings().discretization == tables.DEFAULT_DISCRETIZATION == "hex8"
    assert tables.SweepSettings(box="equiaxed", distance="polyhedral").name == "equiaxed_polyhedral_hex8"
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


def test_shipped_wall_table_is_resolved_and_read_by_name():
    """The `equiaxed_polyhedral` table (the wall foam the beam scenes read): 8 cells in the box (γ, 1, 1), 3 seeds
    per node, every wall at least 3 voxels across along x (the x spacing resolves the γ = 0.1 walls, sheets
    nearly normal to x), every sample at its density; foam_material(table=...) returns its rows exactly."""
    name = "equiaxed_polyhedral"
    assert name in tables.shipped_tables()
    paths = tables.table_paths(name)
    samples, table = tables.read_csv(paths["samples"]), tables.read_csv(paths["table"])
    assert set(samples["box"]) == {"equiaxed"} and set(samples["distance"]) == {"polyhedral"}
    assert set(samples["n_cells"]) == {8}
    for gamma, radius, grid in zip(samples["gamma"], samples["radius"], samples["resolution"], strict=True):
        shape = [int(float(n)) for n in str(grid).split("x")]
        nx = shape[0] if len(shape) == 3 else round(float(shape[0]) * gamma)  # N along the longest edge, 1
        assert 2 * radius * nx / gamma >= 3.0, (gamma, grid)
    assert np.all(np.abs(samples["measured_density"] - samples["density"]) < 0.002)
    assert np.all(table["n_seeds"] >= 3)
    for i in range(len(table["density"])):
        m = foam_material(table["density"][i], table["gamma"][i], E_TPU, 0.3, table=name)
        expected = [E_TPU * table[k][i] for k in ("ti_E_t", "ti_E_l", "ti_G_l")]
        np.testing.assert_allclose([m.E_t, m.E_l, m.G_l], expected, rtol=1e-10)


def test_resolution_for_strut_is_the_smallest_admissible_grid():
    """N reaches the requested voxels across the strut and N − step does not; the step gives cubic voxels (γN an
    integer); with multiple=10 it reproduces the shipped `equiaxed` table's grids (3.85 voxels across, seed 0)."""
    from meshes.foam import VoronoiFoam

    settings = tables.SweepSettings(n_cells=8, box="equiaxed")
    for gamma, step in ((1.0, 1), (0.5, 2), (0.1, 10)):
        width = 2 * VoronoiFoam(8, 0.18, gamma, seed=0, box="equiaxed").radius
        for voxels in (3.5, 6.1):
            N = tables.resolution_for_strut(settings, 0.18, gamma, voxels)
            assert N % step == 0 and width * N >= voxels > width * (N - step)
    shipped = tables.read_csv(tables.table_paths("equiaxed")["samples"])
    for gamma in (0.1, 1.0):
        N = tables.resolution_for_strut(tables.SweepSettings(n_cells=27, box="equiaxed"), 0.18, gamma, 3.85,
                                        multiple=10)
        assert set(shipped["resolution"][shipped["gamma"] == gamma]) == {N}
    with pytest.raises(ValueError, match=r"voxels across the strut must be positive and finite, got -1"):
        tables.resolution_for_strut(settings, 0.18, 1.0, -1)
    with pytest.raises(ValueError, match=r"multiple must be a positive integer, got 0"):
        tables.resolution_for_strut(settings, 0.18, 1.0, 3.5, multiple=0)


def test_non_cubic_sweep_settings_are_an_explicit_opt_in_with_their_own_entries(tmp_path):
    """cubic=False takes the grid itself; its samples are named and keyed by the grid, carry it in their
    'resolution' column and are read back from the cache; cubic settings keep their entries' names."""
    grid = tables.SweepSettings(n_cells=3, resolution=(8, 16, 16), tol=1e-5, cubic=False)
    assert grid.resolution == (8, 16, 16)
    assert tables.SweepSettings(n_cells=3, resolution="8x16x16", tol=1e-5, cubic=False) == grid
    sample = tables.Sample(0.3, 1.0, 1)
    assert "_N8x16x16_" in tables.cache_name(sample, grid)
    assert "cubic" not in tables._cache_key(sample, TINY)   # cubic entries keep their names and hashes
    [row] = tables.run_sweep([sample], grid, tmp_path, MPI.COMM_SELF, progress=False)
    assert row["resolution"] == "8x16x16" and tables.settings_from_row(row) == grid
    assert abs(row["measured_density"] - 0.3) < 1e-3
    [cubic] = tables.run_sweep([sample], TINY, tmp_path, MPI.COMM_SELF, progress=False)
    assert tables.settings_from_row(cubic) == TINY
    assert abs(row["iso_E"] - cubic["iso_E"]) > 1e-6 * cubic["iso_E"]   # another grid, another sample
    assert len(list(tmp_path.glob("*.json"))) == 2
    assert tables.run_sweep([sample], grid, tmp_path, MPI.COMM_SELF, progress=False) == [row]  # read back


@pytest.mark.parametrize("kwargs, match", [
    ({"resolution": (8, 16, 16)}, r"resolution must be an integer >= 8 .*cubic=False.*\(8, 16, 16\)"),
    ({"resolution": 48, "cubic": False}, r"with cubic=False, resolution must be three integers .*48"),
    ({"resolution": (8, 16), "cubic": False}, r"with cubic=False, resolution must be three integers .*\(8, 16\)"),
    ({"resolution": "8x1x16", "cubic": False}, r"three integers >= 2 .*'8x1x16'"),
    ({"resolution": 48, "cubic": "no"}, r"cubic must be True or False, got 'no'"),
])
def test_bad_grids_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match):
        tables.SweepSettings(**kwargs)


def test_csv_round_trips_text_with_commas_and_floats_exactly(tmp_path):
    note = 'stopped at 96.9 %: DIVERGED_MAX_IT, "elliptic", margin 359 Pa'
    rows = [{"name": "beam_ti_z", "note": note, "x": 0.1 + 0.2}, {"name": "plain", "note": "", "x": -1e-300}]
    back = tables.read_csv(tables.to_csv(rows, tmp_path / "t.csv"))
    assert list(back["note"]) == [r["note"] for r in rows] and list(back["name"]) == ["beam_ti_z", "plain"]
    assert list(back["x"]) == [0.1 + 0.2, -1e-300]


# --------------------------------------------------------------------------------------------------
# The default discretization and the shipped tables' recorded one
# --------------------------------------------------------------------------------------------------
def test_shipped_tables_record_their_scheme_and_regenerate_with_it():
    """Every shipped table records the scheme it was made with: the older ones rotated (their provenance says so
    or, made before the choice, says nothing, which means rotated), the paper's foam the rotated … hex8 bracket
    (the default table: its hex8 side at γ 0.3, the midpoint elsewhere); the settings agree with every
    sample row, and the settings read back name the shipped table itself (the default: the tables it was merged
    from), not a table of today's default (hex8)."""
    assert tables.DEFAULT_DISCRETIZATION == "hex8"
    bracket = "equiaxed_polyhedral_bracket_pores0p0045"
    for name in tables.shipped_tables():
        recorded = tables.recorded_settings(name, nodes=True)
        samples = tables.read_csv(tables.table_paths(name)["samples"])
        assert sorted(recorded) == sorted(set(zip(samples["density"].tolist(), samples["gamma"].tolist(),
                                                  strict=True))), name
        for (_, gamma), settings in recorded.items():
            if name == tables.DEFAULT_TABLE:
                scheme = "hex8" if gamma == 0.3 else "bracket"
                source = "equiaxed_polyhedral_hex8_pores0p0045" if scheme == "hex8" else bracket
            else:
                scheme, source = ("bracket" if name == bracket else "rotated"), name
            assert settings.discretization == scheme and settings.name == source, (name, settings)
    polyhedral = tables.recorded_settings("equiaxed_polyhedral")
    assert polyhedral[0.1].resolution == (60, 300, 300) and not polyhedral[0.1].cubic
    assert polyhedral[0.1].maxiter == 20000 and polyhedral[1.0].resolution == 96
    # the paper's foam: grids scaled with density from the reference grid at 18 % (constant voxels across a wall)
    paper = tables.recorded_settings(tables.DEFAULT_TABLE, nodes=True)
    assert paper[(0.18, 0.1)].resolution == (60, 100, 100) and paper[(0.09, 0.1)].resolution == (120, 100, 100)
    assert paper[(0.18, 0.2)].resolution == (90, 150, 150) and paper[(0.09, 0.2)].resolution == (180, 150, 150)
    assert {s.pore_modulus for s in paper.values()} == {0.0045}
    with pytest.raises(ValueError, match=r"settings vary with density at gamma 0.1 .*nodes=True"):
        tables.recorded_settings(tables.DEFAULT_TABLE)


def test_recorded_settings_refuse_a_provenance_that_is_not_the_rows(tmp_path):
    """A table whose provenance has no settings, or settings that are not those of its rows, is refused by name."""
    import json
    import shutil

    src = tables.table_paths("equiaxed")
    dst = tables.table_paths("equiaxed", tmp_path)
    for key in ("samples", "table"):
        shutil.copy(src[key], dst[key])
    provenance = json.loads(src["provenance"].read_text())
    provenance["settings_per_gamma"]["0.1"]["tol"] = 1e-4
    dst["provenance"].write_text(json.dumps(provenance))
    with pytest.raises(ValueError, match=r"foam table 'equiaxed', gamma 0.1: the provenance's settings .* are not "
                                         r"those of its sample rows"):
        tables.recorded_settings("equiaxed", tmp_path)
    del provenance["settings_per_gamma"]
    dst["provenance"].write_text(json.dumps(provenance))
    with pytest.raises(ValueError, match=r"foam table 'equiaxed': its provenance records no settings for density "
                                         r"0.18, gamma 0.1"):
        tables.recorded_settings("equiaxed", tmp_path)
    dst["provenance"].unlink()
    with pytest.raises(ValueError, match=r"foam table 'equiaxed': provenance .* unreadable"):
        tables.recorded_settings("equiaxed", tmp_path)


@pytest.mark.slow  # one 48³ sample of the shipped cube table
def test_a_shipped_sample_recomputed_with_its_recorded_settings_is_the_shipped_one():
    """Regenerating a shipped table reads its recorded settings: the cube table's sample (0.3, 0.1, seed 0)
    recomputed with them is the shipped row to the solver's round-off (pcg reproduces the cg it was made with)."""
    samples = tables.read_csv(tables.SAMPLES_CSV)
    i = int(np.flatnonzero((samples["density"] == 0.3) & (samples["gamma"] == 0.1) & (samples["seed"] == 0))[0])
    settings = tables.recorded_settings("cube")[0.1]
    row = tables.homogenize_sample(tables.Sample(0.3, 0.1, 0), settings, threads=1)
    shipped = np.array([samples[c][i] for c in tables.C_ENTRIES])
    got = np.array([row[c] for c in tables.C_ENTRIES])
    assert np.abs(got - shipped).max() < 1e-6 * np.abs(shipped).max()
    assert "discretization" not in row
