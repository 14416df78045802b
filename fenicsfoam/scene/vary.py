"""Parameters in one form: a parsed scene varied in its regions' values, every variation checked before any work.

Calibration (``E_solid``), uncertainty (the foam ``table`` of every foam region, one per seed) and design (the
material numbers of a built scene) change a scene through :func:`vary_scene`: a new :class:`Scene` whose regions
hold the new values. Nothing is re-parsed and nothing deep-copied; the ``raw`` dict of the new scene shares every
table with the old one but the regions changed (it is the scene as it would be read, so ``summary.json`` records
the variation). Each variation is checked as the schema checks a value (the key's range,
:class:`~fenicsfoam.material.kinds.Key`) and the scene's materials are resolved again
(:func:`fenicsfoam.scene.build.check_materials`), so a value the materials refuse is a :class:`SceneError` naming
``regions.NAME.KEY`` before anything is built.

A parameter is named ``KEY`` (every region whose kind has the key, e.g. ``E_solid``: every foam region) or
``KEY:REGION`` (that region only, e.g. ``density:arms``), the names :mod:`fenicsfoam.design` uses.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from fenicsfoam.material import MATERIAL_KINDS
from fenicsfoam.scene.schema import Region, Scene
from fenicsfoam.scene.table import SceneError
from foambase.errors import InputError

__all__ = ["parameter_regions", "vary_scene"]


def parameter_regions(scene: Scene, name: str) -> list[tuple[Region, str]]:
    """The ``(region, key)`` pairs a parameter ``KEY`` or ``KEY:REGION`` names; :class:`SceneError` if none."""
    key, _, only = name.partition(":")
    pairs = [(r, key) for r in scene.regions
             if MATERIAL_KINDS[r.material].key(key) is not None and (not only or r.name == only)]
    if not pairs:
        keys = sorted({k.name for r in scene.regions for k in MATERIAL_KINDS[r.material].keys})
        regions = ", ".join(f"{r.name} ({r.material})" for r in scene.regions)
        raise SceneError(f"parameter {name!r}: no region of scene {scene.name!r} has it; its regions: {regions}; "
                         f"their keys: {', '.join(keys)} (name a key, or KEY:REGION)")
    return pairs


def _checked(region: Region, key: str, value: Any) -> Any:
    """The value ``value`` of ``region``'s key ``key``, checked in the key's form."""
    kind = MATERIAL_KINDS[region.material]
    spec = kind.key(key)
    path = f"regions.{region.name}"
    if spec.form == "table":
        from homogenization.tables import resolve_table
        try:
            _, file = resolve_table(value)
        except InputError as exc:
            raise SceneError(f"{path}.{key}: {exc}") from exc
        if not Path(file).is_file():
            raise SceneError(f"{path}.{key}: no foam table file {str(file)!r}")
        return str(value)
    if spec.form == "choice":
        if value not in spec.choices:
            raise SceneError(f"{path}.{key}: expected one of {spec.choices}, got {value!r}")
        return value
    try:
        kind.check(path, key, value)
    except InputError as exc:
        raise SceneError(str(exc)) from exc
    return float(value)


def vary_scene(scene: Scene, changes: Mapping[str, Any]) -> Scene:
    """The scene with the region values ``changes`` (``{KEY or KEY:REGION: value}``), every one checked.

    Raises :class:`SceneError` naming ``regions.NAME.KEY`` for a value out of its key's range or refused by the
    material (e.g. a density outside the foam table), or for a parameter no region has, before anything is built.
    """
    changed: dict[str, dict[str, Any]] = {}
    for name, value in changes.items():
        for region, key in parameter_regions(scene, name):
            changed.setdefault(region.name, {})[key] = _checked(region, key, value)
    regions = tuple(dataclasses.replace(r, parameters={**r.parameters, **changed[r.name]}) if r.name in changed
                    else r for r in scene.regions)
    raw_regions = dict(scene.raw.get("regions", {}))
    for name, values in changed.items():
        raw_regions[name] = {**raw_regions[name], **values}
    varied = dataclasses.replace(scene, regions=regions, raw={**scene.raw, "regions": raw_regions})
    from fenicsfoam.scene.build import check_materials
    check_materials(varied)
    return varied
