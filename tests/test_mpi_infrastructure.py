"""The MPI fixtures themselves: a shared temporary directory and collective sums (run under mpirun -n 2)."""

import numpy as np
import pytest
from mpi4py import MPI

pytestmark = pytest.mark.mpi


def test_mpi_tmp_path_is_shared(mpi_tmp_path):
    comm = MPI.COMM_WORLD
    paths = comm.allgather(str(mpi_tmp_path))
    assert len(set(paths)) == 1
    if comm.rank == 0:
        (mpi_tmp_path / "marker").write_text("rank0")
    comm.Barrier()
    assert (mpi_tmp_path / "marker").read_text() == "rank0"


def test_buffer_allreduce_sums_over_ranks():
    comm = MPI.COMM_WORLD
    local = np.array([comm.rank + 1.0, 1.0])
    total = np.empty_like(local)
    comm.Allreduce(local, total, op=MPI.SUM)
    n = comm.size
    np.testing.assert_array_equal(total, [n * (n + 1) / 2, n])
