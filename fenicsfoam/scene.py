"""TOML scene files: a robot (mesh, regions, orientation, model), its load schedule, probes and outputs.

A scene is read with the standard library's ``tomllib`` and validated key by key before anything is built:
an unknown key, a value of the wrong type, a missing value or a value out of range raises :class:`SceneError`
whose message names the key path (e.g. ``regions.arms.density``) and what would be valid. Only what the scene
declares is built (a clamp if ``loads.clamp`` is given, servo horns if ``loads.servos`` is true, gravity if
``loads.gravity`` is given, the listed probes). Every key is documented in README, "Scenes and fenicsfoam run".

Layout of a scene (SI units; servo angles in degrees)::

    name = "tripod_case_b"
    [geometry]      builder = "beam" | "tripod", and the builder's parameters (h, order, sizes),
                    or builder = "file", path = "robot.msh" (gmsh; relative to the scene file's directory)
    [fem]           model = "linear" | "svk" | "corotational", degree = 1 | 2, [fem.petsc] options
    [regions.NAME]  tags = int | [ints] | "named region", material = "isotropic" | "transverse_isotropic" | "foam"
    [orientation]   kind = "uniform" | "per_tag" | "spiral" | "callable"  (only with anisotropic regions)
    [loads]         gravity = [gx, gy, gz], clamp = [facet tags] | "name", servos = true
    [[steps]]       label, gravity (factor), servo_deg (one angle or three), increments
    probes = ["tip_deflection"] | ["center_height", "center_rotation"]
    [outputs]       xdmf = true, png = true | false | [step labels]

Modelling choices (documented, not fitted):

* *Orientation on an isotropic scene* is rejected (:class:`SceneError` naming ``orientation``): every region
  being isotropic, the isotropic energy is used and a direction field would silently do nothing, which is
  more likely a mistake in the scene (e.g. a foam fitted isotropic by accident) than an intention.
* *Servo rest angle*: 0° = the horns horizontal, the arm ends at their reference (flat-plate) position; the
  flat plate is stress-free there and gravity is applied at that rest pose. The paper's positions are
  rest = 0°, middle = 19°, top = 38° (Table I is compared as differences from rest). The real robot's
  absolute horn angle at rest is not given by the paper; 0° is the pose where the mesh is undeformed.
* *Spiral*: in-plane fibres ``d = sin p e_r + h cos p e_θ`` about the vertical axis through ``center``, with
  the pitch ``p`` the angle between fibre and circle (0°: circles, 90°: radial) and ``h = +1`` when the
  fibre traced outwards turns counter-clockwise seen from above (``handedness = "counterclockwise"``),
  ``h = −1`` for ``"clockwise"``. A mirror image (y → −y) of one handedness is the other.
* *tip_deflection* is measured along ``−ĝ`` (up): a sagging tip is negative, as Fig. 6 reports (−48 mm).
* *center_height*, *center_rotation* use the Tripod's probe ring (``meshes.tripod.RING``).
"""

from __future__ import annotations

import contextlib
import copy
import csv
import importlib
import io
import logging
import math
import os
import shutil
import tempfile
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fenicsfoam.materials import FOAM_FITS
from foambase.errors import InputError
from foambase.files import write_json_atomic, write_text_atomic

__all__ = [
    "PROBES",
    "Scene",
    "SceneError",
    "SceneResult",
    "StepResult",
    "load_scene",
    "parse_scene",
    "run_scene",
    "spiral_directions",
]

logger = logging.getLogger(__name__)

#: Probe names and what they need: a facet group named "tip" (the beam's, or a mesh file's) or the Tripod.
PROBES: dict[str, str] = {"tip_deflection": "tip", "center_height": "tripod", "center_rotation": "tripod"}
#: Units of the probe values in summaries (SI, angles in degrees).
PROBE_UNITS: dict[str, str] = {"tip_deflection": "m", "center_height": "m", "center_rotation": "deg"}
MATERIAL_KEYS: dict[str, dict[str, tuple[bool, float | None]]] = {
    # key: (required, default)
    "isotropic": {"E": (True, None), "nu": (True, None), "rho": (False, 0.0)},
    "transverse_isotropic": {"E_t": (True, None), "E_l": (True, None), "nu_t": (True, None),
                             "nu_tl": (True, None), "G_l": (True, None), "rho": (False, 0.0)},
    "foam": {"density": (True, None), "gamma": (True, None), "E_solid": (True, None), "nu_solid": (True, None),
             "rho_solid": (False, 0.0)},
}
ORIENTATION_KINDS = ("uniform", "per_tag", "spiral", "callable")
HANDEDNESS = {"counterclockwise": 1.0, "clockwise": -1.0}
#: The options prefix of every scene's SNES (command-line options: ``-scene_snes_rtol 1e-8``).
PETSC_PREFIX = "scene_"


class SceneError(InputError):
    """A scene is invalid: the message names the key path and what would be valid."""


