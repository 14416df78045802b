"""Geometry builders are a registry (``fenicsfoam.scene.kinds.GEOMETRY_KINDS``): a new builder is one entry.

A builder registered by this test (a cube through ``meshes.beam.make_beam``, with its own key ``side``) is read,
checked and meshed by the scene like the shipped ones: its default, its check, its groups and its mesher are the
entry's; the clamped cube under gravity reaches the same tip deflection as the beam builder given the same box.
"""

from __future__ import annotations

import pytest
from mpi4py import MPI

from fenicsfoam.scene import SceneError, parse_scene, run_scene
from fenicsfoam.scene.kinds import GEOMETRY_KINDS, GeometryKey, GeometryKind


def _cube_mesh(comm, params):
    from meshes.beam import make_beam
    return make_beam(comm, params["side"], params["side"], params["side"], params["h"])


@pytest.fixture
def cube_builder(monkeypatch):
    beam = GEOMETRY_KINDS["beam"]
    kind = GeometryKind(lambda: {"h": GeometryKey(0.01), "side": GeometryKey(0.04)}, beam.groups, _cube_mesh)
    monkeypatch.setitem(GEOMETRY_KINDS, "cube", kind)
    return kind


def _scene(geometry):
    return {"geometry": geometry, "probes": ["tip_deflection"],
            "regions": {"all": {"tags": "beam", "material": "isotropic", "E": 1e5, "nu": 0.3, "rho": 1000.0}},
            "loads": {"gravity": [0.0, 0.0, -9.81], "clamp": "clamped"},
            "steps": [{"label": "sag", "gravity": 1.0}], "fem": {"degree": 1, "model": "linear"},
            "outputs": {"png": False, "xdmf": False}}


def test_a_registered_builder_is_read_checked_and_meshed_like_the_shipped_ones(cube_builder):
    scene = parse_scene(_scene({"builder": "cube"}))
    assert scene.builder == "cube" and scene.geometry == {"h": 0.01, "side": 0.04}
    assert set(scene.facets) == {"clamped", "tip"} and set(scene.geometry) == {"h", "side"}
    with pytest.raises(SceneError, match=r"^geometry\.side: -1\.0 is out of range; valid: a length > 0 \(m\)"):
        parse_scene(_scene({"builder": "cube", "side": -1.0}))
    with pytest.raises(SceneError, match=r"^geometry\.length: unknown key; valid keys here: builder, h, side$"):
        parse_scene(_scene({"builder": "cube", "length": 0.04}))
    cube = run_scene(scene, comm=MPI.COMM_SELF).steps[0].probes["tip_deflection"]
    beam = run_scene(parse_scene(_scene({"builder": "beam", "h": 0.01, "length": 0.04, "width": 0.04,
                                         "height": 0.04})), comm=MPI.COMM_SELF).steps[0].probes["tip_deflection"]
    assert cube < 0 and cube == pytest.approx(beam, rel=1e-12)


def test_the_builder_names_come_from_the_registry():
    with pytest.raises(SceneError, match=r"geometry\.builder: .*'beam', 'tripod', 'finger', 'file'"):
        parse_scene(_scene({"builder": "sphere"}))
