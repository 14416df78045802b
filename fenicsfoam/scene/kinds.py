"""What a scene may declare besides its materials: geometry builders, probe kinds and load kinds, one registry each.

``[geometry] builder`` names an entry of :data:`GEOMETRY_KINDS` (each declares its keys, their defaults and
checks, the named regions and facet groups it makes, and its mesher); ``probes = [...]`` names entries of
:data:`PROBE_KINDS` (``"tip_deflection"``) or of :data:`GROUP_PROBE_KINDS` written ``"KIND:GROUP"``
(``"reaction_force:base"``); the keys of ``[loads]`` are the entries of :data:`LOAD_KINDS` (``servo``: the servo
actuators, :func:`servo_box`). Each entry carries its validation, run by :mod:`fenicsfoam.scene.schema` before
anything is built, and its builder, run by :mod:`fenicsfoam.scene.build`; the reader and the builder loop over the
registries, so a new kind is one entry here. Builders import the dolfinx-based modules when they are called, so
reading and validating a scene stays light.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fenicsfoam.scene.table import SceneError, _Table, _tags, _vector

__all__ = ["GEOMETRY_KINDS", "GROUP_PROBE_KINDS", "LOAD_KINDS", "PROBES", "PROBE_KINDS", "PROBE_UNITS",
           "RESERVED_MOTIONS", "BuildContext", "GeometryKey", "GeometryKind", "GroupProbeKind", "LoadKind", "MeshInfo",
           "ProbeKind", "probe_size", "probe_unit", "servo_box", "tripod_flat_servos"]


@dataclass(frozen=True)
class MeshInfo:
    """What validation knows of a scene's mesh before it is built (from the builder, or a mesh file's groups)."""

    builder: str                          #: an entry of :data:`GEOMETRY_KINDS` ("beam", "tripod", "file", ...)
    params: dict[str, Any]                #: the builder's keyword arguments, or the mesh file's path
    regions: dict[str, tuple[int, ...]]   #: named cell regions
    facets: dict[str, tuple[int, ...]]    #: named facet groups
    cell_tags: frozenset[int]             #: every cell tag of the mesh
    facet_tags: frozenset[int]            #: every facet tag of the mesh


@dataclass(frozen=True)
class BuildContext:
    """What a kind's builder may use: the validated scene, the tagged mesh and the displacement space."""

    scene: Any    #: the :class:`fenicsfoam.scene.schema.Scene`
    tagged: Any   #: the built mesh: ``mesh``, ``cell_tags``, ``facet_tags`` (and the builder's extras)
    V: Any = None  #: the displacement space, once the problem exists (probes)
    problem: Any = None  #: the :class:`fenicsfoam.solver.ElasticityProblem`, once it exists (probes)


# --------------------------------------------------------------------------------------------------
# Probes
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProbeKind:
    """A probe a scene may list: what the mesh must provide, the unit of its value, and how to build it."""

    needs: str                                               #: "tip": a facet group named tip; "tripod": that builder
    unit: str                                                #: unit of the value in summaries ("m" or "deg")
    build: Callable[[BuildContext], Callable[[Any], float]]  #: the probe, called with the displacement
    along_gravity: bool = False                              #: measured along gravity (needs ``loads.gravity``)

    def check(self, name: str, mesh: MeshInfo, loads: Mapping[str, Any]) -> None:
        """Raise :class:`SceneError` if the scene cannot provide what the probe ``name`` needs."""
        if self.needs == "tip" and "tip" not in mesh.facets:
            raise SceneError(f"probes: {name!r} needs a facet group named 'tip' (the beam builder's, or a "
                             f"physical surface named tip in a mesh file); the {mesh.builder} mesh has "
                             f"{sorted(mesh.facets) or 'none'}")
        if self.needs == "tripod" and mesh.builder != "tripod":
            raise SceneError(f"probes: {name!r} needs the tripod builder, the scene uses {mesh.builder!r}")
        if self.along_gravity and loads.get("gravity") is None:
            raise SceneError(f"probes: {name!r} is measured along gravity; give loads.gravity")


def _tip_deflection(context: BuildContext):
    from fenicsfoam.probes import TipDeflection
    scene = context.scene
    return TipDeflection(context.V, context.tagged.facet_tags, scene.facets["tip"][0], -np.asarray(scene.gravity))


def _center_height(context: BuildContext):
    from fenicsfoam.probes import CenterHeight
    from meshes.tripod import RING
    return CenterHeight(context.V, context.tagged.cell_tags, RING)


def _center_rotation(context: BuildContext):
    from fenicsfoam.probes import CenterRotation
    from meshes.tripod import RING
    return CenterRotation(context.V, context.tagged.cell_tags, RING)


def _center_tilt(axis: str):
    def build(context: BuildContext):
        from fenicsfoam.probes import CenterTilt
        from meshes.tripod import RING
        return CenterTilt(context.V, context.tagged.cell_tags, RING, axis)
    return build


