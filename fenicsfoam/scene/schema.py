"""A scene's schema: the TOML read section by section and validated into a :class:`Scene` before anything is built.

:func:`parse_scene` reads the sections in the order of the file's layout (``[geometry]``, ``[fem]``,
``[regions.*]``, ``[[blends]]``, ``[orientation]``, ``[loads]`` (with ``[contacts.*]``), ``[[steps]]``, ``probes``,
``[outputs]``), one reader each; the
first problem raises :class:`~fenicsfoam.scene.table.SceneError` naming its key path. Probes and load keys are
validated by their entries in :mod:`fenicsfoam.scene.kinds`.
"""

from __future__ import annotations

import copy
import math
import os
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fenicsfoam.material.kinds import GRADED_KEYS, MATERIAL_KINDS, tabulated_regions
from fenicsfoam.orientation import HANDEDNESS
from fenicsfoam.scene.kinds import (
    GEOMETRY_KINDS,
    GROUP_PROBE_KINDS,
    LOAD_KINDS,
    PROBE_KINDS,
    MeshInfo,
    tripod_flat_servos,
)
from fenicsfoam.scene.table import KNOWN_KEYS, SceneError, _Table, _tags, _type_name, _vector
from foambase.errors import InputError
from foambase.files import check_input_file

__all__ = ["LABEL_PATTERN", "RESERVED_NAMES", "Region", "Scene", "Step", "load_scene", "parse_scene"]

#: Per material kind (:data:`fenicsfoam.material.MATERIAL_KINDS`): its numeric keys, ``key: (required, default)``.
MATERIAL_KEYS: dict[str, dict[str, tuple[bool, float | None]]] = {
    name: {k.name: (k.required, k.default) for k in kind.keys if k.form in ("number", "field", "modulus")}
    for name, kind in MATERIAL_KINDS.items()}
KNOWN_KEYS.update(k.name for kind in MATERIAL_KINDS.values() for k in kind.keys)  # never taken for typos
#: Range checks of the material constants (the material classes check admissibility again).
MATERIAL_CHECKS: dict[str, dict[str, Any]] = {k.name: {"check": k.check, "valid": k.valid}
                                              for kind in MATERIAL_KINDS.values() for k in kind.keys if k.check}
ORIENTATION_KINDS = ("uniform", "per_tag", "spiral", "callable")
#: The options prefix of every scene's SNES (command-line options: ``-scene_snes_rtol 1e-8``).
PETSC_PREFIX = "scene_"
#: Step labels name output files (``<label>.png``), so they are safe file names on every platform: ASCII letters,
#: digits, ``_``, ``-`` and ``.``, starting with a letter or a digit, at most 64 characters.
LABEL_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
#: The longest scene ``name`` (it titles pictures and the progress bar).
MAX_NAME = 200
#: The largest scene file read (a scene is a page of text; anything larger is not one).
MAX_SCENE_BYTES = 16 << 20
#: The most load increments a step may ask for (each is at least one Newton solve; more is a typo, not a plan).
MAX_INCREMENTS = 10_000
#: Names of a run's fixed outputs (``summary.json``, ``probes.csv``, ``solution.pvd``, ``orientation.png``,
#: ``run.log``): no step label may take one (compared without case, as case-insensitive file systems do).
RESERVED_NAMES = ("summary", "probes", "solution", "orientation", "run")


# --------------------------------------------------------------------------------------------------
# The parsed scene
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Region:
    """A material region: cell tags and either explicit constants or a foam resolved by ``foam_material``."""

    name: str
    tags: tuple[int, ...]
    material: str                     #: the kind, a key of :data:`fenicsfoam.material.MATERIAL_KINDS`
    parameters: Mapping[str, Any]     #: the values of the kind's keys (foam: also ``fit``, and ``table`` if given)


