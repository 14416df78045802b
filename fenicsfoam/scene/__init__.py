"""TOML scene files: a robot (mesh, regions, orientation, model), its load schedule, probes and outputs.

A scene is read with the standard library's ``tomllib`` and validated key by key before anything is built:
an unknown key, a value of the wrong type, a missing value or a value out of range raises :class:`SceneError`
whose message names the key path (e.g. ``regions.arms.density``) and what would be valid. Only what the scene
declares is built (a clamp if ``loads.clamp`` is given, servo actuators if ``[loads.servo.NAME]`` is given (or
``loads.servos`` is true), gravity if ``loads.gravity`` is given, each named load and motion, the listed probes).
Every key is documented in the docs' scenes page.

Layout of a scene (SI units; servo angles in degrees)::

    name = "tripod_case_b"
    [geometry]      builder = "beam" | "tripod" | "finger", and the builder's parameters (h, order, sizes),
                    or builder = "file", path = "robot.msh" (gmsh; relative to the scene file's directory)
    [fem]           model = "linear" | "svk" | "corotational" | "bonet_burton" | "corotational_sofa",
                    degree = 2 | 1, [fem.petsc] options
    [regions.NAME]  tags = int | [ints] | "named region", material = "isotropic" | "transverse_isotropic" | "foam"
                    (foam: E_solid = a modulus, or {calibration = "calibration.json"} relative to the scene file)
    [orientation]   kind = "uniform" | "per_tag" | "spiral" | "callable"  (only with anisotropic regions)
    [loads]         gravity = [gx, gy, gz], clamp = [facet tags] | "name", servos = true (the Tripod, flat)
    [loads.servo.NAME]                    axle_point, axle, horn, horn_length, clamp | clamp_box,
                                          setup_translation, setup_deg, range_deg
    [loads.force|traction|pressure.NAME]  group, force (N) | traction (Pa) | pressure (Pa)
    [loads.cable.NAME]                    points, tension (N), pull_point
    [loads.motion.NAME]                   group, axis, point, components
    [[steps]]       label, gravity (factor), servos = {NAME = deg} (or servo_deg), loads = {NAME = factor},
                    motions = {NAME = {angle_deg, translation}}, increments
    probes = ["tip_deflection", "center_height", "center_rotation", "KIND:GROUP" (reaction_force, displacement,
              rotation, volume)]
    [outputs]       xdmf = true, png = true | false | [step labels]

The package, in the order of the data flow:

* :mod:`~fenicsfoam.scene.table` — the key-by-key TOML reader and :class:`SceneError`;
* :mod:`~fenicsfoam.scene.kinds` — the registries of geometry builders, probe kinds and load kinds (validation and
  builder of each);
* :mod:`~fenicsfoam.scene.schema` — one reader per section, :func:`parse_scene`, :func:`load_scene` → :class:`Scene`;
* :mod:`~fenicsfoam.scene.build` — materials, mesh, orientation, motions, problem and probes (modelling choices);
* :mod:`~fenicsfoam.scene.run` — :func:`run_scene`, the load loop;
* :mod:`~fenicsfoam.scene.outputs` — :class:`SceneResult`, ``summary.json``, ``probes.csv``, XDMF, pictures;
* :mod:`~fenicsfoam.scene.vary` — :func:`vary_scene`, a parsed scene with other region values, checked.
"""

from fenicsfoam.materials import FOAM_FITS
from fenicsfoam.orientation import HANDEDNESS, spiral_directions
from fenicsfoam.scene.kinds import LOAD_KINDS, PROBE_KINDS, PROBE_UNITS, PROBES
from fenicsfoam.scene.outputs import SceneResult, StepResult
from fenicsfoam.scene.run import run_scene
from fenicsfoam.scene.schema import (
    MATERIAL_KEYS,
    ORIENTATION_KINDS,
    PETSC_PREFIX,
    Region,
    Scene,
    Step,
    load_scene,
    parse_scene,
)
from fenicsfoam.scene.table import SceneError
from fenicsfoam.scene.vary import vary_scene

__all__ = [
    "FOAM_FITS",
    "HANDEDNESS",
    "LOAD_KINDS",
    "MATERIAL_KEYS",
    "ORIENTATION_KINDS",
    "PETSC_PREFIX",
    "PROBES",
    "PROBE_KINDS",
    "PROBE_UNITS",
    "Region",
    "Scene",
    "SceneError",
    "SceneResult",
    "Step",
    "StepResult",
    "load_scene",
    "parse_scene",
    "run_scene",
    "spiral_directions",
    "vary_scene",
]