#: The probes a scene may list (documented in :mod:`fenicsfoam.probes`; *tip_deflection* is measured along ``−ĝ``,
#: so a sagging tip is negative; *center_height*, *center_rotation*, *center_tilt_x*, *center_tilt_y* use the
#: Tripod's probe ring).
PROBE_KINDS: dict[str, ProbeKind] = {
    "tip_deflection": ProbeKind("tip", "m", _tip_deflection, along_gravity=True),
    "center_height": ProbeKind("tripod", "m", _center_height),
    "center_rotation": ProbeKind("tripod", "deg", _center_rotation),
    "center_tilt_x": ProbeKind("tripod", "deg", _center_tilt("x")),
    "center_tilt_y": ProbeKind("tripod", "deg", _center_tilt("y")),
}
#: Probe names and what they need: a facet group named "tip" (the beam's, or a mesh file's) or the Tripod.
PROBES: dict[str, str] = {name: kind.needs for name, kind in PROBE_KINDS.items()}
#: Units of the probe values in summaries (SI, angles in degrees).
PROBE_UNITS: dict[str, str] = {name: kind.unit for name, kind in PROBE_KINDS.items()}


@dataclass(frozen=True)
class Group:
    """A named group of the mesh as a probe or a load refers to it: its tags and their dimension."""

    name: str
    tags: tuple[int, ...]
    cells: bool   #: a cell region (else a facet group)

    def meshtags(self, tagged):
        return tagged.cell_tags if self.cells else tagged.facet_tags


def _group(value: Any, path: str, mesh: MeshInfo, facets_only: bool = False) -> Group:
    """A group given by name (a facet group, else a cell region) or by facet tags."""
    if isinstance(value, str):
        if value in mesh.facets:
            return Group(value, tuple(mesh.facets[value]), False)
        if value in mesh.regions and not facets_only:
            return Group(value, tuple(mesh.regions[value]), True)
        if value in mesh.regions:  # a volume where a surface is needed
            raise SceneError(f"{path}: unknown facet group {value!r}: it is a volume group (a cell region) of the "
                             f"mesh, and a surface is needed here; facet groups: "
                             f"{', '.join(sorted(mesh.facets)) or 'none'}")
        names = sorted(mesh.facets) + ([] if facets_only else sorted(mesh.regions))
        what = "facet group" if facets_only else "facet group or region"
        raise SceneError(f"{path}: unknown {what} {value!r}; valid names: {', '.join(names) or 'none'}"
                         + (" (or integer facet tags)" if mesh.facet_tags else ""))
    tags = _tags(value, path, mesh.facets, "facet group")
    unknown = sorted(set(tags) - set(mesh.facet_tags))
    if unknown:
        raise SceneError(f"{path}: facet tags {unknown} are not facet tags of the {mesh.builder} mesh "
                         f"(facet tags: {sorted(mesh.facet_tags) or 'none'})")
    return Group(str(value), tags, False)


def _prescribed(loads: Mapping[str, Any]) -> tuple[set[int], set[int]]:
    """Facet tags and cell tags whose nodes a scene prescribes (clamp, motions, the Tripod's horns)."""
    facets, cells = set(loads.get("clamp") or ()), set()
    for motion in (loads.get("motion") or {}).values():
        (cells if motion["group"].cells else facets).update(motion["group"].tags)
    for servo in (loads.get("servo") or {}).values():
        if servo["clamp"] is not None:
            (cells if servo["clamp"].cells else facets).update(servo["clamp"].tags)
    return facets, cells


@dataclass(frozen=True)
class GroupProbeKind:
    """A probe of a named group, written ``"KIND:GROUP"``: its unit, size, what groups it takes, how it is built."""

    unit: str                                                  #: unit of the value ("N", "m", "deg", "m3")
    size: int                                                  #: 1 (a number) or 3 (a vector, a list in JSON)
    build: Callable[[BuildContext, Group], Callable[[Any], Any]]  #: the probe, called with the displacement
    facets_only: bool = False                                  #: the group must be a facet group
    prescribed: bool = False                                   #: the group must be clamped or moved
    contact: bool = False                                      #: GROUP names a ``[contacts.NAME]``, not a group

    def check(self, name: str, group: str, mesh: MeshInfo, loads: Mapping[str, Any]) -> Group:
        """The :class:`Group` the probe ``name`` refers to; :class:`SceneError` if the scene cannot provide it."""
        if self.contact:
            contacts = loads.get("contact") or {}
            if group not in contacts:
                raise SceneError(f"probes: {name!r}: no contact named {group!r}; declared contacts: "
                                 f"{', '.join(sorted(contacts)) or 'none'} ([contacts.NAME])")
            return Group(group, contacts[group]["group"].tags, False)
        resolved = _group(group, f"probes: {name!r}", mesh, self.facets_only)
        if self.prescribed:
            facets, cells = _prescribed(loads)
            if not set(resolved.tags) <= (cells if resolved.cells else facets):
                raise SceneError(f"probes: {name!r}: the group {group!r} is not clamped or moved (a reaction force "
                                 "needs a support: loads.clamp, a [loads.motion.NAME] on that group, or the "
                                 "Tripod's servos)")
        return resolved