# --------------------------------------------------------------------------------------------------
# Validation helpers
# --------------------------------------------------------------------------------------------------
def _type_name(value: Any) -> str:
    return {bool: "boolean", int: "integer", float: "float", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)


class _Table:
    """A TOML table being read: every key taken is remembered; :meth:`done` refuses the keys left over."""

    def __init__(self, data: Any, path: str):
        if not isinstance(data, dict):
            raise SceneError(f"{path or 'scene'}: expected a table, got {_type_name(data)} {data!r}")
        self.data, self.path, self._taken = data, path, set()

    def key(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = None, required: bool = False) -> Any:
        self._taken.add(key)
        if key not in self.data:
            if required:
                raise SceneError(f"{self.key(key)}: missing value (required)")
            return default
        return self.data[key]

    def number(self, key: str, *, required: bool = False, default: float | None = None,
               check: Callable[[float], bool] | None = None, valid: str = "") -> float | None:
        value = self.raw(key, default, required)
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise SceneError(f"{self.key(key)}: expected a finite number, got {_type_name(value)} {value!r}")
        if check is not None and not check(value):
            raise SceneError(f"{self.key(key)}: {value!r} is out of range; valid: {valid}")
        return float(value)

    def integer(self, key: str, *, default: int, choices: Sequence[int] | None = None, minimum: int | None = None
                ) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"{self.key(key)}: expected an integer, got {_type_name(value)} {value!r}")
        if choices is not None and value not in choices:
            raise SceneError(f"{self.key(key)}: {value!r} is not valid; valid: {', '.join(map(str, choices))}")
        if minimum is not None and value < minimum:
            raise SceneError(f"{self.key(key)}: {value!r} is out of range; valid: an integer >= {minimum}")
        return value

    def string(self, key: str, *, required: bool = False, default: str | None = None,
               choices: Sequence[str] | None = None) -> str | None:
        value = self.raw(key, default, required)
        if value is None:
            return None
        if not isinstance(value, str):
            raise SceneError(f"{self.key(key)}: expected a string, got {_type_name(value)} {value!r}")
        if choices is not None and value not in choices:
            raise SceneError(f"{self.key(key)}: {value!r} is not valid; valid: {', '.join(map(repr, choices))}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise SceneError(f"{self.key(key)}: expected true or false, got {_type_name(value)} {value!r}")
        return value

    def vector(self, key: str, size: int, *, required: bool = False, default: Sequence[float] | None = None
               ) -> tuple[float, ...] | None:
        value = self.raw(key, default, required)
        if value is None:
            return None
        return _vector(value, size, self.key(key))

    def table(self, key: str, required: bool = False) -> _Table | None:
        value = self.raw(key, None, required)
        return None if value is None else _Table(value, self.key(key))

    def done(self, allowed_extra: Sequence[str] = ()) -> None:
        unknown = sorted(set(self.data) - self._taken - set(allowed_extra))
        if unknown:
            valid = sorted(self._taken | set(allowed_extra))
            raise SceneError(f"{self.key(unknown[0])}: unknown key; valid keys here: {', '.join(valid) or 'none'}")


def _vector(value: Any, size: int, path: str) -> tuple[float, ...]:
    if (not isinstance(value, list) or len(value) != size
            or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise SceneError(f"{path}: expected an array of {size} finite numbers, got {_type_name(value)} {value!r}")
    return tuple(float(v) for v in value)


# --------------------------------------------------------------------------------------------------
# The parsed scene
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Region:
    """A material region: cell tags and either explicit constants or a foam resolved by ``foam_material``."""

    name: str
    tags: tuple[int, ...]
    material: str                     #: "isotropic" | "transverse_isotropic" | "foam"
    parameters: Mapping[str, Any]     #: the material's keyword arguments (foam: also ``fit``)


@dataclass(frozen=True)
class Step:
    """A load step of the schedule: gravity factor, horn angles (degrees), increments."""

    label: str
    gravity: float | None
    servo_deg: tuple[float, float, float] | None
    increments: int


@dataclass(frozen=True)
class Scene:
    """A validated scene (:func:`parse_scene`); ``raw`` is the scene as read."""

    raw: Mapping[str, Any]
    name: str
    builder: str
    geometry: Mapping[str, Any]       #: builder keyword arguments (h, order, sizes), or the mesh file's path
    facets: Mapping[str, tuple[int, ...]]  #: named facet groups of the mesh
    model: str
    degree: int
    petsc: Mapping[str, Any]
    regions: tuple[Region, ...]
    orientation: Mapping[str, Any] | None
    gravity: tuple[float, float, float] | None
    clamp: tuple[int, ...]
    servos: bool
    steps: tuple[Step, ...]
    probes: tuple[str, ...]
    xdmf: bool
    png: tuple[str, ...]              #: labels of the steps pictured (the orientation is pictured with any)


def _builder_info(builder: str) -> tuple[dict[str, Any], dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]:
    """Defaults of the builder's parameters, its named cell regions and named facet groups."""
    if builder == "beam":
        from meshes.beam import BEAM_VOLUME, CLAMPED_FACE, FIG6_BEAM, TIP_FACE
        return ({**FIG6_BEAM, "order": 1}, {"beam": (BEAM_VOLUME,)},
                {"clamped": (CLAMPED_FACE,), "tip": (TIP_FACE,)})
    from dataclasses import fields

    from meshes.tripod import PAPER_H, REGIONS, TripodGeometry
    defaults = {f.name: f.default for f in fields(TripodGeometry)}
    return {"h": PAPER_H, "order": 1, **defaults}, dict(REGIONS), {}


def _tags(value: Any, path: str, named: Mapping[str, tuple[int, ...]], what: str) -> tuple[int, ...]:
    """An int, a non-empty array of ints, or a name of ``named``, as a tuple of tags."""
    if isinstance(value, str):
        if value not in named:
            raise SceneError(f"{path}: unknown {what} name {value!r}; valid names: {', '.join(sorted(named))} "
                             "(or integer tags)")
        return tuple(named[value])
    if isinstance(value, int) and not isinstance(value, bool):
        return (value,)
    if isinstance(value, list) and value and all(isinstance(t, int) and not isinstance(t, bool) for t in value):
        return tuple(value)
    raise SceneError(f"{path}: expected an integer tag, an array of integer tags or a {what} name, "
                     f"got {_type_name(value)} {value!r}")


@dataclass(frozen=True)
class _Geometry:
    """The parsed ``[geometry]``: builder, its keyword arguments, named and all cell/facet tags of its mesh."""

    builder: str
    params: dict[str, Any]
    regions: dict[str, tuple[int, ...]]
    facets: dict[str, tuple[int, ...]]
    cell_tags: frozenset[int]
    facet_tags: frozenset[int]


def _parse_mesh_file(geometry: _Table, base: Path | None) -> _Geometry:
    """``builder = "file"``: a gmsh ``.msh`` file; its physical groups are read (not the mesh) to validate."""
    from meshes.msh import physical_groups

    path = Path(geometry.string("path", required=True))
    geometry.done()
    if not path.is_absolute() and base is not None:
        path = base / path
    if not path.is_file():
        raise SceneError(f"geometry.path: mesh file {str(path)!r} does not exist")
    try:
        groups = physical_groups(path)
    except ValueError as exc:
        raise SceneError(f"geometry.path: {exc}") from exc
    return _Geometry("file", {"path": path}, {n: (t,) for n, t in groups.cell_names.items()},
                     {n: (t,) for n, t in groups.facet_names.items()}, groups.cells, groups.facets)


def _parse_geometry(scene: _Table, base: Path | None) -> _Geometry:
    geometry = scene.table("geometry", required=True)
    builder = geometry.string("builder", required=True, choices=("beam", "tripod", "file"))
    if builder == "file":
        return _parse_mesh_file(geometry, base)
    defaults, regions, facets = _builder_info(builder)
    params = {}
    for key, default in defaults.items():
        if key == "order":
            params[key] = geometry.integer(key, default=default, choices=(1, 2))
        elif key == "pivot_z":
            params[key] = geometry.number(key, default=default)
        elif key == "fillet_radius":
            params[key] = geometry.number(key, default=default, check=lambda v: v >= 0, valid="a length >= 0 (m)")
        else:
            params[key] = geometry.number(key, default=default, check=lambda v: v > 0, valid="a length > 0 (m)")
    geometry.done()
    return _Geometry(builder, params, regions, facets, frozenset().union(*regions.values()),
                     frozenset().union(*facets.values()))


def _parse_region(name: str, table: _Table, named: Mapping[str, tuple[int, ...]]) -> Region:
    tags = _tags(table.raw("tags", required=True), table.key("tags"), named, "region")
    material = table.string("material", required=True, choices=tuple(MATERIAL_KEYS))
    positive = {"check": lambda v: v > 0, "valid": "a number > 0"}
    checks = {
        "E": positive, "E_t": positive, "E_l": positive, "G_l": positive, "E_solid": positive,
        "nu": {"check": lambda v: -1 < v < 0.5, "valid": "-1 < nu < 0.5"},
        "nu_solid": {"check": lambda v: -1 < v < 0.5, "valid": "-1 < nu_solid < 0.5"},
        "nu_t": {"check": lambda v: -1 < v < 1, "valid": "-1 < nu_t < 1"},
        "rho": {"check": lambda v: v >= 0, "valid": "a density >= 0 (kg/m³)"},
        "rho_solid": {"check": lambda v: v >= 0, "valid": "a density >= 0 (kg/m³)"},
        "density": {"check": lambda v: 0 < v <= 1, "valid": "a relative density in (0, 1]"},
        "gamma": {"check": lambda v: 0 < v <= 1, "valid": "an anisotropy ratio in (0, 1] (1: isotropic)"},
    }
    parameters = {key: table.number(key, required=required, default=default, **checks.get(key, {}))
                  for key, (required, default) in MATERIAL_KEYS[material].items()}
    if material == "foam":
        parameters["fit"] = table.string("fit", default="transverse", choices=FOAM_FITS)
    table.done()
    return Region(name, tags, material, parameters)


def _parse_orientation(table: _Table, named: Mapping[str, tuple[int, ...]]) -> dict[str, Any]:
    kind = table.string("kind", required=True, choices=ORIENTATION_KINDS)
    spec: dict[str, Any] = {"kind": kind}
    if kind == "uniform":
        spec["direction"] = table.vector("direction", 3, required=True)
    elif kind == "per_tag":
        directions = table.table("directions", required=True)
        spec["directions"] = {}
        for key in directions.data:
            tags = _tags(int(key) if key.lstrip("-").isdigit() else key, directions.key(key), named, "region")
            d = directions.vector(key, 3, required=True)
            spec["directions"].update(dict.fromkeys(tags, d))
        directions.done()
        spec["default"] = table.vector("default", 3)
    elif kind == "spiral":
        spec["pitch_deg"] = table.number("pitch_deg", required=True, check=lambda v: 0 <= v <= 90,
                                         valid="an angle in [0, 90] degrees (0: circles, 90: radial)")
        spec["handedness"] = table.string("handedness", required=True, choices=tuple(HANDEDNESS))
        spec["center"] = table.vector("center", 2, default=[0.0, 0.0])
    else:
        function = table.string("function", required=True)
        if function.count(":") != 1:
            raise SceneError(f"{table.key('function')}: expected 'module:function', got {function!r}")
        spec["function"] = function
    table.done()
    return spec


def _parse_step(table: _Table, servos: bool) -> Step:
    label = table.string("label", required=True)
    gravity = table.number("gravity", check=lambda v: v >= 0, valid="a load factor >= 0 (1: full gravity)")
    servo = table.raw("servo_deg")
    if servo is not None:
        if not servos:
            raise SceneError(f"{table.key('servo_deg')}: the scene has no servos; set loads.servos = true "
                             "(Tripod) or remove servo_deg")
        if isinstance(servo, int | float) and not isinstance(servo, bool) and math.isfinite(servo):
            servo = (float(servo),) * 3
        else:
            servo = _vector(servo, 3, table.key("servo_deg"))
    increments = table.integer("increments", default=1, minimum=1)
    table.done()
    return Step(label, gravity, servo, increments)


def parse_scene(data: Mapping[str, Any], base: str | os.PathLike | None = None) -> Scene:
    """Validate a scene given as a dict (as ``tomllib`` reads it) and return the :class:`Scene`.

    ``base`` is the directory a relative ``geometry.path`` refers to (:func:`load_scene` passes the scene
    file's directory; default: the current directory).

    Raises
    ------
    SceneError
        On the first problem found, naming its key path (e.g. ``regions.arms.density``) and what is valid.

    """
    scene = _Table(dict(data), "")
    name = scene.string("name", default="scene")
    scene.string("description", default="")
    parsed = _parse_geometry(scene, None if base is None else Path(base))
    builder, geometry, named_regions, named_facets = parsed.builder, parsed.params, parsed.regions, parsed.facets

    fem = scene.table("fem") or _Table({}, "fem")
    model = fem.string("model", default="corotational", choices=("linear", "svk", "corotational"))
    degree = fem.integer("degree", default=1, choices=(1, 2))
    petsc = fem.table("petsc")
    petsc_options = {}
    if petsc is not None:
        for key, value in petsc.data.items():
            if not isinstance(value, str | int | float | bool):
                raise SceneError(f"{petsc.key(key)}: expected a string, number or boolean PETSc option value, "
                                 f"got {_type_name(value)}")
            petsc_options[key] = value
    fem.done()

    regions_table = scene.table("regions", required=True)
    if not regions_table.data:
        raise SceneError("regions: at least one region is required")
    regions = tuple(_parse_region(key, regions_table.table(key), named_regions) for key in list(regions_table.data))
    regions_table.done()
    owner: dict[int, str] = {}
    for region in regions:
        for tag in region.tags:
            if tag in owner:
                raise SceneError(f"regions.{region.name}.tags: cell tag {tag} is already in region {owner[tag]!r}")
            owner[tag] = region.name
    all_tags = set(parsed.cell_tags)
    unknown = sorted(set(owner) - all_tags)
    if unknown:
        raise SceneError(f"regions.{owner[unknown[0]]}.tags: cell tag {unknown[0]} is not a tag of the {builder} "
                         f"mesh (tags: {sorted(all_tags)})")
    missing = sorted(all_tags - set(owner))
    if missing:
        raise SceneError(f"regions: cell tags {missing} of the {builder} mesh have no region (every cell needs "
                         "a material)")

    orientation_table = scene.table("orientation")
    orientation = None if orientation_table is None else _parse_orientation(orientation_table, named_regions)

    loads = scene.table("loads") or _Table({}, "loads")
    gravity = loads.vector("gravity", 3)
    clamp_value = loads.raw("clamp")
    clamp = () if clamp_value is None else _tags(clamp_value, loads.key("clamp"), named_facets, "facet group")
    servos = loads.boolean("servos", False)
    loads.done()
    if clamp and not parsed.facet_tags:
        raise SceneError(f"loads.clamp: the {builder} mesh has no facet tags to clamp")
    if servos and builder != "tripod":
        raise SceneError(f"loads.servos: servo horns need the tripod builder, not {builder!r}")
    all_facets = set(parsed.facet_tags)
    if set(clamp) - all_facets:
        raise SceneError(f"loads.clamp: facet tags {sorted(set(clamp) - all_facets)} are not facet tags of the "
                         f"{builder} mesh (facet tags: {sorted(all_facets)})")

    steps_value = scene.raw("steps", required=True)
    if not isinstance(steps_value, list) or not steps_value:
        raise SceneError(f"steps: expected a non-empty array of tables ([[steps]]), got {_type_name(steps_value)}")
    steps = tuple(_parse_step(_Table(s, f"steps[{i}]"), servos) for i, s in enumerate(steps_value))
    labels = [s.label for s in steps]
    duplicated = sorted({label for label in labels if labels.count(label) > 1})
    if duplicated:
        raise SceneError(f"steps: labels must be distinct, {duplicated[0]!r} is repeated")
    if gravity is None and any(s.gravity for s in steps):
        raise SceneError("loads.gravity: a step sets a gravity factor but the scene gives no gravity vector")

    probes_value = scene.raw("probes", default=[])
    if not isinstance(probes_value, list) or not all(isinstance(p, str) for p in probes_value):
        raise SceneError(f"probes: expected an array of probe names, got {_type_name(probes_value)} {probes_value!r}")
    for probe in probes_value:
        if probe not in PROBES:
            raise SceneError(f"probes: unknown probe {probe!r}; valid: {', '.join(PROBES)}")
        if PROBES[probe] == "tip" and "tip" not in named_facets:
            raise SceneError(f"probes: {probe!r} needs a facet group named 'tip' (the beam builder's, or a "
                             f"physical surface named tip in a mesh file); the {builder} mesh has "
                             f"{sorted(named_facets) or 'none'}")
        if PROBES[probe] == "tripod" and builder != "tripod":
            raise SceneError(f"probes: {probe!r} needs the tripod builder, the scene uses {builder!r}")
    if "tip_deflection" in probes_value and gravity is None:
        raise SceneError("probes: 'tip_deflection' is measured along gravity; give loads.gravity")

    outputs = scene.table("outputs") or _Table({}, "outputs")
    xdmf = outputs.boolean("xdmf", True)
    png_value = outputs.raw("png", True)
    if isinstance(png_value, bool):
        png = labels if png_value else []
    elif isinstance(png_value, list) and all(label in labels for label in png_value):
        png = list(png_value)
    else:
        raise SceneError(f"outputs.png: expected true, false or an array of step labels ({labels}), "
                         f"got {_type_name(png_value)} {png_value!r}")
    outputs.done()
    scene.done()
    return Scene(raw=copy.deepcopy(dict(data)), name=name, builder=builder, geometry=geometry,
                 facets=named_facets, model=model,
                 degree=degree, petsc=petsc_options, regions=regions, orientation=orientation, gravity=gravity,
                 clamp=clamp, servos=servos, steps=steps, probes=tuple(dict.fromkeys(probes_value)), xdmf=xdmf,
                 png=tuple(png))


def load_scene(source: str | os.PathLike | Mapping[str, Any]) -> Scene:
    """Read and validate a scene from a TOML file (path) or a dict; :class:`SceneError` names the problem."""
    if isinstance(source, Mapping):
        return parse_scene(source)
    path = Path(source)
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:  # the message gives line and column
        raise SceneError(f"{path}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise SceneError(f"cannot read scene {path}: {exc}") from exc
    try:
        return parse_scene(data, base=path.parent)
    except SceneError as exc:
        raise SceneError(f"{path}: {exc}") from exc


# --------------------------------------------------------------------------------------------------
# Building the model
# --------------------------------------------------------------------------------------------------
def spiral_directions(points: np.ndarray, pitch_deg: float, handedness: str,
                      center: Sequence[float] = (0.0, 0.0)) -> np.ndarray:
    """In-plane spiral fibre directions at ``points`` (n, 3): ``d = sin p e_r + h cos p e_θ``.

    ``e_r`` is the horizontal unit vector from the vertical axis through ``center`` to the point,
    ``e_θ = e_z × e_r``, ``p`` the pitch angle (0: circles, 90°: radial), and ``h = +1`` for
    ``"counterclockwise"`` (the fibre traced outwards turns counter-clockwise seen from +z), ``-1`` for
    ``"clockwise"``. Points on the axis get a zero vector (refused by the orientation builders).
    """
    h = HANDEDNESS[handedness]
    p = math.radians(pitch_deg)
    r = np.asarray(points, dtype=float)[:, :2] - np.asarray(center, dtype=float)
    norm = np.linalg.norm(r, axis=1, keepdims=True)
    e_r = np.divide(r, norm, out=np.zeros_like(r), where=norm > 0)
    e_theta = np.column_stack([-e_r[:, 1], e_r[:, 0]])
    d = math.sin(p) * e_r + h * math.cos(p) * e_theta
    return np.column_stack([d, np.zeros(len(d))])


def _resolve_material(region: Region):
    """The :mod:`fenicsfoam.materials` object of a region (foam: through ``foam_material``, imported lazily)."""
    from fenicsfoam.materials import Isotropic, TransverseIsotropic
    from homogenization.tensors import InadmissibleMaterialError
    path = f"regions.{region.name}"
    try:
        if region.material == "isotropic":
            return Isotropic(**region.parameters)
        if region.material == "transverse_isotropic":
            return TransverseIsotropic(**region.parameters)
        try:
            from fenicsfoam.materials import foam_material
        except ImportError as exc:
            raise SceneError(f"{path}: foam regions need fenicsfoam.materials.foam_material (the homogenized "
                             "tables), which this installation lacks; use explicit constants") from exc
        params = dict(region.parameters)
        return foam_material(params.pop("density"), params.pop("gamma"), params.pop("E_solid"),
                             params.pop("nu_solid"), **params)
    except (InadmissibleMaterialError, ValueError) as exc:
        if isinstance(exc, SceneError):
            raise
        raise SceneError(f"{path}: {exc}") from exc


def _material_record(material) -> dict[str, Any]:
    from dataclasses import asdict
    return {"type": type(material).__name__, **asdict(material)}


def _import_callable(spec: str) -> Callable[[np.ndarray], np.ndarray]:
    module, _, name = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise SceneError(f"orientation.function: cannot import {spec!r}: {exc}") from exc


def _check_orientation(scene: Scene, materials: Mapping[str, Any]) -> None:
    """An orientation is required with a TI region and refused when every region is isotropic."""
    from fenicsfoam.materials import Isotropic
    anisotropic = [name for name, m in materials.items() if not isinstance(m, Isotropic)]
    if not anisotropic and scene.orientation is not None:
        raise SceneError("orientation: every region is isotropic, so an orientation field would have no effect; "
                         "remove the [orientation] table (or make a region anisotropic)")
    if anisotropic and scene.orientation is None:
        raise SceneError(f"orientation: missing; the transversely isotropic region(s) {', '.join(anisotropic)} "
                         "need an [orientation] table (kind = uniform, per_tag, spiral or callable)")
    if scene.orientation is not None and scene.orientation["kind"] == "callable":
        _import_callable(scene.orientation["function"])


def _build_orientation(scene: Scene, mesh, cell_tags):
    """The DG0 l-axis field the scene declares (None for an isotropic scene)."""
    from fenicsfoam import orientation as orient
    spec = scene.orientation
    if spec is None:
        return None
    try:
        if spec["kind"] == "uniform":
            return orient.uniform(mesh, spec["direction"])
        if spec["kind"] == "per_tag":
            return orient.per_tag(mesh, cell_tags, spec["directions"], default=spec["default"])
        if spec["kind"] == "spiral":
            return orient.from_callable(mesh, lambda x: spiral_directions(x, spec["pitch_deg"], spec["handedness"],
                                                                          spec["center"]))
        return orient.from_callable(mesh, _import_callable(spec["function"]))
    except orient.OrientationError as exc:
        raise SceneError(f"orientation: {exc}") from exc


@dataclass
class _Model:
    """What a scene builds: the mesh, the problem, the probes, the load steps."""

    tagged: Any
    problem: Any
    orientation: Any
    probes: dict[str, Callable]
    steps: list
    materials: dict[str, dict]


def _build(scene: Scene, comm) -> _Model:
    from fenicsfoam.bcs import RigidMotion
    from fenicsfoam.constitutive import MaterialField
    from fenicsfoam.probes import CenterHeight, CenterRotation, TipDeflection
    from fenicsfoam.solver import ElasticityProblem, LoadStep

    resolved = {region.name: _resolve_material(region) for region in scene.regions}  # before meshing: fail fast
    _check_orientation(scene, resolved)
    params = dict(scene.geometry)
    if scene.builder == "file":
        from meshes.msh import read_msh
        tagged = read_msh(comm, params["path"])
    elif scene.builder == "beam":
        from meshes.beam import make_beam
        tagged = make_beam(comm, **params)
    else:
        from meshes.tripod import ARM_END, RING, TripodGeometry, make_tripod
        h, order = params.pop("h"), params.pop("order")
        try:
            geometry = TripodGeometry(**params)
        except ValueError as exc:
            raise SceneError(f"geometry: {exc}") from exc
        tagged = make_tripod(comm, h, geometry, order)
    mesh, cell_tags = tagged.mesh, tagged.cell_tags
    materials = {tag: resolved[region.name] for region in scene.regions for tag in region.tags}
    field = MaterialField.from_regions(mesh, cell_tags, materials)
    a = _build_orientation(scene, mesh, cell_tags)

    motions = []
    if scene.clamp:
        facets = np.concatenate([tagged.facet_tags.find(t) for t in scene.clamp])
        motions.append(RigidMotion("clamp", facets))
    if scene.servos:
        for i, frame in enumerate(tagged.geometry.servo_frames()):
            motions.append(RigidMotion(f"servo{i}", cell_tags.find(ARM_END[i]), dim=mesh.topology.dim,
                                       axis=tuple(frame.axis), point=tuple(frame.pivot)))
    gravity = (0.0, 0.0, 0.0) if scene.gravity is None else scene.gravity
    problem = ElasticityProblem(mesh, field, orientation=a, model=scene.model, degree=scene.degree,
                                gravity=gravity, motions=motions, prefix=PETSC_PREFIX, options=dict(scene.petsc))
    V = problem.V
    builders = {
        "tip_deflection": lambda: TipDeflection(V, tagged.facet_tags, scene.facets["tip"][0],
                                                -np.asarray(gravity)),
        "center_height": lambda: CenterHeight(V, cell_tags, RING),
        "center_rotation": lambda: CenterRotation(V, cell_tags, RING),
    }
    probes = {name: builders[name]() for name in scene.probes}
    steps = [LoadStep(s.label, gravity=s.gravity, increments=s.increments,
                      angles={} if s.servo_deg is None else
                      {f"servo{i}": math.radians(angle) for i, angle in enumerate(s.servo_deg)})
             for s in scene.steps]
    return _Model(tagged, problem, a, probes, steps,
                  {region.name: _material_record(resolved[region.name]) for region in scene.regions})


# --------------------------------------------------------------------------------------------------
# Results and outputs
# --------------------------------------------------------------------------------------------------
@dataclass
class StepResult:
    """One load step: probe values (SI, angles in degrees) and solver statistics."""

    label: str
    probes: dict[str, float]
    newton_iterations: int
    increments: int
    cutbacks: int
    min_det_F: float
    wall_s: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the ``steps`` entries of ``summary.json``)."""
        return dict(self.__dict__)


@dataclass
class SceneResult:
    """The outcome of :func:`run_scene`; :meth:`summary` is ``summary.json``, :meth:`table` a printable table."""

    scene: Scene
    steps: list[StepResult] = field(default_factory=list)
    n_cells: int = 0
    n_dofs: int = 0
    n_ranks: int = 1
    wall_s: float = 0.0
    materials: dict[str, dict] = field(default_factory=dict)
    error: str | None = None
    #: when a step failed: its label, the load factor reached and the strong-ellipticity check there
    failure: dict[str, Any] | None = None
    out_dir: Path | None = None

    def probe(self, name: str, relative_to: str | None = None) -> dict[str, float]:
        """``{step label: value}`` of a probe, minus its value at step ``relative_to`` if given."""
        values = {s.label: s.probes[name] for s in self.steps}
        base = 0.0 if relative_to is None else values[relative_to]
        return {label: v - base for label, v in values.items()}

    def summary(self) -> dict[str, Any]:
        """The ``summary.json`` content (DESIGN.md contract, plus materials and solver statistics)."""
        return {"scene": dict(self.scene.raw), "steps": [s.to_dict() for s in self.steps], "wall_s": self.wall_s,
                "n_cells": self.n_cells, "n_dofs": self.n_dofs, "n_ranks": self.n_ranks,
                "probe_units": {p: PROBE_UNITS[p] for p in self.scene.probes}, "materials": self.materials,
                "model": self.scene.model, "degree": self.scene.degree, "error": self.error,
                "failure": self.failure}

    def table(self) -> str:
        """Probes per step (lengths in mm, angles in degrees), Newton iterations and wall time."""
        scale = {"m": 1e3, "deg": 1.0}
        unit = {"m": "mm", "deg": "deg"}
        names = list(self.scene.probes)
        head = f"{'step':>10s} " + " ".join(f"{n + ' (' + unit[PROBE_UNITS[n]] + ')':>22s}" for n in names)
        lines = [f"scene {self.scene.name}: {self.n_cells} cells, {self.n_dofs} dofs, {self.n_ranks} rank(s), "
                 f"{self.wall_s:.1f} s", head + f" {'Newton':>7s} {'wall (s)':>9s}"]
        for s in self.steps:
            values = " ".join(f"{s.probes[n] * scale[PROBE_UNITS[n]]:22.4f}" for n in names)
            lines.append(f"{s.label:>10s} {values} {s.newton_iterations:7d} {s.wall_s:9.2f}")
        if self.error:
            lines.append(f"FAILED: {self.error}")
        return "\n".join(lines)


def _probes_csv(result: SceneResult) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["step", *(f"{p}_{PROBE_UNITS[p]}" for p in result.scene.probes), "newton_iterations", "wall_s"])
    for s in result.steps:
        writer.writerow([s.label, *(repr(s.probes[p]) for p in result.scene.probes), s.newton_iterations,
                         repr(s.wall_s)])
    return buffer.getvalue()


class _XdmfSeries:
    """``solution.xdmf`` (+ ``.h5``): the mesh once, the displacement per step (time = step index).

    Written in a temporary directory inside the output directory (the XDMF refers to its HDF5 file by name)
    and moved into place by :meth:`commit` (rank 0, ``os.replace``, the HDF5 file first).
    """

    def __init__(self, comm, out_dir: Path, mesh):
        from dolfinx.io import XDMFFile
        self._comm, self._out = comm, out_dir
        tmp = comm.bcast(tempfile.mkdtemp(dir=out_dir, prefix=".solution.") if comm.rank == 0 else None, root=0)
        self._tmp = Path(tmp)
        self._file = XDMFFile(comm, str(self._tmp / "solution.xdmf"), "w")
        self._file.write_mesh(mesh)

    def write(self, u, t: float) -> None:
        self._file.write_function(u, t)

    def commit(self) -> None:
        self._file.close()
        self._comm.Barrier()
        if self._comm.rank == 0:
            os.replace(self._tmp / "solution.h5", self._out / "solution.h5")
            os.replace(self._tmp / "solution.xdmf", self._out / "solution.xdmf")
            shutil.rmtree(self._tmp, ignore_errors=True)
        self._comm.Barrier()

    def abort(self) -> None:
        with contextlib.suppress(Exception):
            self._file.close()
        if self._comm.rank == 0:
            shutil.rmtree(self._tmp, ignore_errors=True)


def run_scene(source: str | os.PathLike | Mapping[str, Any] | Scene, out_dir: str | os.PathLike | None = None, *,
              comm=None) -> SceneResult:
    """Build a scene, run its load schedule, evaluate its probes after every step and write its outputs.

    Parameters
    ----------
    source
        A TOML file, a dict as ``tomllib`` reads one, or a parsed :class:`Scene`.
    out_dir
        Where to write ``summary.json``, ``probes.csv``, ``solution.xdmf`` (+ ``.h5``) and the PNG pictures
        (``<step>.png``, and ``orientation.png`` for anisotropic scenes); ``None`` writes nothing. Every file
        is written atomically, the text and pictures on rank 0 only.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).

    Returns
    -------
    SceneResult
        Steps with probe values (SI, angles in degrees) and Newton statistics, sizes and timings;
        ``result.table()`` prints them.

    Raises
    ------
    SceneError
        Invalid scene (nothing is built).
    fenicsfoam.solver.ConvergenceError
        A load step failed; the outputs of the steps done (and ``error`` in the summary) are written first.

    """
    from mpi4py import MPI

    from fenicsfoam.solver import ConvergenceError
    comm = MPI.COMM_WORLD if comm is None else comm
    start = time.perf_counter()
    scene = source if isinstance(source, Scene) else load_scene(source)
    model = _build(scene, comm)
    problem = model.problem
    result = SceneResult(scene, n_cells=model.tagged.n_cells, n_ranks=comm.size,
                         n_dofs=problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
                         materials=model.materials)
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        if comm.rank == 0:
            out.mkdir(parents=True, exist_ok=True)
        comm.Barrier()
    series = _XdmfSeries(comm, out, problem.V.mesh) if out is not None and scene.xdmf else None
    pictures = scene.png if out is not None else ()
    failure = None
    try:
        for index, step in enumerate(model.steps):
            try:
                stats = problem.solve_step(step)
            except ConvergenceError as exc:
                failure = exc
                result.error = str(exc)
                result.failure = {"step": exc.step, "load_factor": exc.load_factor, "reason": exc.reason,
                                  "ellipticity": None if exc.ellipticity is None else exc.ellipticity.to_dict()}
                break
            result.steps.append(StepResult(step.label, {n: float(p(problem.u)) for n, p in model.probes.items()},
                                           stats.newton_iterations, stats.increments, stats.cutbacks,
                                           stats.min_det_F, stats.wall_s))
            logger.info("scene %s, step %s: %s", scene.name, step.label, result.steps[-1].probes)
            if series is not None:
                series.write(problem.u, float(index))
            if step.label in pictures:
                from fenicsfoam.plotting import plot_displacement
                plot_displacement(problem.u, out / f"{step.label}.png", title=f"{scene.name}: {step.label}")
    except BaseException:
        if series is not None:
            series.abort()
        raise
    if series is not None:
        series.commit()
    if pictures and model.orientation is not None:
        from fenicsfoam.plotting import plot_orientation
        plot_orientation(model.orientation, out / "orientation.png", title=f"{scene.name}: l axis")
    result.wall_s = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    result.out_dir = out
    if out is not None and comm.rank == 0:
        write_json_atomic(out / "summary.json", result.summary())
        write_text_atomic(out / "probes.csv", _probes_csv(result))
    if failure is not None:
        raise failure
    return result
