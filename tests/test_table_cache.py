"""The foam table sweep's cache: exact keys, unusable entries recomputed, failed samples recorded."""

import json
import logging

import pytest
from mpi4py import MPI

from foambase.errors import ComputationError
from homogenization import tables

TINY = tables.SweepSettings(n_cells=3, resolution=16, tol=1e-5)


def _strip_time(rows):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


def test_settings_that_round_alike_never_share_an_entry(tmp_path):
    sample = tables.Sample(0.3, 1.0, 1)
    loose, close = (tables.SweepSettings(n_cells=3, resolution=16, tol=t) for t in (1e-5, 1.4e-5))
    assert tables.cache_name(sample, loose) != tables.cache_name(sample, close)
    assert tables.cache_name(sample, TINY) != tables.cache_name(tables.Sample(0.30001, 1.0, 1), TINY)
    [first] = tables.run_sweep([sample], loose, tmp_path, MPI.COMM_SELF, progress=False)
    [second] = tables.run_sweep([sample], close, tmp_path, MPI.COMM_SELF, progress=False)
    assert (first["tol"], second["tol"]) == (1e-5, 1.4e-5)  # the second sweep computed its own sample
    assert len(list(tmp_path.glob("*.json"))) == 2


@pytest.mark.parametrize("damage", ["truncated", "another sample", "not an object"])
def test_an_unusable_entry_is_named_and_recomputed(tmp_path, caplog, damage):
    samples = tables.grid((0.25, 0.3), (1.0,), (1,))
    straight = tables.run_sweep(samples, TINY, tmp_path / "a", MPI.COMM_SELF, progress=False)
    entry = tmp_path / "a" / tables.cache_name(samples[1], TINY)
    text = entry.read_text()
    if damage == "truncated":
        entry.write_text(text[: len(text) // 2])
    elif damage == "another sample":
        entry.write_text((tmp_path / "a" / tables.cache_name(samples[0], TINY)).read_text())
    else:
        entry.write_text(json.dumps([1, 2, 3]))
    with caplog.at_level(logging.WARNING, logger="homogenization.tables"):
        again = tables.run_sweep(samples, TINY, tmp_path / "a", MPI.COMM_SELF, progress=False)
    assert str(entry) in caplog.text and "recomputed" in caplog.text
    assert _strip_time(again) == _strip_time(straight)
    assert json.loads(entry.read_text())["density"] == 0.3  # overwritten with the sample's own row


def test_a_failed_sample_is_recorded_while_the_sweep_goes_on(tmp_path):
    samples = tables.grid((0.3, 0.9), (1.0,), (1,))  # 0.9: a density the strut foam cannot reach
    with pytest.raises(ComputationError, match=r"1 sample\(s\) failed.*density=0.9.*FoamParameterError") as info:
        tables.run_sweep(samples, TINY, tmp_path, MPI.COMM_SELF, progress=False)
    assert info.value.exit_code == 2
    assert (tmp_path / tables.cache_name(samples[0], TINY)).is_file()  # the sample after the failure was computed
    [record] = tmp_path.glob("*.failed.txt")
    assert "density=0.9" in record.read_text() and record.name.startswith("d0.9000")
    assert not (tmp_path / tables.cache_name(samples[1], TINY)).exists()


@pytest.mark.mpi
def test_a_failure_on_one_rank_is_raised_on_every_rank_after_the_others_finish(tmp_path):
    comm = MPI.COMM_WORLD
    cache = comm.bcast(tmp_path if comm.rank == 0 else None) / "sweep"
    samples = tables.grid((0.3, 0.9), (1.0,), (1,))
    with pytest.raises(ComputationError, match=r"density=0.9"):
        tables.run_sweep(samples, TINY, cache, comm, progress=False)
    comm.barrier()
    assert (cache / tables.cache_name(samples[0], TINY)).is_file()