def _reaction_force(context: BuildContext, group: Group):
    from fenicsfoam.probes import ReactionForce
    probe = ReactionForce(context.problem, group.meshtags(context.tagged), group.tags)
    return lambda u: probe().tolist()


def _mean_displacement(context: BuildContext, group: Group):
    from fenicsfoam.probes import MeanDisplacement
    probe = MeanDisplacement(context.V, group.meshtags(context.tagged), group.tags)
    return lambda u: probe(u).tolist()


def _rotation(context: BuildContext, group: Group):
    from fenicsfoam.probes import BestFitRotation
    probe = BestFitRotation(context.V, group.meshtags(context.tagged), group.tags)
    return lambda u: probe(u).tolist()


def _contact_force(context: BuildContext, group: Group):
    contact = context.problem.external[group.name]
    return lambda u: contact.force().tolist()


def _contact_area(context: BuildContext, group: Group):
    contact = context.problem.external[group.name]
    return lambda u: contact.contact_area()


def _volume(context: BuildContext, group: Group):
    from fenicsfoam.probes import EnclosedVolume
    return EnclosedVolume(context.V, context.tagged.facet_tags, group.tags)


#: Probes of any named group, written ``"KIND:GROUP"`` (GROUP a facet group name, or a region name where allowed):
#: *reaction_force* (N, the force the supports exert on a clamped or moved group, from the residual),
#: *displacement* (m, mean over the group), *rotation* (deg, rotation vector of the group's best-fit rotation),
#: *volume* (m³, enclosed by a closed facet group, deformed). Documented in :mod:`fenicsfoam.probes`. Of a
#: contact (``"KIND:NAME"``, NAME a ``[contacts.NAME]``): *contact_force* (N, the force the obstacle exerts on the
#: body) and *contact_area* (m², reference area in contact), documented in :mod:`fenicsfoam.contact`.
GROUP_PROBE_KINDS: dict[str, GroupProbeKind] = {
    "reaction_force": GroupProbeKind("N", 3, _reaction_force, prescribed=True),
    "displacement": GroupProbeKind("m", 3, _mean_displacement),
    "rotation": GroupProbeKind("deg", 3, _rotation),
    "volume": GroupProbeKind("m3", 1, _volume, facets_only=True),
    "contact_force": GroupProbeKind("N", 3, _contact_force, contact=True),
    "contact_area": GroupProbeKind("m2", 1, _contact_area, contact=True),
}


def _probe_kind(name: str):
    kind = name.partition(":")[0] if ":" in name else name
    return GROUP_PROBE_KINDS[kind] if ":" in name else PROBE_KINDS[kind]


def probe_unit(name: str) -> str:
    """The unit of a listed probe's value (``"tip_deflection"`` → ``"m"``, ``"reaction_force:base"`` → ``"N"``)."""
    return _probe_kind(name).unit


def probe_size(name: str) -> int:
    """1 for a number, 3 for a vector (a list of 3 components)."""
    return getattr(_probe_kind(name), "size", 1)


# --------------------------------------------------------------------------------------------------
# Loads
# --------------------------------------------------------------------------------------------------
def _none(value: Any, context: BuildContext) -> list:
    return []


@dataclass(frozen=True)
class LoadKind:
    """A key of ``[loads]``: how its value is read and checked, its rigid motions and its external loads."""

    read: Callable[[_Table, str, MeshInfo], Any]      #: the validated value (its default when the key is absent)
    motions: Callable[[Any, BuildContext], list] = _none   #: ``fenicsfoam.bcs.RigidMotion`` objects
    external: Callable[[Any, BuildContext], list] = _none  #: ``fenicsfoam.loads.Load`` objects
    named: bool = False                                    #: a table of named loads, moved by the steps
    #: read from a top-level table of its own (``"contacts"``: ``[contacts.NAME]``) rather than a key of ``[loads]``
    section: str | None = None


#: Motion names the scene uses itself (no named load or motion ``[loads.KIND.NAME]`` may take them; ``servo0..2``
#: are the servos of ``loads.servos = true``, a ``[loads.servo.NAME]`` may take them).
RESERVED_MOTIONS = ("clamp", "servo0", "servo1", "servo2")


def _read_gravity(loads: _Table, key: str, mesh: MeshInfo):
    return loads.vector(key, 3)


def _read_clamp(loads: _Table, key: str, mesh: MeshInfo) -> tuple[int, ...]:
    value = loads.raw(key)
    clamp = () if value is None else _tags(value, loads.key(key), mesh.facets, "facet group")
    if clamp and not mesh.facet_tags:
        raise SceneError(f"loads.clamp: the {mesh.builder} mesh has no facet tags to clamp")
    unknown = set(clamp) - set(mesh.facet_tags)
    if unknown:
        raise SceneError(f"loads.clamp: facet tags {sorted(unknown)} are not facet tags of the {mesh.builder} mesh "
                         f"(facet tags: {sorted(mesh.facet_tags)})")
    return clamp