@dataclass(frozen=True)
class Step:
    """A load step of the schedule: gravity factor, increments, load factors, motions, servo angles."""

    label: str
    gravity: float | None
    increments: int
    loads: Mapping[str, float] = field(default_factory=dict)   #: factor per named load and per contact
    #: per named motion: ``{"angle_deg": float, "translation": (tx, ty, tz)}`` (either may be absent)
    motions: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    #: per servo actuator: its horn's angle from rest (deg); servos not listed keep theirs
    servos: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Scene:
    """A validated scene (:func:`parse_scene`); ``raw`` is the scene as read."""

    raw: Mapping[str, Any]
    name: str
    builder: str
    geometry: Mapping[str, Any]       #: builder keyword arguments (h, order, sizes), or the mesh file's path
    facets: Mapping[str, tuple[int, ...]]  #: named facet groups of the mesh
    model: str                        #: name of the constitutive model (``fenicsfoam.constitutive.MODELS``)
    degree: int
    petsc: Mapping[str, Any]
    regions: tuple[Region, ...]
    orientation: Mapping[str, Any] | None
    loads: Mapping[str, Any]          #: the value of every load kind (:data:`fenicsfoam.scene.kinds.LOAD_KINDS`)
    steps: tuple[Step, ...]
    probes: tuple[str, ...]
    xdmf: bool
    png: tuple[str, ...]              #: labels of the steps pictured (the orientation is pictured with any)
    #: the group (:class:`fenicsfoam.scene.kinds.Group`) of each ``"KIND:GROUP"`` probe
    probe_groups: Mapping[str, Any] = field(default_factory=dict)
    blends: tuple[Mapping[str, Any], ...] = ()  #: ``{"regions": (A, B), "width": w}`` between foam regions

    @property
    def graded(self) -> bool:
        """Whether some foam region's density or γ is a field (per tag, a function, or blended)."""
        return bool(self.blends) or any(isinstance(r.parameters.get(k), dict) for r in self.regions
                                        for k in GRADED_KEYS)

    @property
    def gravity(self) -> tuple[float, float, float] | None:
        """The full gravity vector (m/s²), or ``None``."""
        return self.loads["gravity"]

    @property
    def clamp(self) -> tuple[int, ...]:
        """Facet tags held fixed."""
        return self.loads["clamp"]

    @property
    def servos(self) -> Mapping[str, Mapping[str, Any]]:
        """The servo actuators by name (``[loads.servo.NAME]``, or the Tripod's three of ``loads.servos = true``)."""
        return self.loads["servo"]


# --------------------------------------------------------------------------------------------------
# Section readers
# --------------------------------------------------------------------------------------------------
def _read_geometry(scene: _Table, base: Path | None) -> MeshInfo:
    """``[geometry]``: the builder (:data:`~fenicsfoam.scene.kinds.GEOMETRY_KINDS`) reads and checks its keys."""
    geometry = scene.table("geometry", required=True)
    builder = geometry.string("builder", required=True, choices=tuple(GEOMETRY_KINDS))
    return GEOMETRY_KINDS[builder].info(builder, geometry, base)


def _read_fem(scene: _Table) -> tuple[str, int, dict[str, Any]]:
    """``[fem]``: model name, degree and PETSc options."""
    from fenicsfoam.constitutive import MODELS

    fem = scene.table("fem") or _Table({}, "fem")
    model = fem.string("model", default="corotational", choices=tuple(MODELS))
    degree = fem.integer("degree", default=2, choices=(1, 2))
    petsc = fem.table("petsc")
    options = {}
    if petsc is not None:
        for key, value in petsc.data.items():
            if not isinstance(value, str | int | float | bool):
                raise SceneError(f"{petsc.key(key)}: expected a string, number or boolean PETSc option value, "
                                 f"got {_type_name(value)}")
            options[key] = value
    fem.done()
    return model, degree, options


def _calibrated_E_solid(name: str, region: _Table, base: Path | None, table: str | None) -> float:
    """A foam region's ``E_solid = {calibration = "path"}``: the modulus of a ``calibration.json``.

    The file must have been calibrated through the region's foam ``table`` (``None``: the default table,
    ``homogenization.tables.DEFAULT_TABLE``), :func:`fenicsfoam.scene.calibration.check_calibration_table`.
    """
    from fenicsfoam.scene.calibration import CalibrationError, check_calibration_table, read_calibration

    spec = region.table("E_solid")
    path = Path(spec.string("calibration", required=True))
    spec.done()
    if not path.is_absolute() and base is not None:
        path = base / path
    try:
        E_solid = read_calibration(path)
        check_calibration_table(path, table, name)
    except CalibrationError as exc:
        raise SceneError(f"{spec.key('calibration')}: {exc}") from exc
    return E_solid


