"""Tripod case A as built: l axes 30° from the arms (a chiral, D3-symmetric layout) twist the centre; the mirror
layout twists by the opposite angle; the probes do not depend on the partition.

The shipped scene `demos/scenes/tripod_case_a_flat.toml` is run with the shipped foam table at a coarser mesh
(2202 tets instead of 2694).
"""

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fenicsfoam.scene import run_scene

SCENE = Path(__file__).resolve().parents[1] / "demos" / "scenes" / "tripod_case_a_flat.toml"
COARSE_TRIPOD_H = 0.006  # 2202 tets, D3-invariant
#: the mirror y → −y: an element of the plate's (and the mesh's) symmetry group; it maps arm 0 onto itself and
#: swaps arms 1 and 2 (arms at 0°, 120°, 240°)
MIRROR = np.diag([1.0, -1.0, 1.0])
MIRRORED_ARM = {"arm0": "arm0", "arm1": "arm2", "arm2": "arm1"}


def case_a(h=COARSE_TRIPOD_H):
    scene = tomllib.loads(SCENE.read_text())
    scene["geometry"]["h"] = h
    scene["outputs"] = {"xdmf": False, "png": False}
    return scene


def mirror_image(scene):
    """The same plate reflected by y → −y: each arm's l axis reflected and carried to the reflected arm."""
    mirrored = copy.deepcopy(scene)
    directions = scene["orientation"]["directions"]
    mirrored["orientation"]["directions"] = {MIRRORED_ARM[arm]: (MIRROR @ np.asarray(d)).tolist()
                                             for arm, d in directions.items()}
    return mirrored


def test_case_a_directions_are_30_degrees_from_each_arm_with_one_sense():
    """The scene's l axes make +30° (counter-clockwise seen from above) with arms at 0°, 120°, 240°."""
    directions = case_a()["orientation"]["directions"]
    for i, arm_deg in enumerate((0.0, 120.0, 240.0)):
        d = np.asarray(directions[f"arm{i}"])
        assert np.linalg.norm(d) == pytest.approx(1.0, abs=1e-15)
        angle = np.degrees(np.arctan2(d[1], d[0])) - arm_deg
        assert (angle + 90.0) % 180.0 - 90.0 == pytest.approx(30.0, abs=1e-12), i  # an axis: modulo 180°


@pytest.fixture(scope="module")
def torsion():
    """Twist of the centre relative to rest (deg) of case A and of its mirror image, on one rank each."""
    scene = case_a()
    return {name: run_scene(s, comm=MPI.COMM_SELF).probe("center_rotation", relative_to="rest")
            for name, s in (("case_a", scene), ("mirror", mirror_image(scene)))}


def test_case_a_twists(torsion):
    """A chiral layout twists: more than a degree at the top (the layout along the arms gives round-off)."""
    assert abs(torsion["case_a"]["top"]) > 1.0, torsion["case_a"]
    assert abs(torsion["case_a"]["middle"]) < abs(torsion["case_a"]["top"])


def test_case_a_mirror_image_twists_the_opposite_way(torsion):
    """Mirror symmetry of the D3-invariant mesh: the reflected layout twists by exactly the opposite angle."""
    scale = abs(torsion["case_a"]["top"])
    for label, angle in torsion["case_a"].items():
        assert torsion["mirror"][label] == pytest.approx(-angle, abs=1e-9 * scale), label


@pytest.mark.mpi
@pytest.mark.skipif(MPI.COMM_WORLD.size < 2,
                    reason="compares a COMM_WORLD run with a COMM_SELF run: on one rank they are the same computation "
                           "(runs under mpirun -n 2)")
def test_case_a_probes_do_not_depend_on_the_partition():
    """Case A on COMM_WORLD (2 ranks under mpirun) and on each rank alone gives the same probes."""
    scene = case_a()
    parallel = run_scene(scene, comm=MPI.COMM_WORLD)
    serial = run_scene(scene, comm=MPI.COMM_SELF)
    assert parallel.n_dofs == serial.n_dofs
    for a, b in zip(parallel.steps, serial.steps):
        for name, value in b.probes.items():
            assert a.probes[name] == pytest.approx(value, rel=1e-7, abs=1e-10), (a.label, name)