def _clamp_motions(clamp: tuple[int, ...], context: BuildContext) -> list:
    from fenicsfoam.bcs import RigidMotion
    if not clamp:
        return []
    return [RigidMotion("clamp", np.concatenate([context.tagged.facet_tags.find(t) for t in clamp]))]


def _read_servos(loads: _Table, key: str, mesh: MeshInfo) -> bool:
    """``servos = true``: the Tripod's three horns with the flat-plate kinematics (:func:`tripod_flat_servos`)."""
    servos = loads.boolean(key, False)
    if servos and mesh.builder != "tripod":
        raise SceneError(f"loads.servos: servo horns need the tripod builder, not {mesh.builder!r}")
    if servos and loads.has("servo"):
        raise SceneError("loads.servos: give either servos = true (the Tripod's flat-plate servos) or "
                         "[loads.servo.NAME] servo actuators, not both")
    return servos


def tripod_flat_servos(params: Mapping[str, Any], mesh: MeshInfo | None = None) -> dict[str, dict]:
    """The servos of ``loads.servos = true``: the Tripod's flat-plate kinematics as three servo actuators.

    Servo ``servo{i}`` turns the arm end ``arm_end{i}`` about the axle through ``servo_radius e_i + pivot_z e_z``
    along the counter-clockwise tangent ``t_i = (−sin φ_i, cos φ_i, 0)``; no set-up motion (the flat, stress-free
    plate is the rest), angles from there (:meth:`meshes.tripod.TripodGeometry.servo_frames`).
    """
    from meshes.tripod import ARM_ANGLES_DEG, ARM_END
    servos = {}
    for i, phi in enumerate(np.radians(ARM_ANGLES_DEG)):
        e = np.array([np.cos(phi), np.sin(phi), 0.0])
        servos[f"servo{i}"] = {
            "clamp": Group(f"arm_end{i}", (ARM_END[i],), True), "box": None,
            "axle_point": tuple(float(v) for v in params["servo_radius"] * e + [0.0, 0.0, params["pivot_z"]]),
            "axle": (float(-e[1]), float(e[0]), 0.0), "horn": tuple(float(v) for v in -e),
            "horn_length": float(params["horn_length"]), "setup_translation": (0.0, 0.0, 0.0), "setup_deg": 0.0,
            "range_deg": None}
    return servos


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _read_servo(loads: _Table, key: str, mesh: MeshInfo) -> dict[str, dict]:
    """``[loads.servo.NAME]``: a servo actuator (:mod:`fenicsfoam.scene.kinds`, :data:`LOAD_KINDS`)."""
    def one(table: _Table, name: str) -> dict:
        if name in RESERVED_MOTIONS[:1]:
            raise SceneError(f"{table.path}: the name {name!r} is reserved ({RESERVED_MOTIONS[0]})")
        axle_point = table.vector("axle_point", 3, required=True)
        axle = table.vector("axle", 3, required=True)
        if not any(axle):
            raise SceneError(f"{table.key('axle')}: the axle must be a non-zero vector")
        horn = table.vector("horn", 3, required=True)
        if not any(horn) or abs(float(_unit(horn) @ _unit(axle))) > 1e-6:
            raise SceneError(f"{table.key('horn')}: the horn's direction {list(horn)} must be a non-zero vector "
                             f"perpendicular to the axle {list(axle)}")
        horn_length = table.number("horn_length", required=True, check=lambda v: v > 0, valid="a length > 0 (m)")
        has_clamp, has_box = table.has("clamp"), table.has("clamp_box")
        if has_clamp == has_box:
            raise SceneError(f"{table.path}: give exactly one of clamp (a region or facet group carried by the horn) "
                             "and clamp_box ([along the axle, along the horn, across], m: a box centred on the "
                             "horn's tip)")
        clamp = _group(table.raw("clamp"), table.key("clamp"), mesh) if has_clamp else None
        box = None
        if has_box:
            box = table.vector("clamp_box", 3, required=True)
            if not all(v > 0 for v in box):
                raise SceneError(f"{table.key('clamp_box')}: the box's sizes must be > 0 (m), got {list(box)}")
        setup_translation = table.vector("setup_translation", 3, default=[0.0, 0.0, 0.0])
        setup_deg = table.number("setup_deg", default=0.0)
        range_deg = table.raw("range_deg")
        if range_deg is not None:
            range_deg = _vector(range_deg, 2, table.key("range_deg"))
            if not range_deg[0] < range_deg[1] or not range_deg[0] <= setup_deg <= range_deg[1]:
                raise SceneError(f"{table.key('range_deg')}: expected [lo, hi] with lo < hi holding setup_deg = "
                                 f"{setup_deg:g} (the horn's angle at rest, deg), got {list(range_deg)}")
        table.done()
        return {"clamp": clamp, "box": box, "axle_point": axle_point, "axle": axle, "horn": horn,
                "horn_length": horn_length, "setup_translation": setup_translation, "setup_deg": setup_deg,
                "range_deg": range_deg}
    return _named_tables(loads, key, one)