def _foam_table_name(region: _Table, base: Path | None) -> str:
    """A foam region's ``table``: a shipped table's name, or a ``.csv`` path (relative to the scene file)."""
    from homogenization.tables import shipped_tables

    value = region.string("table")
    if value.endswith(".csv"):
        path = Path(value)
        path = path if path.is_absolute() or base is None else base / path
        if not path.is_file():
            raise SceneError(f"{region.key('table')}: no foam table file {str(path)!r}")
        return str(path)
    if value not in shipped_tables():
        raise SceneError(f"{region.key('table')}: {value!r} is not a shipped foam table {shipped_tables()} nor a "
                         ".csv path")
    return value


def _read_field(table: _Table, key: str, tags: tuple[int, ...], named: Mapping[str, tuple[int, ...]]):
    """A foam's ``density`` or ``gamma``: a number, a per-tag table or a function (:mod:`fenicsfoam.grading`).

    TOML: ``density = 0.3``, ``density = {per_tag = {arm0 = 0.3, arm1 = 0.25}}`` or
    ``density = {function = "module:name"}``.
    """
    checks = MATERIAL_CHECKS[key]
    if not isinstance(table.raw(key, required=True), dict):
        return table.number(key, required=True, **checks)
    spec = table.table(key)
    if spec.has("function"):
        function = spec.string("function", required=True)
        if function.count(":") != 1:
            raise SceneError(f"{spec.key('function')}: expected 'module:function', got {function!r}")
        spec.done()
        return {"function": function}
    per_tag = spec.table("per_tag")
    if per_tag is None:
        raise SceneError(f"{spec.path}: expected a number, {{per_tag = {{...}}}} or {{function = \"module:name\"}}")
    spec.done()
    values: dict[int, float] = {}
    for name in per_tag.data:
        keys = _tags(_tag_key(name), per_tag.key(name), named, "region")
        value = per_tag.number(name, required=True, **checks)
        for tag in keys:
            if tag not in tags:
                raise SceneError(f"{per_tag.key(name)}: cell tag {tag} is not a tag of this region (tags {list(tags)})")
            values[tag] = value
    per_tag.done()
    missing = sorted(set(tags) - set(values))
    if missing:
        raise SceneError(f"{per_tag.path}: cell tags {missing} of the region have no value")
    return {"per_tag": values}


def _read_region(name: str, table: _Table, named: Mapping[str, tuple[int, ...]], base: Path | None = None
                 ) -> Region:
    """A region: its tags, its kind (:data:`~fenicsfoam.material.MATERIAL_KINDS`) and the kind's keys.

    Each key is read in its form: a number, a field, a modulus or its calibration, a choice, a foam table.
    """
    tags = _tags(table.raw("tags", required=True), table.key("tags"), named, "region")
    kind = MATERIAL_KINDS[table.string("material", required=True, choices=tuple(MATERIAL_KINDS))]
    forms = {k.form: k.name for k in kind.keys}
    foam_table = _foam_table_name(table, base) if "table" in forms and forms["table"] in table.data else None
    parameters = {}
    for key in kind.keys:
        checks = {"check": key.check, "valid": key.valid} if key.check else {}
        if key.form == "modulus" and isinstance(table.data.get(key.name), dict):
            parameters[key.name] = _calibrated_E_solid(name, table, base, foam_table)
        elif key.form == "field":
            parameters[key.name] = _read_field(table, key.name, tags, named)
        elif key.form in ("number", "modulus"):
            parameters[key.name] = table.number(key.name, required=key.required, default=key.default, **checks)
        elif key.form == "choice":
            parameters[key.name] = table.string(key.name, default=key.default, choices=key.choices)
        elif foam_table is not None:
            parameters[key.name] = foam_table
    table.done()
    return Region(name, tags, kind.name, parameters)


def _read_regions(scene: _Table, mesh: MeshInfo, base: Path | None = None) -> tuple[Region, ...]:
    """``[regions.NAME]``: every cell tag of the mesh in exactly one region (``base``: calibration files)."""
    table = scene.table("regions", required=True)
    if not table.data:
        raise SceneError("regions: at least one region is required")
    regions = tuple(_read_region(key, table.table(key), mesh.regions, base) for key in list(table.data))
    table.done()
    owner: dict[int, str] = {}
    for region in regions:
        for tag in region.tags:
            if tag in owner:
                raise SceneError(f"regions.{region.name}.tags: cell tag {tag} is already in region {owner[tag]!r}")
            owner[tag] = region.name
    all_tags = set(mesh.cell_tags)
    unknown = sorted(set(owner) - all_tags)
    if unknown:
        raise SceneError(f"regions.{owner[unknown[0]]}.tags: cell tag {unknown[0]} is not a tag of the "
                         f"{mesh.builder} mesh (tags: {sorted(all_tags)})")
    missing = sorted(all_tags - set(owner))
    if missing:
        raise SceneError(f"regions: cell tags {missing} of the {mesh.builder} mesh have no region (every cell needs "
                         "a material)")
    return regions


