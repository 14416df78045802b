"""The finger builder: exact volume and facet-group areas (planar faces), with and without chamber and pad, on any
number of ranks; invalid sizes are refused before meshing."""

import dolfinx
import pytest
import ufl
from mpi4py import MPI

from foambase.errors import InputError
from meshes.finger import FACET_TAGS, FingerGeometry, make_finger


def measure(mesh, form) -> float:
    return mesh.comm.allreduce(dolfinx.fem.assemble_scalar(dolfinx.fem.form(form)), op=MPI.SUM)


@pytest.mark.mpi
@pytest.mark.parametrize("geometry", [FingerGeometry(), FingerGeometry(chamber=False, pad=0.01),
                                      FingerGeometry(pad=0.008)], ids=["chamber", "pad", "chamber+pad"])
def test_volume_and_group_areas_are_exact(geometry):
    finger = make_finger(MPI.COMM_WORLD, 0.004, geometry)
    mesh, g = finger.mesh, geometry
    one = dolfinx.fem.Constant(mesh, 1.0)
    assert measure(mesh, one * ufl.dx) == pytest.approx(g.volume, rel=1e-12)
    ds = ufl.Measure("ds", domain=mesh, subdomain_data=finger.facet_tags)
    lo, hi = g.chamber_box
    a, b, c = (h - l for l, h in zip(lo, hi))
    expected = {"base": g.width * g.height, "tip": g.width * g.height, "top": g.length * g.width,
                "bottom": (g.length - g.pad) * g.width, "sides": 2 * g.length * g.height, "pad": g.pad * g.width,
                "chamber": 2 * (a * b + b * c + c * a) if g.chamber else 0.0}
    for name, area in expected.items():
        assert measure(mesh, one * ds(FACET_TAGS[name])) == pytest.approx(area, rel=1e-12, abs=1e-15), name
    assert measure(mesh, one * ds) == pytest.approx(sum(expected.values()), rel=1e-12)  # nothing else on the boundary


@pytest.mark.parametrize("kwargs, message", [
    ({"top_wall": 0.01, "bottom_wall": 0.006}, "leave no room for the chamber in height"),
    ({"length": -0.1}, "finger length must be a length > 0"),
    ({"pad": 0.2}, r"pad must be a length in \[0, length\)"),
])
def test_invalid_geometry_is_refused(kwargs, message):
    with pytest.raises(InputError, match=message):
        FingerGeometry(**kwargs)


def test_element_size_is_checked_against_the_thinnest_wall():
    with pytest.raises(InputError, match="more than twice its thinnest wall"):
        make_finger(MPI.COMM_SELF, 0.005)
