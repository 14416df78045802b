"""Mesh checks: a mesh drawn in millimetres warns naming metres; P1 through a thin part warns; sound meshes do not."""

import logging

import pytest
from mpi4py import MPI

from fenicsfoam.meshcheck import MIN_P1_LAYERS, check_degree, check_units, elements_through_thickness, mesh_extent
from fenicsfoam.scene import run_scene
from meshes.finger import FingerGeometry, make_finger

COMM = MPI.COMM_SELF
FINGER_MM = FingerGeometry(length=120.0, width=20.0, height=6.0, chamber=False)  # the same finger in millimetres


@pytest.fixture(scope="module")
def finger_m():
    return make_finger(COMM, 0.003, FingerGeometry(length=0.120, width=0.020, height=0.006, chamber=False))


def test_a_mesh_in_millimetres_warns_naming_metres(caplog):
    mesh = make_finger(COMM, 3.0, FINGER_MM).mesh
    with caplog.at_level(logging.WARNING, logger="fenicsfoam.meshcheck"):
        assert check_units(mesh)
    (record,) = caplog.records
    assert "120 m across" in record.getMessage() and "metres" in record.getMessage()
    assert "0.001" in record.getMessage()


def test_a_metre_mesh_does_not_warn(finger_m, caplog):
    with caplog.at_level(logging.WARNING, logger="fenicsfoam.meshcheck"):
        assert not check_units(finger_m.mesh)
        assert not check_degree(finger_m.mesh, 2)
    assert not caplog.records


def test_thinnest_dimension_is_measured_through_the_thickness(finger_m):
    """6 mm thick at h = 3 mm: about two elements through it (measured with the mean edge length)."""
    extent = mesh_extent(finger_m.mesh)
    assert extent.thinnest == pytest.approx(0.006, rel=1e-9)
    assert extent.size == pytest.approx(0.120, rel=1e-9)
    assert 1.0 < elements_through_thickness(finger_m.mesh, extent) < MIN_P1_LAYERS


def test_p1_through_a_thin_part_warns(finger_m, caplog):
    with caplog.at_level(logging.WARNING, logger="fenicsfoam.meshcheck"):
        assert check_degree(finger_m.mesh, 1)
    (record,) = caplog.records
    assert "degree = 2" in record.getMessage()


def test_scene_default_degree_is_2_and_a_p1_scene_warns(caplog):
    scene = {"geometry": {"builder": "finger", "h": 0.003, "length": 0.12, "width": 0.02, "height": 0.006,
                          "chamber": False},
             "regions": {"all": {"tags": "finger", "material": "isotropic", "E": 1e6, "nu": 0.3}},
             "loads": {"clamp": "base"}, "steps": [{"label": "rest"}], "outputs": {"xdmf": False, "png": False}}
    with caplog.at_level(logging.WARNING, logger="fenicsfoam.meshcheck"):
        result = run_scene(scene, comm=COMM)
    assert result.scene.degree == 2 and not caplog.records
    scene["fem"] = {"degree": 1}
    with caplog.at_level(logging.WARNING, logger="fenicsfoam.meshcheck"):
        run_scene(scene, comm=COMM)
    assert [r for r in caplog.records if "degree 1" in r.getMessage()]