def _tag_key(key: str) -> int | str:
    """A per-tag table's key: an integer cell tag if it is written in ASCII digits, else a region name."""
    return int(key) if re.fullmatch(r"-?[0-9]+", key) else key


def _direction(table: _Table, key: str, required: bool = False) -> tuple[float, ...] | None:
    """A direction: 3 finite numbers, not all zero (:class:`SceneError` naming the key)."""
    value = table.vector(key, 3, required=required)
    if value is not None and not any(value):
        raise SceneError(f"{table.key(key)}: a direction must be a non-zero vector, got {list(value)}")
    return value


def _read_orientation(scene: _Table, mesh: MeshInfo) -> dict[str, Any] | None:
    """``[orientation]`` (optional): the kind and its parameters."""
    table = scene.table("orientation")
    if table is None:
        return None
    kind = table.string("kind", required=True, choices=ORIENTATION_KINDS)
    spec: dict[str, Any] = {"kind": kind}
    if kind == "uniform":
        spec["direction"] = _direction(table, "direction", required=True)
    elif kind == "per_tag":
        directions = table.table("directions", required=True)
        spec["directions"] = {}
        for key in directions.data:
            tags = _tags(_tag_key(key), directions.key(key), mesh.regions, "region")
            d = _direction(directions, key, required=True)
            spec["directions"].update(dict.fromkeys(tags, d))
        directions.done()
        spec["default"] = _direction(table, "default")
        if spec["default"] is not None and mesh.cell_tags and set(mesh.cell_tags) <= set(spec["directions"]):
            raise SceneError(f"{table.key('default')}: every cell tag of the mesh ({sorted(mesh.cell_tags)}) has a "
                             "direction, so the default would never be used; remove it")
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
    spec["offset_deg"] = table.number("offset_deg", default=0.0)
    table.done()
    return spec


def _read_blends(scene: _Table, regions: tuple[Region, ...]) -> tuple[dict[str, Any], ...]:
    """``[[blends]]`` (optional): ``regions = [A, B]`` (two foam regions, density and γ numbers), ``width`` (m)."""
    value = scene.raw("blends", default=[])
    if not isinstance(value, list):
        raise SceneError(f"blends: expected an array of tables ([[blends]]), got {_type_name(value)}")
    by_name = {r.name: r for r in regions}
    blends, used = [], set()
    for i, item in enumerate(value):
        table = _Table(item, f"blends[{i}]")
        pair = table.raw("regions", required=True)
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(n, str) for n in pair)
                and pair[0] != pair[1]):
            raise SceneError(f"{table.key('regions')}: expected two distinct region names, got {pair!r}")
        for name in pair:
            region = by_name.get(name)
            if region is None or not MATERIAL_KINDS[region.material].tabulated:
                raise SceneError(f"{table.key('regions')}: {name!r} is not a foam region "
                                 f"(foam regions: {sorted(r.name for r in tabulated_regions(regions))})")
            for key in GRADED_KEYS:
                if isinstance(region.parameters[key], dict):
                    raise SceneError(f"{table.key('regions')}: region {name!r} gives {key} as a field; a blend "
                                     "mixes two regions whose density and gamma are numbers")
            if name in used:
                raise SceneError(f"{table.key('regions')}: region {name!r} is already in a blend")
            used.add(name)
        width = table.number("width", required=True, check=lambda v: v >= 0, valid="a length >= 0 (m)")
        table.done()
        blends.append({"regions": tuple(pair), "width": width})
    return tuple(blends)