def servo_box(spec: Mapping[str, Any]) -> Callable[[np.ndarray], np.ndarray]:
    """The marker of a servo's ``clamp_box``: points (3, n) in the box centred on the horn's tip (reference pose).

    The box's edges lie along the axle, the horn and ``axle × horn``; its sizes are ``clamp_box`` in that order.
    """
    a, h = _unit(spec["axle"]), _unit(spec["horn"])
    frame = np.array([a, h, np.cross(a, h)])
    tip = np.asarray(spec["axle_point"], dtype=float) + spec["horn_length"] * h
    half = 0.5 * np.asarray(spec["box"], dtype=float)

    def inside(x: np.ndarray) -> np.ndarray:
        local = frame @ (np.asarray(x, dtype=float).T - tip).T
        return np.all(np.abs(local) <= half[:, None] * (1 + 1e-12), axis=0)
    return inside


def _servo_motions(servos: Mapping[str, dict], context: BuildContext) -> list:
    """Each servo carries its clamp rigidly: ``x = R(θ, axle)(X − p) + p + t`` (:mod:`fenicsfoam.bcs`)."""
    from fenicsfoam.bcs import RigidMotion
    dim = context.tagged.mesh.topology.dim
    motions = []
    for name, spec in servos.items():
        if spec["clamp"] is not None:
            group = spec["clamp"]
            motions.append(RigidMotion(name, _entities(group, context), dim=dim if group.cells else None,
                                       axis=spec["axle"], point=spec["axle_point"]))
        else:
            motions.append(RigidMotion(name, np.zeros(0, dtype=np.int32), axis=spec["axle"],
                                       point=spec["axle_point"], where=servo_box(spec)))
    return motions


def _named_tables(loads: _Table, key: str, read_one: Callable[[_Table, str], dict]) -> dict[str, dict]:
    table = loads.table(key)
    if table is None:
        return {}
    reserved = RESERVED_MOTIONS[:1] if key == "servo" else RESERVED_MOTIONS
    for name in table.data:  # the scene's own motions are named so too: the steps could not tell them apart
        if name in reserved:
            raise SceneError(f"{table.path}.{name}: the name {name!r} is reserved ({', '.join(reserved)}); "
                             "choose another name")
    named = {name: read_one(table.table(name), name) for name in list(table.data)}
    table.done()
    return named


def _read_surface(quantity: str, size: int, valid: str):
    """Reader of ``[loads.force|traction|pressure.NAME]``: ``group`` (a facet group) and the load's value."""
    def read(loads: _Table, key: str, mesh: MeshInfo) -> dict[str, dict]:
        def one(table: _Table, name: str) -> dict:
            group = _group(table.raw("group", required=True), table.key("group"), mesh, facets_only=True)
            value = table.vector(quantity, 3, required=True) if size == 3 else \
                table.number(quantity, required=True, valid=valid)
            table.done()
            return {"group": group, quantity: value}
        return _named_tables(loads, key, one)
    return read


def _read_cable(loads: _Table, key: str, mesh: MeshInfo) -> dict[str, dict]:
    def one(table: _Table, name: str) -> dict:
        points = table.raw("points", required=True)
        path = table.key("points")
        if not isinstance(points, list) or not points:
            raise SceneError(f"{path}: expected an array of points [x, y, z] or facet group names, got {points!r}")
        via = []
        for i, entry in enumerate(points):
            if isinstance(entry, str):
                via.append(_group(entry, f"{path}[{i}]", mesh, facets_only=True))
            else:
                via.append(_vector(entry, 3, f"{path}[{i}]"))
        tension = table.number("tension", required=True, check=lambda v: v >= 0,
                               valid="a tension >= 0 (N); a cable cannot push")
        pull = table.vector("pull_point", 3)
        if len(via) < (1 if pull is not None else 2):
            raise SceneError(f"{path}: a cable needs at least two points, or one and a pull_point")
        table.done()
        return {"points": via, "tension": tension, "pull_point": pull}
    return _named_tables(loads, key, one)


def _read_motion(loads: _Table, key: str, mesh: MeshInfo) -> dict[str, dict]:
    def one(table: _Table, name: str) -> dict:
        if name in RESERVED_MOTIONS:
            raise SceneError(f"{table.path}: the name {name!r} is reserved ({', '.join(RESERVED_MOTIONS)})")
        group = _group(table.raw("group", required=True), table.key("group"), mesh)
        axis = table.vector("axis", 3, default=[0.0, 0.0, 1.0])
        if not any(axis):
            raise SceneError(f"{table.key('axis')}: the rotation axis must be a non-zero vector")
        point = table.vector("point", 3, default=[0.0, 0.0, 0.0])
        components = table.raw("components", default=["x", "y", "z"])
        if (not isinstance(components, list) or not components or len(set(components)) != len(components)
                or not all(c in ("x", "y", "z") for c in components)):
            raise SceneError(f"{table.key('components')}: expected a non-empty array of distinct \"x\", \"y\", \"z\" "
                             f"(the prescribed components), got {components!r}")
        table.done()
        return {"group": group, "axis": axis, "point": point,
                "components": tuple(sorted("xyz".index(c) for c in components))}
    return _named_tables(loads, key, one)


