"""Test-suite wide fixtures: MPI synchronisation after each test and an MPI-safe temporary directory.

Run serially with ``pytest`` and in parallel with
``mpirun -n 2 python3 -m mpi4py -m pytest -m mpi`` (``-m mpi4py`` aborts every rank on an
uncaught exception instead of leaving the others hanging).
"""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

from foambase.threads import single_threaded_blas_by_default

single_threaded_blas_by_default()  # the test entry point, before numpy is imported
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _comm():
    from mpi4py import MPI

    return MPI.COMM_WORLD


@pytest.fixture(autouse=True)
def _mpi_barrier():
    """Synchronise all ranks after each test, so that one rank's failure cannot desynchronise the next test."""
    yield
    comm = _comm()
    if comm.size > 1:
        comm.Barrier()


@pytest.fixture
def mpi_tmp_path():
    """A temporary directory shared by all ranks: created on rank 0, its path broadcast, removed after the test."""
    comm = _comm()
    path = tempfile.mkdtemp(prefix="fenicsfoam-") if comm.rank == 0 else None
    path = comm.bcast(path, root=0)
    yield Path(path)
    comm.Barrier()
    if comm.rank == 0:
        shutil.rmtree(path, ignore_errors=True)