def _read_loads(scene: _Table, mesh: MeshInfo) -> dict[str, Any]:
    """``[loads]``: one value per load kind (:data:`~fenicsfoam.scene.kinds.LOAD_KINDS`); named loads distinct."""
    table = scene.table("loads") or _Table({}, "loads")
    loads = {key: kind.read(table, key, mesh) if kind.section is None else kind.read(scene, kind.section, mesh)
             for key, kind in LOAD_KINDS.items()}
    table.done()
    if loads["servos"]:
        loads["servo"] = tripod_flat_servos(mesh.params)
    seen: dict[str, str] = {}
    for key in [*(k for k, kind in LOAD_KINDS.items() if kind.named), "motion", "servo"]:
        path = LOAD_KINDS[key].section or f"loads.{key}"
        for name in loads[key]:
            if name in seen:
                raise SceneError(f"{path}.{name}: the name {name!r} is already used by {seen[name]}.{name} "
                                 "(the steps refer to loads, contacts and motions by name)")
            seen[name] = path
    return loads


def _named_loads(loads: Mapping[str, Any]) -> dict[str, str]:
    """Name → kind of every load the steps scale (``loads = {NAME = factor}``)."""
    return {name: key for key, kind in LOAD_KINDS.items() if kind.named and kind.section is None
            for name in loads[key]}


def _read_step_contacts(table: _Table, loads: Mapping[str, Any]) -> dict[str, float]:
    """``contacts = {NAME = factor}``: the obstacles' positions, ``factor × motion`` from where they were declared."""
    factors = table.table("contacts")
    if factors is None:
        return {}
    declared = loads.get("contact") or {}
    result = {}
    for name in factors.data:
        if name not in declared:
            raise SceneError(f"{factors.key(name)}: no contact named {name!r}; declared contacts: "
                             f"{', '.join(sorted(declared)) or 'none'} ([contacts.NAME])")
        result[name] = factors.number(name)
    factors.done()
    return result


def _read_step_loads(table: _Table, loads: Mapping[str, Any]) -> dict[str, float]:
    """``loads = {NAME = factor}``: factors of named loads (a cable's ≥ 0)."""
    factors = table.table("loads")
    if factors is None:
        return {}
    named = _named_loads(loads)
    result = {}
    for name in factors.data:
        if name not in named:
            raise SceneError(f"{factors.key(name)}: no load named {name!r}; declared loads: "
                             f"{', '.join(sorted(named)) or 'none'} ([loads.force|traction|pressure|cable.NAME])")
        if named[name] == "cable":
            result[name] = factors.number(name, check=lambda v: v >= 0,
                                          valid="a factor >= 0 of the cable's tension (a cable cannot push)")
        else:
            result[name] = factors.number(name)
    factors.done()
    return result