def _entities(group: Group, context: BuildContext) -> np.ndarray:
    meshtags = group.meshtags(context.tagged)
    return np.unique(np.concatenate([meshtags.find(t) for t in group.tags])).astype(np.int32)


def _motion_motions(motions: dict[str, dict], context: BuildContext) -> list:
    from fenicsfoam.bcs import RigidMotion
    dim = context.tagged.mesh.topology.dim
    return [RigidMotion(name, _entities(spec["group"], context), dim=dim if spec["group"].cells else None,
                        axis=spec["axis"], point=spec["point"], components=spec["components"])
            for name, spec in motions.items()]


def _surface_loads(quantity: str):
    def build(named: dict[str, dict], context: BuildContext) -> list:
        from fenicsfoam.loads import FollowerPressure, SurfaceTraction
        tagged = context.tagged
        if quantity == "pressure":
            return [FollowerPressure(name, tagged.mesh, tagged.facet_tags, spec["group"].tags, spec["pressure"])
                    for name, spec in named.items()]
        return [SurfaceTraction(name, tagged.mesh, tagged.facet_tags, spec["group"].tags,
                                **{quantity: spec[quantity]}) for name, spec in named.items()]
    return build


def _cables(named: dict[str, dict], context: BuildContext) -> list:
    from fenicsfoam.loads import Cable, Facets
    return [Cable(name, [Facets(p.tags) if isinstance(p, Group) else p for p in spec["points"]], spec["tension"],
                  pull_point=spec["pull_point"], facet_tags=context.tagged.facet_tags)
            for name, spec in named.items()]


def _read_contacts(scene: _Table, key: str, mesh: MeshInfo) -> dict[str, dict]:
    """``[contacts.NAME]``: a facet ``group``, an ``obstacle`` (plane | sphere | box) and its geometry.

    Also the obstacle's ``motion`` (m, at factor 1; the steps' ``contacts = {NAME = factor}`` move it) and
    ``nitsche`` (θ_N, :mod:`fenicsfoam.contact`).
    """
    from fenicsfoam.contact import NITSCHE, OBSTACLES

    def one(table: _Table, name: str) -> dict:
        group = _group(table.raw("group", required=True), table.key("group"), mesh, facets_only=True)
        shape = table.string("obstacle", required=True, choices=tuple(OBSTACLES))
        geometry: dict[str, Any] = {}
        if shape == "plane":
            geometry["point"] = table.vector("point", 3, required=True)
            geometry["normal"] = table.vector("normal", 3, required=True)
            if not any(geometry["normal"]):
                raise SceneError(f"{table.key('normal')}: the plane's normal must be a non-zero vector")
        elif shape == "sphere":
            geometry["center"] = table.vector("center", 3, required=True)
            geometry["radius"] = table.number("radius", required=True, check=lambda v: v > 0,
                                              valid="a radius > 0 (m)")
        else:
            corners = table.has("min") or table.has("max")
            if corners == (table.has("center") or table.has("half_sizes")):
                raise SceneError(f"{table.path}: a box is given by min and max (corners, m) or by center and "
                                 "half_sizes (m), one pair")
            if corners:
                lo, hi = table.vector("min", 3, required=True), table.vector("max", 3, required=True)
            else:
                center = np.asarray(table.vector("center", 3, required=True))
                half = np.asarray(table.vector("half_sizes", 3, required=True))
                lo, hi = tuple((center - half).tolist()), tuple((center + half).tolist())
            if not all(b > a for a, b in zip(lo, hi)):
                raise SceneError(f"{table.path}: the box must have max > min in every component, got min {list(lo)}, "
                                 f"max {list(hi)}")
            geometry.update(min=lo, max=hi)
        motion = table.vector("motion", 3, default=[0.0, 0.0, 0.0])
        nitsche = table.number("nitsche", default=NITSCHE, check=lambda v: v > 0,
                               valid="a dimensionless Nitsche parameter > 0 (γ = nitsche·(λ+2μ)/h)")
        table.done()
        return {"group": group, "obstacle": shape, **geometry, "motion": motion, "nitsche": nitsche}
    return _named_tables(scene, key, one)


def _contacts(named: dict[str, dict], context: BuildContext) -> list:
    from fenicsfoam.contact import OBSTACLES, Contact, Obstacle
    tagged = context.tagged
    return [Contact(name, tagged.mesh, tagged.facet_tags, spec["group"].tags,
                    Obstacle(spec["obstacle"], motion=spec["motion"],
                             **{k: spec[k] for k in OBSTACLES[spec["obstacle"]]}), nitsche=spec["nitsche"])
            for name, spec in named.items()]


