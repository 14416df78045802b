"""Cell-wise orientation fields: values checked cell by cell at the cell midpoints, errors, ghost consistency."""

import numpy as np
import pytest
from dolfinx import mesh
from mpi4py import MPI

from fenicsfoam import orientation
from fenicsfoam.orientation import OrientationError

pytestmark = pytest.mark.mpi


@pytest.fixture(scope="module")
def cube():
    msh = mesh.create_unit_cube(MPI.COMM_WORLD, 3, 3, 3)
    n = msh.topology.index_map(3).size_local
    midpoints = mesh.compute_midpoints(msh, 3, np.arange(n, dtype=np.int32))
    # Tag 1 below x = 1/2, tag 2 above, tag 3 for the top layer z > 2/3.
    tags = np.where(midpoints[:, 0] < 0.5, 1, 2).astype(np.int32)
    tags[midpoints[:, 2] > 2 / 3] = 3
    cell_tags = mesh.meshtags(msh, 3, np.arange(n, dtype=np.int32), tags)
    return msh, cell_tags, midpoints


def values_at_midpoints(f, midpoints):
    """Evaluate the DG0 field at the midpoint of each owned cell (cell i contains midpoint i)."""
    return f.eval(midpoints, np.arange(len(midpoints), dtype=np.int32))


def test_uniform(cube):
    msh, _, midpoints = cube
    a = orientation.uniform(msh, (0.0, 3.0, 4.0))
    np.testing.assert_allclose(values_at_midpoints(a, midpoints), np.tile([0.0, 0.6, 0.8], (len(midpoints), 1)))


def test_per_tag_cell_by_cell(cube):
    msh, cell_tags, midpoints = cube
    a = orientation.per_tag(msh, cell_tags, {1: (2.0, 0.0, 0.0), 2: (0.0, -1.0, 1.0), 3: (0.0, 0.0, 5.0)})
    expected = np.where((midpoints[:, 0] < 0.5)[:, None], [1.0, 0.0, 0.0], [0.0, -np.sqrt(0.5), np.sqrt(0.5)])
    expected[midpoints[:, 2] > 2 / 3] = [0.0, 0.0, 1.0]
    np.testing.assert_allclose(values_at_midpoints(a, midpoints), expected, atol=1e-15)


def test_per_tag_default_and_missing_tags(cube):
    msh, cell_tags, midpoints = cube
    a = orientation.per_tag(msh, cell_tags, {1: (1.0, 0.0, 0.0)}, default=(0.0, 0.0, 2.0))
    expected = np.where((midpoints[:, 0] < 0.5) & (midpoints[:, 2] <= 2 / 3), 1.0, 0.0)
    np.testing.assert_allclose(values_at_midpoints(a, midpoints)[:, 0], expected, atol=1e-15)
    n_missing = msh.comm.allreduce(int(np.sum(midpoints[:, 0] >= 0.5) + np.sum(
        (midpoints[:, 0] < 0.5) & (midpoints[:, 2] > 2 / 3))))
    with pytest.raises(OrientationError, match=rf"{n_missing} cell\(s\) have tags \[2, 3\] without a direction"):
        orientation.per_tag(msh, cell_tags, {1: (1.0, 0.0, 0.0)})


PITCH = np.radians(30.0)


def spiral(x, pitch=PITCH):
    """A helix of the given pitch angle about the z axis (tangent to circles about the axis, tilted up)."""
    theta = np.arctan2(x[:, 1] - 0.5, x[:, 0] - 0.5)
    return np.column_stack([-np.sin(theta) * np.cos(pitch), np.cos(theta) * np.cos(pitch),
                            np.full(len(x), np.sin(pitch))]) * 7.0


def test_from_callable_cell_by_cell(cube):
    msh, _, midpoints = cube
    a = orientation.from_callable(msh, spiral)
    d = spiral(midpoints)
    np.testing.assert_allclose(values_at_midpoints(a, midpoints), d / np.linalg.norm(d, axis=1)[:, None], atol=1e-15)


def test_ghost_values_are_the_owners(cube):
    msh = cube[0]
    a = orientation.from_callable(msh, spiral)
    before = a.x.array.copy()
    a.x.scatter_forward()
    np.testing.assert_array_equal(a.x.array, before)
    assert np.allclose(np.linalg.norm(a.x.array.reshape(-1, 3), axis=1), 1.0)


def test_zero_and_non_finite_directions_are_refused(cube):
    msh, _, midpoints = cube
    with pytest.raises(OrientationError, match="must be finite and non-zero"):
        orientation.uniform(msh, (0.0, 0.0, 0.0))
    n_bad = msh.comm.allreduce(int(np.sum(midpoints[:, 0] < 0.5)))

    def half_zero(x):
        d = np.tile([1.0, 0.0, 0.0], (len(x), 1))
        d[x[:, 0] < 0.5] = [0.0, np.nan, 0.0]
        return d

    with pytest.raises(OrientationError, match=rf"from_callable: {n_bad} cell\(s\) have a zero or non-finite"):
        orientation.from_callable(msh, half_zero)
    with pytest.raises(OrientationError, match="directions of the same shape"):
        orientation.from_callable(msh, lambda x: x[:, :2])
