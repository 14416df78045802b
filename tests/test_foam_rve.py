"""mesh_rve: the conforming periodic two-phase tetrahedral mesh of a foam RVE.

Cross-checks: the meshed solid volume against the foam's sampled density (the piecewise-linear interface converges
at second order in h), the face areas and total volume against the cube, the node-for-node match of opposite faces,
the solid-only mesh against the solid phase of the two-phase mesh, serial against ``mpirun -n 2``.
"""

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from meshes.foam import FoamParameterError, VoronoiFoam, mesh_rve
from meshes.rve import FACE_TAGS, SOLID, VOID

ONE_RANK_SKIP = pytest.mark.skipif(
    MPI.COMM_WORLD.size < 2,
    reason="compares a COMM_WORLD run with a COMM_SELF run: on one rank they are the same computation "
           "(runs under mpirun -n 2)")


@pytest.fixture(scope="module")
def foam():
    """A small foam with thick struts (4 cells, density 0.25, radius 0.088), meshable at coarse h."""
    return VoronoiFoam(4, 0.25, gamma=1.0, seed=1)


@pytest.fixture(scope="module")
def rve(foam):
    return mesh_rve(foam, 1 / 12, MPI.COMM_WORLD)


def _integral(mesh, integrand) -> float:
    return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(integrand)), op=MPI.SUM)


def _volumes(rve) -> dict[int, float]:
    dx = ufl.Measure("dx", domain=rve.mesh, subdomain_data=rve.cell_tags)
    one = dolfinx.fem.Constant(rve.mesh, 1.0)
    return {tag: _integral(rve.mesh, one * dx(tag)) for tag in (SOLID, VOID)}


@pytest.mark.mpi
def test_phases_fill_the_cube_and_faces_are_tagged(rve):
    volumes = _volumes(rve)
    assert volumes[SOLID] + volumes[VOID] == pytest.approx(1.0, abs=1e-12)
    ds = ufl.Measure("ds", domain=rve.mesh, subdomain_data=rve.facet_tags)
    one = dolfinx.fem.Constant(rve.mesh, 1.0)
    for name, tag in FACE_TAGS.items():
        assert _integral(rve.mesh, one * ds(tag)) == pytest.approx(1.0, abs=1e-12), name
    assert _integral(rve.mesh, one * ds) == pytest.approx(6.0, abs=1e-12)    # no other boundary
    assert rve.kind == "two-phase" and rve.n_elements > 6 * 12**3 and rve.meshing_s > 0


def test_solid_volume_converges_to_the_density_at_second_order(foam, rve):
    """The interface is the piecewise-linear interpolant of the strut surface: volume error O(h²), measured
    7.1e-3 at h = 1/12 and 1.5e-3 at h = 1/24 (rate 2.2) against the foam's sampled density (± 2e-4)."""
    errors = [abs(_volumes(r)[SOLID] - foam.measured_density) for r in (rve, mesh_rve(foam, 1 / 24, MPI.COMM_SELF))]
    assert errors[0] < 0.01 and errors[1] < 0.0025
    assert np.log2(errors[0] / errors[1]) > 1.7


def _face_points(rve, axis: int, value: float) -> np.ndarray:
    """Mesh vertices on the plane ``x_axis = value``, gathered on every rank, sorted (rounded to 1e-12)."""
    x = rve.mesh.geometry.x
    local = x[np.abs(x[:, axis] - value) < 1e-12]
    points = np.concatenate(rve.mesh.comm.allgather(local))
    points[:, axis] = 0.0
    return np.unique(np.round(points, 12), axis=0)


@pytest.mark.mpi
def test_opposite_faces_match_node_for_node(rve):
    for axis in range(3):
        lower, upper = _face_points(rve, axis, 0.0), _face_points(rve, axis, 1.0)
        assert len(lower) > (12 + 1) ** 2
        assert np.array_equal(lower, upper)


def test_solid_only_mesh_is_the_solid_phase(foam, rve):
    solid = mesh_rve(foam, 1 / 12, MPI.COMM_WORLD, kind="solid")
    assert solid.kind == "solid"
    assert set(np.unique(solid.cell_tags.values)) == {SOLID}
    dx = ufl.Measure("dx", domain=solid.mesh)
    assert _integral(solid.mesh, dolfinx.fem.Constant(solid.mesh, 1.0) * dx) == pytest.approx(
        _volumes(rve)[SOLID], abs=1e-12)
    mesh, cell_tags, facet_tags = rve                       # unpacks like a (mesh, cell_tags, facet_tags) tuple
    assert mesh is rve.mesh and cell_tags is rve.cell_tags and facet_tags is rve.facet_tags


@ONE_RANK_SKIP
@pytest.mark.mpi
def test_distributed_mesh_has_the_serial_volume(foam, rve):
    serial = mesh_rve(foam, 1 / 12, MPI.COMM_SELF)
    assert serial.n_elements == rve.n_elements
    assert _volumes(rve)[SOLID] == pytest.approx(_volumes(serial)[SOLID], rel=1e-12)


@pytest.mark.parametrize("kwargs, match", [
    ({"h": 0.5}, r"h must be in \[1/64, 2 radius = 0\.17\d+\] for VoronoiFoam\(n_cells=4, density=0\.25, "
                 r"gamma=1\.0, seed=1.*got 0\.5"),
    ({"h": 0.01}, r"h must be in \[1/64, .*got 0\.01"),
    ({"h": 0.1, "order": 2}, r"only order=1 .* got 2"),
    ({"h": 0.1, "kind": "voxel"}, r"kind must be one of \('two-phase', 'solid'\), got 'voxel'"),
])
def test_invalid_arguments_raise_clear_errors(foam, kwargs, match):
    with pytest.raises(FoamParameterError, match=match):
        mesh_rve(foam, comm=MPI.COMM_WORLD, **kwargs)
