"""The registry of material kinds: each declares its scene keys and their checks, its resolver and its per-cell data.

A region of a scene names its kind (``[regions.NAME] material = "foam"``); everything the code does with a region
is looked up here, so that a new kind is one entry of :data:`MATERIAL_KINDS`:

* the schema (:mod:`fenicsfoam.scene.schema`) reads the kind's :attr:`MaterialKind.keys`, each with its form
  (a number, a graded field, a modulus that may come from a calibration, a choice, a foam table) and its check;
* the builder (:mod:`fenicsfoam.scene.build`) resolves a region's parameters into a material with
  :attr:`MaterialKind.resolve` before meshing (every value checked);
* the per-cell materials (:class:`fenicsfoam.grading.CellMaterials`) take the kind's per-cell data from
  :attr:`MaterialKind.cells`: a fixed material on the region's cells, or per-cell data with derivatives
  (:class:`~fenicsfoam.material.foam.FoamCells`);
* calibration, uncertainty and design act on the kinds whose constants come from the foam table
  (:attr:`MaterialKind.tabulated`: a solid modulus ``E_solid`` and a ``table``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fenicsfoam.material.constants import MAX_MODULUS, Isotropic, Material, TransverseIsotropic
from fenicsfoam.material.table import FOAM_FITS
from foambase.errors import InputError

__all__ = ["GRADED_KEYS", "MATERIAL_KINDS", "Key", "MaterialKind", "tabulated_regions"]

#: Key forms: a number; a field (a number, a per-tag table or a function of the cell midpoints); a modulus (a number
#: or ``{calibration = "calibration.json"}``); one of ``choices``; a foam table (a shipped name or a ``.csv`` path).
FORMS = ("number", "field", "modulus", "choice", "table")


@dataclass(frozen=True)
class Key:
    """A key of a region of the kind: ``[regions.NAME] <name> = ...``."""

    name: str
    required: bool = True
    default: Any = None
    check: Callable[[float], bool] | None = None  #: range check of a number (the materials check admissibility)
    valid: str = ""                               #: what the check accepts, for the error message
    form: str = "number"                          #: one of :data:`FORMS`
    choices: tuple[str, ...] = ()                 #: the values of a ``choice``


@dataclass(frozen=True)
class MaterialKind:
    """A material kind: its keys, its resolver and its per-cell data.

    ``resolve(parameters)`` is the material of a region (its parameters as the schema read them); it raises
    :class:`~homogenization.tensors.InadmissibleMaterialError` or :class:`~foambase.errors.InputError` for values
    the material refuses. ``cells(name, cells, parameters, material)`` is the region's per-cell data on the owned
    ``cells``: the fixed ``material``, or an object with per-cell moduli and their derivatives
    (:class:`~fenicsfoam.material.foam.FoamCells`). ``tabulated``: the constants come from the foam table.
    """

    name: str
    keys: tuple[Key, ...]
    resolve: Callable[[Mapping[str, Any]], Material]
    cells: Callable[[str, np.ndarray, Mapping[str, Any], Material | None], Any]
    tabulated: bool = False

    def key(self, name: str) -> Key | None:
        """The key ``name`` of the kind, or ``None``."""
        return next((k for k in self.keys if k.name == name), None)

    def check(self, path: str, name: str, value: Any) -> None:
        """Raise :class:`InputError` if the number ``value`` of key ``name`` fails its check (``path``: the region)."""
        key = self.key(name)
        if key is None:
            raise InputError(f"{path}: a {self.name} region has no key {name!r}; its keys: "
                             f"{', '.join(k.name for k in self.keys)}")
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise InputError(f"{path}.{name}: expected a finite number, got {value!r}")
        if key.check is not None and not key.check(value):
            raise InputError(f"{path}.{name}: {value!r} is not {key.valid}")


def _positive(name: str, required: bool = True, form: str = "number") -> Key:
    """A modulus (Pa): ``0 < value <= MAX_MODULUS`` (larger is a typo or a unit error, and overflows)."""
    return Key(name, required, check=lambda v: 0 < v <= MAX_MODULUS, valid=f"a modulus in (0, {MAX_MODULUS:g}] Pa",
               form=form)


def _density(name: str) -> Key:
    return Key(name, False, 0.0, check=lambda v: v >= 0, valid="a density >= 0 (kg/m³)")


def _fixed_cells(name: str, cells: np.ndarray, parameters: Mapping[str, Any], material: Material | None,
                 kind: type) -> tuple[np.ndarray, Material]:
    """A region of explicit constants: the same material on all its cells."""
    material = kind(**parameters) if material is None else material
    if not isinstance(material, Isotropic | TransverseIsotropic):
        raise InputError(f"expected Isotropic or TransverseIsotropic, got {material!r}")
    return cells, material


# --------------------------------------------------------------------------------------------------
# The foam kind: a region resolved before meshing, then per cell
# --------------------------------------------------------------------------------------------------
#: Keys of a foam region that may be fields (a per-tag table or a function of the cell midpoints).
GRADED_KEYS = ("density", "gamma")


def representative(spec, key: str) -> float:
    """The value of a foam field that stands for its region before meshing (its material's kind, the summary).

    The number, a per-tag table's first value, or for a function the middle of the foam table's range
    (arithmetic for density, geometric for γ).
    """
    if not isinstance(spec, dict):
        return spec
    if "per_tag" in spec:
        return next(iter(spec["per_tag"].values()))
    from fenicsfoam.material.table import foam_table
    lo, hi = getattr(foam_table(), f"{key}_range")
    return 0.5 * (lo + hi) if key == "density" else math.sqrt(lo * hi)


def _resolve_foam(parameters: Mapping[str, Any]) -> Material:
    """The foam's material at its representative (density, γ); every per-tag value is checked against the table.

    Reads ``fenicsfoam.materials.foam_material`` when called (the seam through which the tables are provided).
    """
    from fenicsfoam import materials

    foam_material = getattr(materials, "foam_material", None)
    if foam_material is None:
        raise InputError("foam regions need fenicsfoam.materials.foam_material (the homogenized tables), which this "
                         "installation lacks; use explicit constants")
    params = dict(parameters)
    density, gamma = (representative(params.pop(key), key) for key in GRADED_KEYS)
    options = {k: params[k] for k in ("rho_solid", "fit", "table") if k in params}
    for key in GRADED_KEYS:  # every per-tag value is checked against the table before meshing
        spec = parameters[key]
        for value in spec.get("per_tag", {}).values() if isinstance(spec, dict) else ():
            foam_material(value if key == "density" else density, value if key == "gamma" else gamma,
                          params["E_solid"], params["nu_solid"], **options)
    return foam_material(density, gamma, params.pop("E_solid"), params.pop("nu_solid"), **params)


def _foam_cells(name: str, cells: np.ndarray, parameters: Mapping[str, Any], material: Material | None):
    """A foam region's per-cell data, density and γ still to be resolved (:meth:`CellMaterials.resolve`)."""
    from fenicsfoam.material.foam import FoamCells

    p = {k: v for k, v in parameters.items() if k not in GRADED_KEYS}
    return FoamCells(name, cells, 0.0, 1.0, **p)


#: The material kinds: ``[regions.NAME] material`` → :class:`MaterialKind`.
MATERIAL_KINDS: dict[str, MaterialKind] = {
    "isotropic": MaterialKind(
        "isotropic",
        (_positive("E"), Key("nu", check=lambda v: -1 < v < 0.5, valid="-1 < nu < 0.5"), _density("rho")),
        lambda p: Isotropic(**p), lambda n, c, p, m: _fixed_cells(n, c, p, m, Isotropic)),
    "transverse_isotropic": MaterialKind(
        "transverse_isotropic",
        (_positive("E_t"), _positive("E_l"), Key("nu_t", check=lambda v: -1 < v < 1, valid="-1 < nu_t < 1"),
         Key("nu_tl"), _positive("G_l"), _density("rho")),
        lambda p: TransverseIsotropic(**p), lambda n, c, p, m: _fixed_cells(n, c, p, m, TransverseIsotropic)),
    "foam": MaterialKind(
        "foam",
        (Key("density", check=lambda v: 0 < v <= 1, valid="a relative density in (0, 1]", form="field"),
         Key("gamma", check=lambda v: 0 < v <= 1, valid="an anisotropy ratio in (0, 1] (1: isotropic)",
             form="field"),
         _positive("E_solid", form="modulus"),
         Key("nu_solid", check=lambda v: -1 < v < 0.5, valid="-1 < nu_solid < 0.5"),
         _density("rho_solid"),
         Key("fit", False, "transverse", form="choice", choices=FOAM_FITS),
         Key("table", False, form="table")),
        _resolve_foam, _foam_cells, tabulated=True),
}


def tabulated_regions(regions) -> list:
    """The regions whose constants come from the foam table (:attr:`MaterialKind.tabulated`)."""
    return [r for r in regions if MATERIAL_KINDS[r.material].tabulated]
