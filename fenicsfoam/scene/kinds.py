"""What a scene may declare besides its mesh and materials: probe kinds and load kinds, one registry each.

``probes = [...]`` names entries of :data:`PROBE_KINDS`; the keys of ``[loads]`` are the entries of
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

from fenicsfoam.scene.table import SceneError, _Table, _tags

__all__ = ["LOAD_KINDS", "PROBES", "PROBE_KINDS", "PROBE_UNITS", "BuildContext", "LoadKind", "MeshInfo", "ProbeKind"]


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


#: The probes a scene may list (documented in :mod:`fenicsfoam.probes`; *tip_deflection* is measured along ``−ĝ``,
#: so a sagging tip is negative; *center_height*, *center_rotation* use the Tripod's probe ring).
PROBE_KINDS: dict[str, ProbeKind] = {
    "tip_deflection": ProbeKind("tip", "m", _tip_deflection, along_gravity=True),
    "center_height": ProbeKind("tripod", "m", _center_height),
    "center_rotation": ProbeKind("tripod", "deg", _center_rotation),
}
#: Probe names and what they need: a facet group named "tip" (the beam's, or a mesh file's) or the Tripod.
PROBES: dict[str, str] = {name: kind.needs for name, kind in PROBE_KINDS.items()}
#: Units of the probe values in summaries (SI, angles in degrees).
PROBE_UNITS: dict[str, str] = {name: kind.unit for name, kind in PROBE_KINDS.items()}


# --------------------------------------------------------------------------------------------------
# Loads
# --------------------------------------------------------------------------------------------------
def _no_motions(value: Any, context: BuildContext) -> list:
    return []


@dataclass(frozen=True)
class LoadKind:
    """A key of ``[loads]``: how its value is read and checked, and the rigid motions it prescribes."""

    read: Callable[[_Table, str, MeshInfo], Any]      #: the validated value (its default when the key is absent)
    motions: Callable[[Any, BuildContext], list] = _no_motions  #: ``fenicsfoam.bcs.RigidMotion`` objects


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


#: The keys of ``[loads]``: ``gravity = [gx, gy, gz]`` (m/s², scaled by the steps' factors), ``clamp = facet tags
#: or a facet group name`` (held fixed), ``servos = true`` (the Tripod's horns, turned by the steps' ``servo_deg``).
LOAD_KINDS: dict[str, LoadKind] = {
    "gravity": LoadKind(_read_gravity),
    "clamp": LoadKind(_read_clamp, _clamp_motions),
    "servos": LoadKind(_read_servos, _servo_motions),
}