#: The keys of ``[loads]``: ``gravity = [gx, gy, gz]`` (m/s², scaled by the steps' gravity factors), ``clamp =
#: facet tags or a facet group name`` (held fixed), ``[loads.servo.NAME]`` (a servo actuator: a rigid servo body
#: whose horn carries a clamped part of the mesh, set up by a translation and a horn angle that define the rest and
#: turned from there by the steps' ``servos = {NAME = deg}``), ``servos = true`` (shorthand: the Tripod's three
#: servos with the flat-plate kinematics, :func:`tripod_flat_servos`, turned by the steps' ``servo_deg``); named
#: loads ``[loads.force.NAME]`` (a total force, N), ``[loads.traction.NAME]`` (a dead traction, Pa),
#: ``[loads.pressure.NAME]`` (a follower pressure, Pa), ``[loads.cable.NAME]`` (a tendon, N), each scaled by the
#: steps' ``loads = {NAME = factor}``; and ``[loads.motion.NAME]`` (a rigid motion of a group, moved
#: by the steps' ``motions``). Contacts with rigid obstacles are declared in a table of their own,
#: ``[contacts.NAME]``, and moved by the steps' ``contacts = {NAME = factor}``. Definitions: :mod:`fenicsfoam.loads`,
#: :mod:`fenicsfoam.bcs`, :mod:`fenicsfoam.contact`.
LOAD_KINDS: dict[str, LoadKind] = {
    "gravity": LoadKind(_read_gravity),
    "clamp": LoadKind(_read_clamp, _clamp_motions),
    "servos": LoadKind(_read_servos),
    "servo": LoadKind(_read_servo, _servo_motions),
    "force": LoadKind(_read_surface("force", 3, ""), external=_surface_loads("force"), named=True),
    "traction": LoadKind(_read_surface("traction", 3, ""), external=_surface_loads("traction"), named=True),
    "pressure": LoadKind(_read_surface("pressure", 1, "a pressure (Pa)"), external=_surface_loads("pressure"),
                         named=True),
    "cable": LoadKind(_read_cable, external=_cables, named=True),
    "motion": LoadKind(_read_motion, _motion_motions),
    "contact": LoadKind(_read_contacts, external=_contacts, named=True, section="contacts"),
}


# --------------------------------------------------------------------------------------------------
# Geometry builders
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GeometryKey:
    """A key of ``[geometry]`` that a builder declares: its default and what values are valid."""

    default: Any
    kind: str = "length"   #: "length" (> 0, m), "length0" (≥ 0, m), "number" (finite), "bool", "order" (1 | 2),
    #: "count" (an integer ≥ 0), "choice" (one of ``choices``)
    choices: tuple[str, ...] = ()

    def read(self, table: _Table, key: str) -> Any:
        """The key's validated value (its default when absent)."""
        if self.kind == "bool":
            return table.boolean(key, self.default)
        if self.kind == "order":
            return table.integer(key, default=self.default, choices=(1, 2))
        if self.kind == "count":
            return table.integer(key, default=self.default, minimum=0)
        if self.kind == "choice":
            return table.string(key, default=self.default, choices=self.choices)
        if self.kind == "number":
            return table.number(key, default=self.default)
        if self.kind == "length0":
            return table.number(key, default=self.default, check=lambda v: v >= 0, valid="a length >= 0 (m)")
        return table.number(key, default=self.default, check=lambda v: v > 0, valid="a length > 0 (m)")


def _no_groups(params: Mapping[str, Any], regions: dict, facets: dict) -> tuple[dict, dict]:
    return regions, facets


@dataclass(frozen=True)
class GeometryKind:
    """A ``[geometry] builder``: its keys, the named groups of its mesh, and its mesher.

    ``keys()`` and ``groups()`` import the mesh module when called (reading a scene stays light); ``mesh(comm,
    params)`` builds the tagged mesh from the validated keys. ``select`` drops the groups a parameter removes
    (e.g. the finger's ``pad`` facet group when ``pad = 0``). A builder with a ``read`` of its own (``file``)
    reads the whole ``[geometry]`` table itself.
    """

    keys: Callable[[], dict[str, GeometryKey]]
    groups: Callable[[], tuple[dict[str, tuple[int, ...]], dict[str, tuple[int, ...]]]]
    mesh: Callable[[Any, dict[str, Any]], Any]
    select: Callable[[Mapping[str, Any], dict, dict], tuple[dict, dict]] = _no_groups
    read: Callable[[_Table, Any], MeshInfo] | None = None

    def info(self, name: str, table: _Table, base: Any = None) -> MeshInfo:
        """The validated keys of ``table`` (its leftovers refused) and what the mesh will hold.

        ``base``: the directory relative paths refer to.
        """
        if self.read is not None:
            return self.read(table, base)
        params = {key: spec.read(table, key) for key, spec in self.keys().items()}
        table.done()
        regions, facets = self.select(params, *self.groups())
        return MeshInfo(name, params, regions, facets, frozenset().union(*regions.values()),
                        frozenset().union(*facets.values()))


