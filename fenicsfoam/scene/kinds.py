"""What a scene may declare besides its mesh and materials: probe kinds and load kinds, one registry each.

``probes = [...]`` names entries of :data:`PROBE_KINDS` (``"tip_deflection"``) or of :data:`GROUP_PROBE_KINDS`
written ``"KIND:GROUP"`` (``"reaction_force:base"``); the keys of ``[loads]`` are the entries of
:data:`LOAD_KINDS`. Each entry carries its validation, run by :mod:`fenicsfoam.scene.schema` before anything is
built, and its builder, run by :mod:`fenicsfoam.scene.build`; the reader and the builder loop over the registries,
so a new kind is one entry here. Builders import the dolfinx-based modules when they are called, so reading and
validating a scene stays light.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fenicsfoam.scene.table import SceneError, _Table, _tags, _vector

__all__ = ["GROUP_PROBE_KINDS", "LOAD_KINDS", "PROBES", "PROBE_KINDS", "PROBE_UNITS", "RESERVED_MOTIONS",
           "BuildContext", "GroupProbeKind", "LoadKind", "MeshInfo", "ProbeKind", "probe_size", "probe_unit"]


@dataclass(frozen=True)
class MeshInfo:
    """What validation knows of a scene's mesh before it is built (from the builder, or a mesh file's groups)."""

    builder: str                          #: "beam" | "tripod" | "file"
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
    if loads.get("servos"):
        from meshes.tripod import ARM_END
        cells.update(ARM_END)
    return facets, cells


@dataclass(frozen=True)
class GroupProbeKind:
    """A probe of a named group, written ``"KIND:GROUP"``: its unit, size, what groups it takes, how it is built."""

    unit: str                                                  #: unit of the value ("N", "m", "deg", "m3")
    size: int                                                  #: 1 (a number) or 3 (a vector, a list in JSON)
    build: Callable[[BuildContext, Group], Callable[[Any], Any]]  #: the probe, called with the displacement
    facets_only: bool = False                                  #: the group must be a facet group
    prescribed: bool = False                                   #: the group must be clamped or moved

    def check(self, name: str, group: str, mesh: MeshInfo, loads: Mapping[str, Any]) -> Group:
        """The :class:`Group` the probe ``name`` refers to; :class:`SceneError` if the scene cannot provide it."""
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


def _volume(context: BuildContext, group: Group):
    from fenicsfoam.probes import EnclosedVolume
    return EnclosedVolume(context.V, context.tagged.facet_tags, group.tags)


#: Probes of any named group, written ``"KIND:GROUP"`` (GROUP a facet group name, or a region name where allowed):
#: *reaction_force* (N, the force the supports exert on a clamped or moved group, from the residual),
#: *displacement* (m, mean over the group), *rotation* (deg, rotation vector of the group's best-fit rotation),
#: *volume* (m³, enclosed by a closed facet group, deformed). Documented in :mod:`fenicsfoam.probes`.
GROUP_PROBE_KINDS: dict[str, GroupProbeKind] = {
    "reaction_force": GroupProbeKind("N", 3, _reaction_force, prescribed=True),
    "displacement": GroupProbeKind("m", 3, _mean_displacement),
    "rotation": GroupProbeKind("deg", 3, _rotation),
    "volume": GroupProbeKind("m3", 1, _volume, facets_only=True),
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


#: Motion names the scene uses itself (no named load or motion ``[loads.KIND.NAME]`` may take them).
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
    servos = loads.boolean(key, False)
    if servos and mesh.builder != "tripod":
        raise SceneError(f"loads.servos: servo horns need the tripod builder, not {mesh.builder!r}")
    return servos


def _servo_motions(servos: bool, context: BuildContext) -> list:
    """The Tripod's three horns: each carries its arm end rigidly, ``servo0..2`` (angles set by the steps)."""
    from fenicsfoam.bcs import RigidMotion
    from meshes.tripod import ARM_END
    if not servos:
        return []
    tagged = context.tagged
    return [RigidMotion(f"servo{i}", tagged.cell_tags.find(ARM_END[i]), dim=tagged.mesh.topology.dim,
                        axis=tuple(frame.axis), point=tuple(frame.pivot))
            for i, frame in enumerate(tagged.geometry.servo_frames())]


def _named_tables(loads: _Table, key: str, read_one: Callable[[_Table, str], dict]) -> dict[str, dict]:
    table = loads.table(key)
    if table is None:
        return {}
    for name in table.data:  # the scene's own motions are named so too: the steps could not tell them apart
        if name in RESERVED_MOTIONS:
            raise SceneError(f"{table.path}.{name}: the name {name!r} is reserved ({', '.join(RESERVED_MOTIONS)}); "
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


#: The keys of ``[loads]``: ``gravity = [gx, gy, gz]`` (m/s², scaled by the steps' gravity factors), ``clamp =
#: facet tags or a facet group name`` (held fixed), ``servos = true`` (the Tripod's horns, turned by the steps'
#: ``servo_deg``); named loads ``[loads.force.NAME]`` (a total force, N), ``[loads.traction.NAME]`` (a dead
#: traction, Pa), ``[loads.pressure.NAME]`` (a follower pressure, Pa), ``[loads.cable.NAME]`` (a tendon, N), each
#: scaled by the steps' ``loads = {NAME = factor}``; and ``[loads.motion.NAME]`` (a rigid motion of a group, moved
#: by the steps' ``motions``). Definitions: :mod:`fenicsfoam.loads`, :mod:`fenicsfoam.bcs`.
LOAD_KINDS: dict[str, LoadKind] = {
    "gravity": LoadKind(_read_gravity),
    "clamp": LoadKind(_read_clamp, _clamp_motions),
    "servos": LoadKind(_read_servos, _servo_motions),
    "force": LoadKind(_read_surface("force", 3, ""), external=_surface_loads("force"), named=True),
    "traction": LoadKind(_read_surface("traction", 3, ""), external=_surface_loads("traction"), named=True),
    "pressure": LoadKind(_read_surface("pressure", 1, "a pressure (Pa)"), external=_surface_loads("pressure"),
                         named=True),
    "cable": LoadKind(_read_cable, external=_cables, named=True),
    "motion": LoadKind(_read_motion, _motion_motions),
}