def _read_step_motions(table: _Table, loads: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """``motions = {NAME = {angle_deg = a, translation = [tx, ty, tz]}}`` of named motions."""
    motions = table.table("motions")
    if motions is None:
        return {}
    result = {}
    for name in list(motions.data):
        if name not in loads["motion"]:
            raise SceneError(f"{motions.key(name)}: no motion named {name!r}; declared motions: "
                             f"{', '.join(sorted(loads['motion'])) or 'none'} ([loads.motion.NAME])")
        motion = motions.table(name)
        values = {"angle_deg": motion.number("angle_deg"), "translation": motion.vector("translation", 3)}
        motion.done()
        result[name] = {k: v for k, v in values.items() if v is not None}
        if not result[name]:
            raise SceneError(f"{motions.key(name)}: give angle_deg (degrees) and/or translation ([tx, ty, tz], m)")
    motions.done()
    return result



def _read_label(table: _Table) -> str:
    """A step label: a safe file name (:data:`LABEL_PATTERN`) that is not a fixed output's (:data:`RESERVED_NAMES`)."""
    label = table.string("label", required=True)
    if not LABEL_PATTERN.fullmatch(label):
        raise SceneError(f"{table.key('label')}: {label!r} is not a valid step label (it names the step's picture "
                         "file); valid: 1 to 64 ASCII letters, digits, '_', '-' or '.', starting with a letter or "
                         "a digit")
    if label.lower() in RESERVED_NAMES:
        raise SceneError(f"{table.key('label')}: {label!r} is the name of a fixed output of a run; choose another "
                         f"label (reserved: {', '.join(RESERVED_NAMES)})")
    return label


def _read_step_servos(table: _Table, loads: Mapping[str, Any]) -> dict[str, float]:
    """A step's horn angles from rest (deg): ``servos = {NAME = deg}`` (or one number), or ``servo_deg``.

    ``servo_deg`` is the shorthand of ``loads.servos = true``; each servo's ``range_deg`` bounds ``setup_deg + θ``.
    """
    servos = loads["servo"]
    angles: dict[str, float] = {}
    for key in ("servos", "servo_deg"):
        value = table.raw(key)
        if value is None:
            continue
        if not servos:
            raise SceneError(f"{table.key(key)}: the scene has no servos; set loads.servos = true (Tripod) or "
                             f"declare [loads.servo.NAME], or remove {key}")
        if angles:
            raise SceneError(f"{table.key(key)}: give servos or servo_deg, not both")
        if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
            angles = dict.fromkeys(servos, float(value))
        elif key == "servo_deg":
            if list(servos) != ["servo0", "servo1", "servo2"]:
                raise SceneError(f"{table.key(key)}: an array of three angles is the shorthand of loads.servos = "
                                 f"true; name the servos instead: servos = {{NAME = deg}} ({', '.join(servos)})")
            angles = dict(zip(servos, _vector(value, 3, table.key(key))))
        else:
            named = table.table(key)
            for name in list(named.data):
                if name not in servos:
                    raise SceneError(f"{named.key(name)}: no servo named {name!r}; declared servos: "
                                     f"{', '.join(servos)}")
                angles[name] = named.number(name, required=True)
            named.done()
        for name, angle in angles.items():
            limits = servos[name]["range_deg"]
            if limits is not None and not limits[0] <= servos[name]["setup_deg"] + angle <= limits[1]:
                raise SceneError(f"{table.key(key)}: servo {name!r} at {angle:g}° from rest reaches "
                                 f"{servos[name]['setup_deg'] + angle:g}°, outside its range_deg {list(limits)}")
    return angles


def _read_step(table: _Table, loads: Mapping[str, Any]) -> Step:
    label = _read_label(table)
    gravity = table.number("gravity", check=lambda v: v >= 0, valid="a load factor >= 0 (1: full gravity)")
    servos = _read_step_servos(table, loads)
    increments = table.integer("increments", default=1, minimum=1, maximum=MAX_INCREMENTS)
    factors = {**_read_step_loads(table, loads), **_read_step_contacts(table, loads)}
    motions = _read_step_motions(table, loads)
    table.done()
    return Step(label, gravity, increments, factors, motions, servos)


def _read_steps(scene: _Table, loads: Mapping[str, Any]) -> tuple[Step, ...]:
    """``[[steps]]``: a non-empty schedule with distinct labels."""
    value = scene.raw("steps", required=True)
    if not isinstance(value, list) or not value:
        raise SceneError(f"steps: expected a non-empty array of tables ([[steps]]), got {_type_name(value)}")
    steps = tuple(_read_step(_Table(s, f"steps[{i}]"), loads) for i, s in enumerate(value))
    seen: dict[str, str] = {}
    for i, step in enumerate(steps):  # distinct even without case: case-insensitive file systems
        other = seen.setdefault(step.label.lower(), step.label)
        if len(seen) <= i:
            same = "is repeated" if other == step.label else f"differs from {other!r} only in case"
            raise SceneError(f"steps[{i}].label: {step.label!r} {same}; labels must be distinct (they name files)")
    if loads["gravity"] is None and any(s.gravity for s in steps):
        raise SceneError("loads.gravity: a step sets a gravity factor but the scene gives no gravity vector")
    return steps


def _read_probes(scene: _Table, mesh: MeshInfo, loads: Mapping[str, Any]) -> tuple[tuple[str, ...], dict]:
    """``probes``: the listed probes that the mesh can provide; returns the names and the group probes' groups.

    A name is an entry of :data:`~fenicsfoam.scene.kinds.PROBE_KINDS`, or ``"KIND:GROUP"`` with ``KIND`` an entry of
    :data:`~fenicsfoam.scene.kinds.GROUP_PROBE_KINDS`.
    """
    value = scene.raw("probes", default=[])
    if not isinstance(value, list) or not all(isinstance(p, str) for p in value):
        raise SceneError(f"probes: expected an array of probe names, got {_type_name(value)} {value!r}")
    groups = {}
    for probe in value:
        if ":" in probe:
            kind, _, group = probe.partition(":")
            if kind not in GROUP_PROBE_KINDS:
                raise SceneError(f"probes: unknown probe kind {kind!r} in {probe!r}; valid: "
                                 f"{', '.join(k + ':GROUP' for k in GROUP_PROBE_KINDS)}")
            groups[probe] = GROUP_PROBE_KINDS[kind].check(probe, group, mesh, loads)
            continue
        if probe not in PROBE_KINDS:
            raise SceneError(f"probes: unknown probe {probe!r}; valid: {', '.join(PROBE_KINDS)}, or "
                             f"{', '.join(k + ':GROUP' for k in GROUP_PROBE_KINDS)}")
        PROBE_KINDS[probe].check(probe, mesh, loads)
    return tuple(dict.fromkeys(value)), groups


def _read_outputs(scene: _Table, labels: list[str]) -> tuple[bool, tuple[str, ...]]:
    """``[outputs]``: the XDMF series, and the steps pictured."""
    outputs = scene.table("outputs") or _Table({}, "outputs")
    xdmf = outputs.boolean("xdmf", True)
    png = outputs.raw("png", True)
    if isinstance(png, bool):
        pictured = labels if png else []
    elif isinstance(png, list) and all(label in labels for label in png):
        pictured = list(png)
    else:
        raise SceneError(f"outputs.png: expected true, false or an array of step labels ({labels}), "
                         f"got {_type_name(png)} {png!r}")
    outputs.done()
    return xdmf, tuple(pictured)


# --------------------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------------------
def parse_scene(data: Mapping[str, Any], base: str | os.PathLike | None = None) -> Scene:
    """Validate a scene given as a dict (as ``tomllib`` reads it) and return the :class:`Scene`.

    ``base`` is the directory a relative ``geometry.path`` or calibration file (``E_solid = {calibration =
    "..."}``) refers to (:func:`load_scene` passes the scene file's directory; default: the current directory).

    Raises
    ------
    SceneError
        On the first problem found, naming its key path (e.g. ``regions.arms.density``) and what is valid.

    """
    if not isinstance(data, Mapping):
        raise SceneError(f"scene: expected a table (a dict, as tomllib reads one), got {type(data).__name__} "
                         f"{data!r:.80}")
    scene = _Table(dict(data), "")
    name = scene.string("name", default="scene")
    if len(name) > MAX_NAME or not name.isprintable():
        raise SceneError(f"name: expected a printable name of at most {MAX_NAME} characters (it titles the pictures "
                         f"and the progress bar), got {len(name)} characters starting {name[:40]!r}")
    scene.string("description", default="")
    base = None if base is None else Path(base)
    mesh = _read_geometry(scene, base)
    model, degree, petsc = _read_fem(scene)
    regions = _read_regions(scene, mesh, base)
    blends = _read_blends(scene, regions)
    orientation = _read_orientation(scene, mesh)
    loads = _read_loads(scene, mesh)
    steps = _read_steps(scene, loads)
    probes, probe_groups = _read_probes(scene, mesh, loads)
    xdmf, png = _read_outputs(scene, [s.label for s in steps])
    scene.done()
    return Scene(raw=copy.deepcopy(dict(data)), name=name, builder=mesh.builder, geometry=mesh.params,
                 facets=mesh.facets, model=model, degree=degree, petsc=petsc, regions=regions,
                 orientation=orientation, loads=loads, steps=steps, probes=probes, xdmf=xdmf, png=png,
                 probe_groups=probe_groups, blends=blends)


def load_scene(source: str | os.PathLike | Mapping[str, Any]) -> Scene:
    """Read and validate a scene from a TOML file (path) or a dict; :class:`SceneError` names the problem."""
    if isinstance(source, Mapping):
        return parse_scene(source)
    if not isinstance(source, str | os.PathLike):
        raise SceneError(f"scene: expected a TOML file's path or a dict, got {type(source).__name__} {source!r:.80}")
    path = Path(source)
    try:
        check_input_file(path, "scene", max_bytes=MAX_SCENE_BYTES)  # a FIFO or /dev/zero is never opened
    except InputError as exc:
        raise SceneError(str(exc)) from exc
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:  # the message gives line and column
        raise SceneError(f"{path}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:  # a binary file: TOML is UTF-8 text
        raise SceneError(f"{path}: not a TOML text file (not UTF-8 at byte {exc.start})") from exc
    except OSError as exc:
        raise SceneError(f"cannot read scene {path}: {exc}") from exc
    try:
        return parse_scene(data, base=path.parent)
    except SceneError as exc:
        raise SceneError(f"{path}: {exc}") from exc
