"""meshes.beam: exact volume and face areas of the tagged box, validation of the arguments."""

import dolfinx
import numpy as np
import pytest
import ufl
from mpi4py import MPI

from meshes.beam import BEAM_VOLUME, CLAMPED_FACE, FIG6_BEAM, TIP_FACE, make_beam, mesh_from_gmsh

L, W, H = 0.25, 0.015, 0.01


def integrate(mesh, integrand, measure):
    return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(integrand * measure)), op=MPI.SUM)


@pytest.fixture(scope="module", params=[1, 2], ids=["order1", "order2"])
def beam(request):
    return make_beam(MPI.COMM_WORLD, L, W, H, h=0.005, order=request.param)


@pytest.mark.mpi
def test_volume_and_tagged_face_areas(beam):
    mesh = beam.mesh
    one = dolfinx.fem.Constant(mesh, 1.0)
    dx = ufl.Measure("dx", domain=mesh, subdomain_data=beam.cell_tags)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=beam.facet_tags)
    eps = 1e-12
    assert integrate(mesh, one, dx) == pytest.approx(L * W * H, rel=eps)
    assert integrate(mesh, one, dx(BEAM_VOLUME)) == pytest.approx(beam.volume, rel=eps)
    assert integrate(mesh, one, ds(CLAMPED_FACE)) == pytest.approx(W * H, rel=eps)
    assert integrate(mesh, one, ds(TIP_FACE)) == pytest.approx(W * H, rel=eps)
    # Each face sits where it should: mean x over the clamped face is 0, over the tip face L.
    X = ufl.SpatialCoordinate(mesh)
    assert integrate(mesh, X[0], ds(CLAMPED_FACE)) == pytest.approx(0.0, abs=eps * L * W * H)
    assert integrate(mesh, X[0], ds(TIP_FACE)) / (W * H) == pytest.approx(L, rel=eps)
    assert beam.mesh.geometry.cmap.degree == beam.order


@pytest.mark.mpi
def test_bounding_box_and_sizes(beam):
    x = beam.mesh.geometry.x
    local = np.concatenate([-x.min(axis=0), x.max(axis=0)])
    extent = np.empty_like(local)
    beam.mesh.comm.Allreduce(local, extent, op=MPI.MAX)
    np.testing.assert_allclose(extent, [0, W / 2, H / 2, L, W / 2, H / 2], atol=1e-15)
    n_local = beam.mesh.topology.index_map(3).size_local
    assert beam.n_cells == beam.mesh.comm.allreduce(n_local, op=MPI.SUM) > 0
    assert beam.meshing_s == beam.mesh.comm.bcast(beam.meshing_s) > 0


def test_fig6_preset_gives_about_20k_tetrahedra():
    beam = make_beam(MPI.COMM_WORLD, **FIG6_BEAM)
    assert 17_000 <= beam.n_cells <= 23_000


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(length=-0.25), "beam length must be a positive length"),
        (dict(width=0.0), "beam width must be a positive length"),
        (dict(h=float("nan")), "beam h must be a positive length"),
        (dict(h=0.02), "h = 0.02 m exceeds the smallest cross-section side 0.01"),
        (dict(order=3), "order must be 1 .* or 2"),
    ],
)
def test_bad_arguments_are_rejected(kwargs, match):
    args = dict(length=L, width=W, height=H, h=0.005) | kwargs
    with pytest.raises(ValueError, match=match):
        make_beam(MPI.COMM_WORLD, **args)


@pytest.mark.mpi
def test_a_failing_gmsh_build_raises_on_every_rank_and_leaves_gmsh_usable():
    def build():
        raise ValueError("no geometry here")

    comm = MPI.COMM_WORLD
    error, match = (ValueError, "no geometry") if comm.rank == 0 else (RuntimeError, "gmsh failed to build 'broken'")
    with pytest.raises(error, match=match):
        mesh_from_gmsh(comm, "broken", build, h=0.1, order=1)
    assert make_beam(comm, 1.0, 0.5, 0.5, h=0.5).n_cells > 0
