"""A density × γ sweep in one resumable run (a grid per node, scaled_resolution) and the merge of tables."""

import pytest
from mpi4py import MPI

from foambase.errors import InputError
from homogenization import tables

DENSITIES, GAMMAS, SEEDS = (0.25, 0.3), (0.5, 1.0), (1,)


def node_settings(sample):
    """The strut foam at 16³ at density 0.25, its grid scaled by 0.25/ρ elsewhere (13³ at 0.3)."""
    n = tables.scaled_resolution(16, sample.density, 0.25, sample.gamma, box="cube")
    return tables.SweepSettings(n_cells=3, resolution=n, tol=1e-5)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    rows = tables.run_sweep(tables.grid(DENSITIES, GAMMAS, SEEDS), node_settings, cache, MPI.COMM_SELF,
                            progress=False)
    return cache, rows


def test_scaled_resolution_keeps_voxels_cubic_and_scales_with_density():
    assert tables.scaled_resolution(96, 0.09, 0.18, 1.0) == 192
    assert tables.scaled_resolution(96, 0.35, 0.18, 1.0) == 49
    assert tables.scaled_resolution(96, 0.35, 0.18, 0.1) == 50  # a multiple of 10: γ N whole in (0.1, 1, 1)
    assert tables.scaled_resolution(96, 0.35, 0.18, 0.5) == 50
    assert tables.scaled_resolution("60x300x300", 0.09, 0.18, 0.1) == (120, 300, 300)  # x only
    assert tables.scaled_resolution((60, 300, 300), 0.18, 0.18, 0.1) == (60, 300, 300)
    assert tables.scaled_resolution(8, 0.3, 0.1, 0.1) == 10  # never below 8, still whole voxels
    with pytest.raises(InputError, match="reference_density must lie in"):
        tables.scaled_resolution(96, 0.2, 1.5)
    with pytest.raises(InputError, match="resolution must be"):
        tables.scaled_resolution("60x300", 0.2, 0.18)


def test_one_run_sweeps_every_node_at_its_own_grid(sweep, tmp_path):
    _, rows = sweep
    assert [(r["density"], r["gamma"], r["resolution"]) for r in rows] == [
        (0.25, 0.5, 16), (0.25, 1.0, 16), (0.3, 0.5, 13), (0.3, 1.0, 13)]
    # the sample computed alone (a fresh cache) at its node's settings gives the sweep's stiffness
    [alone] = tables.run_sweep([tables.Sample(0.3, 1.0, 1)], node_settings(tables.Sample(0.3, 1.0, 1)),
                               tmp_path, MPI.COMM_SELF, progress=False)
    assert alone["C11"] == rows[3]["C11"]


def test_a_second_run_computes_nothing_and_writes_the_same_table(sweep, tmp_path, monkeypatch):
    cache, rows = sweep

    def refuse(*args, **kwargs):
        raise AssertionError("a cached sample was recomputed")

    monkeypatch.setattr(tables, "homogenize_sample", refuse)
    again = tables.run_sweep(tables.grid(DENSITIES, GAMMAS, SEEDS), node_settings, cache, MPI.COMM_SELF,
                             progress=False)
    assert again == rows
    first = tables.write_tables(rows, tmp_path / "a", {"run": 1})
    second = tables.write_tables(again, tmp_path / "b", {"run": 1})
    for kind in ("samples", "table"):
        assert first[kind].read_bytes() == second[kind].read_bytes()


def test_per_density_tables_merge_into_the_whole_grid_table(sweep, tmp_path):
    _, rows = sweep
    whole = tables.write_tables(rows, tmp_path / "whole", {"part": "all"})
    for d in DENSITIES:
        tables.write_tables([r for r in rows if r["density"] == d], tmp_path / f"d{d}", {"density": d})
    # the 0.3 table given twice: the same samples at the same settings are kept once
    merged = tables.merge_tables([tmp_path / "d0.25", tmp_path / "d0.3", tmp_path / "d0.3"], tmp_path / "merged")
    assert merged["table"].read_bytes() == whole["table"].read_bytes()
    assert merged["samples"].read_bytes() == whole["samples"].read_bytes()
    assert tables.read_samples(merged["samples"]) == rows