def _dataclass_keys(cls, kinds: Mapping[str, str] | None = None) -> dict[str, GeometryKey]:
    """Keys of a geometry dataclass's fields: lengths unless ``kinds`` says otherwise; booleans by their default."""
    from dataclasses import fields
    kinds = kinds or {}
    return {f.name: GeometryKey(f.default, "bool" if isinstance(f.default, bool) else kinds.get(f.name, "length"))
            for f in fields(cls)}


def _beam_keys() -> dict[str, GeometryKey]:
    from meshes.beam import FIG6_BEAM
    return {**{k: GeometryKey(v) for k, v in FIG6_BEAM.items()}, "order": GeometryKey(1, "order")}


def _beam_groups():
    from meshes.beam import BEAM_VOLUME, CLAMPED_FACE, TIP_FACE
    return {"beam": (BEAM_VOLUME,)}, {"clamped": (CLAMPED_FACE,), "tip": (TIP_FACE,)}


def _beam_mesh(comm, params: dict[str, Any]):
    from meshes.beam import make_beam
    return make_beam(comm, **params)


def _finger_keys() -> dict[str, GeometryKey]:
    from meshes.finger import FingerGeometry
    return {"h": GeometryKey(0.003), "order": GeometryKey(1, "order"),
            **_dataclass_keys(FingerGeometry, {"pad": "length0"})}


def _finger_groups():
    from meshes.finger import CELL_TAGS, FACET_TAGS
    return {n: (t,) for n, t in CELL_TAGS.items()}, {n: (t,) for n, t in FACET_TAGS.items()}


def _finger_select(params: Mapping[str, Any], regions: dict, facets: dict) -> tuple[dict, dict]:
    absent = {"chamber": not params["chamber"], "pad": params["pad"] == 0}
    return regions, {name: tags for name, tags in facets.items() if not absent.get(name)}


def _finger_mesh(comm, params: dict[str, Any]):
    from meshes.finger import FingerGeometry, make_finger
    params = dict(params)
    h, order = params.pop("h"), params.pop("order")
    try:
        geometry = FingerGeometry(**params)
    except ValueError as exc:
        raise SceneError(f"geometry: {exc}") from exc
    return make_finger(comm, h, geometry, order)


def _tripod_keys() -> dict[str, GeometryKey]:
    from meshes.tripod import ARM_END_CUTS, PAPER_H, TripodGeometry
    return {"h": GeometryKey(PAPER_H), "order": GeometryKey(1, "order"), "layers": GeometryKey(0, "count"),
            **_dataclass_keys(TripodGeometry, {"fillet_radius": "length0", "pivot_z": "number"}),
            "arm_end_cut": GeometryKey("arc", "choice", ARM_END_CUTS)}


def _tripod_groups():
    from meshes.tripod import REGIONS
    return dict(REGIONS), {}


def _tripod_mesh(comm, params: dict[str, Any]):
    from foambase.errors import InputError
    from meshes.tripod import TripodGeometry, make_tripod
    params = dict(params)
    h, order, layers = params.pop("h"), params.pop("order"), params.pop("layers")
    try:
        geometry = TripodGeometry(**params)
    except ValueError as exc:  # named by the scene builder
        raise InputError(str(exc)) from exc
    return make_tripod(comm, h, geometry, order, layers)


def _read_mesh_file(geometry: _Table, base) -> MeshInfo:
    """``builder = "file"``: a gmsh ``.msh`` file; its physical groups are read (not the mesh) to validate."""
    from pathlib import Path

    from meshes.msh import physical_groups

    path = Path(geometry.string("path", required=True))
    geometry.done()
    if not path.is_absolute() and base is not None:
        path = base / path
    from foambase.errors import InputError
    from foambase.files import check_input_file
    try:  # a FIFO, a device or a directory is named as what it is, never opened
        check_input_file(path, "geometry.path: mesh file")
    except InputError as exc:
        raise SceneError(str(exc)) from exc
    try:
        groups = physical_groups(path)
    except ValueError as exc:
        raise SceneError(f"geometry.path: {exc}") from exc
    return MeshInfo("file", {"path": path}, {n: (t,) for n, t in groups.cell_names.items()},
                    {n: (t,) for n, t in groups.facet_names.items()}, groups.cells, groups.facets)


def _file_mesh(comm, params: dict[str, Any]):
    from meshes.msh import read_msh
    return read_msh(comm, params["path"])


#: Geometry builders, ``[geometry] builder = NAME``: ``beam`` (:mod:`meshes.beam`), ``finger``
#: (:mod:`meshes.finger`), ``tripod`` (:mod:`meshes.tripod`), ``file`` (a gmsh ``.msh`` file, ``path``). A new
#: builder is one entry: its keys (with defaults and checks), its named groups and its mesher.
GEOMETRY_KINDS: dict[str, GeometryKind] = {
    "beam": GeometryKind(_beam_keys, _beam_groups, _beam_mesh),
    "tripod": GeometryKind(_tripod_keys, _tripod_groups, _tripod_mesh),
    "finger": GeometryKind(_finger_keys, _finger_groups, _finger_mesh, select=_finger_select),
    "file": GeometryKind(dict, lambda: ({}, {}), _file_mesh, read=_read_mesh_file),
}
