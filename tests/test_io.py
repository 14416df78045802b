"""Reading results back: solution.npz holds the gathered mesh (one conforming mesh on any number of ranks) and the
displacement of every step; the same points and cells on 1 and 2 ranks, number for number."""

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.io import read_solution
from fenicsfoam.scene import run_scene
from foambase.errors import InputError


def scene(degree):
    return {
        "name": "io",
        "geometry": {"builder": "finger", "h": 0.006, "length": 0.06, "width": 0.012, "height": 0.012,
                     "chamber": False},
        "fem": {"model": "linear", "degree": degree},
        "regions": {"all": {"tags": "finger", "material": "isotropic", "E": 1e6, "nu": 0.3, "rho": 500.0}},
        "loads": {"gravity": [0.0, 0.0, -9.81], "clamp": "base"},
        "steps": [{"label": "half", "gravity": 0.5}, {"label": "full", "gravity": 1.0}],
        "probes": ["displacement:tip"],
        "outputs": {"png": False},
    }


@pytest.mark.mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_solution_file_is_the_gathered_mesh_and_every_step(mpi_tmp_path, degree):
    comm = MPI.COMM_WORLD
    world = run_scene(scene(degree), mpi_tmp_path / "world", comm=comm)
    serial = run_scene(scene(degree), mpi_tmp_path / f"self{comm.rank}", comm=MPI.COMM_SELF)
    a = read_solution(mpi_tmp_path / "world")
    b = read_solution(mpi_tmp_path / f"self{comm.rank}")
    assert a.labels == ("half", "full")
    assert len(a.points) * 3 == world.n_dofs == serial.n_dofs  # every node once: no duplicates at rank boundaries
    assert a.cells.shape == (world.n_cells, 4 if degree == 1 else 10)
    assert len(np.unique(a.cells)) == len(a.points)
    # the numbering does not depend on the number of ranks: identical points and cells, in the same order
    assert np.array_equal(a.points, b.points) and np.array_equal(a.cells, b.cells)
    ub = b.displacements
    assert np.allclose(a.displacements, ub, rtol=0, atol=1e-9 * np.abs(ub).max())
    # the clamped face does not move; linear model: half the gravity, half the displacement
    assert np.abs(a.displacement("full")[np.isclose(a.points[:, 0], 0.0)]).max() == 0.0
    assert np.allclose(a.displacement("half"), 0.5 * a.displacement("full"), atol=1e-9 * np.abs(ub).max())
    # the tip nodes' displacement agrees with the probe (a mean over the face)
    tip = np.isclose(a.points[:, 0], 0.06)
    assert a.displacement("full")[tip, 2].mean() == pytest.approx(world.steps[-1].probes["displacement:tip"][2],
                                                                  rel=0.02)
    grid = a.to_pyvista("half")
    assert grid.n_points == len(a.points) and grid.n_cells == len(a.cells)


def test_read_solution_names_a_missing_file(tmp_path):
    with pytest.raises(InputError, match="solution.npz does not exist"):
        read_solution(tmp_path)