def test_merge_refuses_a_node_at_other_settings_and_names_it(sweep):
    _, rows = sweep
    finer = [r | {"resolution": 20, "seed": 2} for r in rows if r["density"] == 0.3]
    with pytest.raises(InputError, match=r"density 0.3, gamma 0.5 has other settings in 'finer' than in 'base'"
                                         r": resolution 13 vs 20"):
        tables.merge_samples([("base", rows), ("finer", finer)])
    changed = [rows[0] | {"C11": rows[0]["C11"] * 1.01}]
    with pytest.raises(InputError, match=r"seed 1 differs between 'base' and 'changed'"):
        tables.merge_samples([("base", rows), ("changed", changed)])
    struts_in_box = [r | {"box": "equiaxed", "density": 0.5} for r in rows[:1]]
    with pytest.raises(InputError, match="different tables"):
        tables.merge_samples([("base", rows), ("box", struts_in_box)])


def test_a_named_merge_puts_nodes_of_different_tables_together_each_with_its_own_settings(sweep, tmp_path):
    """γ = 1 from the sweep's hex8 table, γ = 0.5 from a rotated one (its rows relabelled: the merge reads
    settings, not stiffnesses): refused unnamed, merged under a name, and every node reads back its own source's
    settings."""
    _, rows = sweep
    assert {r["discretization"] for r in rows} == {"hex8"}
    rotated = [r | {"discretization": "rotated"} for r in rows if r["gamma"] == 0.5]
    hex8 = [r for r in rows if r["gamma"] == 1.0]
    for label, part in (("rotated", rotated), ("hex8", hex8)):
        per_node = {f"density={r['density']:g},gamma={r['gamma']:g}": tables.settings_dict(
            tables.settings_from_row(r)) for r in part}
        tables.write_tables(part, tmp_path / label, {"settings_per_node": per_node},
                            tables.settings_from_row(part[0]).name)
    with pytest.raises(InputError, match="different tables.*give the merged table a name"):
        tables.merge_tables([tmp_path / "rotated", tmp_path / "hex8"], tmp_path / "unnamed")
    with pytest.raises(InputError, match="letters, digits"):
        tables.merge_tables([tmp_path / "rotated", tmp_path / "hex8"], tmp_path / "bad", name="a/b")
    tables.write_tables([{k: v for k, v in r.items() if k != "discretization"} for r in rotated],
                        tmp_path / "no_column", {}, "cube")
    with pytest.raises(InputError, match=r"other columns: .*\['discretization'\]"):
        tables.merge_tables([tmp_path / "no_column", tmp_path / "hex8"], tmp_path / "columns", name="chosen")
    paths = tables.merge_tables([tmp_path / "rotated", tmp_path / "hex8"], tmp_path / "mixed", name="chosen")
    assert paths["table"].name == "foam_table_chosen.csv"
    recorded = tables.recorded_settings("chosen", tmp_path / "mixed", nodes=True)
    assert {g: s.discretization for (_, g), s in recorded.items()} == {0.5: "rotated", 1.0: "hex8"}
    assert {(d, g): s.resolution for (d, g), s in recorded.items()} == {
        (0.25, 0.5): 16, (0.3, 0.5): 13, (0.25, 1.0): 16, (0.3, 1.0): 13}


@pytest.mark.mpi
@pytest.mark.parametrize("distribute", ["samples", pytest.param("fft", marks=pytest.mark.slow)])
def test_per_node_settings_under_mpi_give_the_serial_rows(tmp_path, distribute):
    """Two nodes at their own grids, dealt to the ranks or each on both: the rows of one rank alone."""
    comm = MPI.COMM_WORLD
    root = comm.bcast(tmp_path if comm.rank == 0 else None)
    samples = tables.grid((0.25, 0.3), (1.0,), (1,))
    rows = tables.run_sweep(samples, node_settings, root / "mpi", comm, progress=False, distribute=distribute)
    if comm.rank == 0:
        serial = tables.run_sweep(samples, node_settings, root / "serial", MPI.COMM_SELF, progress=False)
        assert [r["resolution"] for r in rows] == [16, 13]
        for got, want in zip(rows, serial, strict=True):
            assert got["C11"] == pytest.approx(want["C11"], rel=1e-8)  # the distributed FFT: round-off through CG
            assert got["G23"] == pytest.approx(want["G23"], rel=1e-8)
    comm.barrier()
