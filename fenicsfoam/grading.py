"""Graded foam fields: density and γ per cell, resolved through the foam table with their derivatives.

A foam region of a scene may take its relative density and its anisotropy γ as *fields*, one value per cell,
instead of one number (docs/scenes.md, ``[regions.NAME] density``/``gamma`` and ``[[blends]]``):

* a per-tag table (one value per cell tag of the region);
* a callable of the cell midpoints, ``f(points (n, 3)) -> values (n,)``;
* a smooth blend across the boundary between two foam regions A and B of a given width ``w``: with ``s`` the
  signed distance of a cell's midpoint to the A–B interface (negative in A, positive in B) and the C¹
  smoothstep ``S(t) = 3t² − 2t³`` on ``t = clip(1/2 + s/w, 0, 1)``, the weight of B is ``β = S(t)``
  and the cell takes ``density = (1 − β) density_A + β density_B`` and ``log γ = (1 − β) log γ_A + β log γ_B``
  (γ is blended in log space, as the table interpolates it). At ``w = 0`` the weight is the indicator of B:
  the sharp fields. Modelling choice: only density and γ are blended; each cell keeps its own region's fit,
  solid constants and *l* axis.

Every cell's constants are then read from the foam table by the foam kind's per-cell data
(:class:`fenicsfoam.material.foam.FoamCells`: the one interpolation of
:class:`~fenicsfoam.material.table.FoamTable`, with exact derivatives). :class:`CellMaterials` holds the per-cell
data of a whole scene, each region's from its kind (:data:`fenicsfoam.material.MATERIAL_KINDS`), and gives the DG0
moduli, the mass density and their derivatives with respect to density, γ and ``E_solid``, the inputs of
:mod:`fenicsfoam.sensitivity`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence

import numpy as np

from fenicsfoam.material import MATERIAL_KINDS, Isotropic
from fenicsfoam.material.foam import FoamCells
from fenicsfoam.material.moduli import MODULI_NAMES, isotropic_moduli, spencer_moduli
from fenicsfoam.material.table import FoamTable, pchip
from foambase.cells import num_owned_cells
from foambase.errors import InputError
from foambase.imports import import_callable

__all__ = [
    "MODULI_NAMES",
    "CellMaterials",
    "FoamCells",
    "FoamTable",
    "blend_weights",
    "interface_triangles",
    "isotropic_moduli",
    "pchip",
    "point_triangle_distance",
    "smoothstep",
    "spencer_moduli",
]

logger = logging.getLogger(__name__)

# --------------------------------------------------------------------------------------------------
# Per-cell materials of a scene
# --------------------------------------------------------------------------------------------------
class CellMaterials:
    """The materials of every owned cell of a scene: fixed constants, or foam data per cell.

    Parameters
    ----------
    n_cells
        Number of owned cells.
    fixed
        ``{name: (cells, material)}``: regions of explicit :class:`~fenicsfoam.materials.Isotropic` or
        :class:`~fenicsfoam.materials.TransverseIsotropic` constants, on the given owned cells.
    foams
        The foam regions (:class:`FoamCells`).

    Every owned cell must belong to exactly one region. ``isotropic`` is true when every cell's material is
    isotropic (the MaterialField then holds Lamé moduli).

    """

    def __init__(self, n_cells: int, fixed: Mapping[str, tuple[np.ndarray, object]] = (),
                 foams: Sequence[FoamCells] = (), descriptions: Mapping[str, dict] | None = None,
                 blend_weight: Mapping[str, tuple[str, str, np.ndarray]] | None = None):
        self.n_cells = n_cells
        self.fixed = dict(fixed)
        self.foams = {f.name: f for f in foams}
        count = np.zeros(n_cells, dtype=int)
        for cells, _ in self.fixed.values():
            count[np.asarray(cells, dtype=np.int64)] += 1
        for f in self.foams.values():
            count[f.cells] += 1
        if np.any(count != 1):
            raise InputError(f"{int(np.sum(count == 0))} cell(s) have no material and {int(np.sum(count > 1))} "
                             "more than one")
        self.isotropic = (all(isinstance(m, Isotropic) for _, m in self.fixed.values())
                          and all(f.isotropic_cells().all() for f in self.foams.values()))
        #: foam region → {"density": description, "gamma": description} (a number, per-tag table or function)
        self.descriptions = {name: dict(d) for name, d in (descriptions or {}).items()}
        #: foam region in a blend → (A, B, weight of B on the region's cells)
        self.blend_weight = dict(blend_weight or {})

    @classmethod
    def from_regions(cls, mesh, cell_tags, regions: Sequence, materials: Mapping[str, object] | None = None,
                     blends: Sequence[Mapping[str, object]] = ()) -> CellMaterials:
        """The cells of a scene's regions, foam densities and γ resolved per cell.

        ``regions`` are :class:`fenicsfoam.scene.Region`-like (``name, tags, material, parameters``), a foam's
        density and γ a number, a per-tag table or a function (module docstring); ``materials`` gives the
        resolved material of non-foam regions (default: built from their parameters); ``blends`` are
        ``{"regions": (A, B), "width": w}`` between two foam regions whose density and γ are numbers.
        """
        from fenicsfoam.orientation import owned_cell_tags

        tags = owned_cell_tags(mesh, cell_tags)
        fixed, foams, descriptions = {}, [], {}
        for region in regions:
            cells = np.flatnonzero(np.isin(tags, list(region.tags)))
            data = MATERIAL_KINDS[region.material].cells(region.name, cells, region.parameters,
                                                         (materials or {}).get(region.name))
            if isinstance(data, FoamCells):
                descriptions[region.name] = {key: region.parameters[key] for key in ("density", "gamma")}
                foams.append(data)
            else:
                fixed[region.name] = data
        by_name = {f.name: f for f in foams}
        weights = {}
        for blend in blends:
            a, b = blend["regions"]
            for name in (a, b):
                if name not in by_name:
                    raise InputError(f"blend {a!r}–{b!r}: {name!r} is not a foam region")
                if name in weights:
                    raise InputError(f"blend {a!r}–{b!r}: region {name!r} is already in a blend")
                for key in ("density", "gamma"):
                    if not _is_number(descriptions[name][key]):
                        raise InputError(f"blend {a!r}–{b!r}: region {name!r} must give {key} as a number to be "
                                         "blended")
            tags_a = next(r.tags for r in regions if r.name == a)
            tags_b = next(r.tags for r in regions if r.name == b)
            for name in (a, b):
                weights[name] = (a, b, blend_weights(mesh, cell_tags, tags_a, tags_b, float(blend["width"]),
                                                     by_name[name].cells))
        self = cls(tags.size, fixed, foams, descriptions, weights)
        for name in self.foams:
            self.resolve(name, mesh, cell_tags)
        self.isotropic = (all(isinstance(m, Isotropic) for _, m in self.fixed.values())
                          and all(f.isotropic_cells().all() for f in self.foams.values()))
        return self

    def resolve(self, name: str, mesh=None, cell_tags=None) -> None:
        """Recompute the per-cell density and γ of the foam region ``name`` from its descriptions."""
        foam, spec = self.foams[name], self.descriptions[name]
        if name in self.blend_weight:
            a, b, weight = self.blend_weight[name]
            da, db = self.descriptions[a], self.descriptions[b]
            foam.density = (1.0 - weight) * float(da["density"]) + weight * float(db["density"])
            foam.gamma = blend_log(float(da["gamma"]), float(db["gamma"]), weight)
            return
        for key in ("density", "gamma"):
            if _is_number(spec[key]):
                setattr(foam, key, np.full(foam.cells.size, float(spec[key])))
            elif mesh is not None:
                setattr(foam, key, field_values(spec[key], mesh, cell_tags, foam.cells, f"regions.{name}.{key}"))

    def set_region_value(self, key: str, name: str, value: float) -> None:
        """Set the number ``key`` (``"density"`` or ``"gamma"``) of foam region ``name`` and re-resolve the cells."""
        if name not in self.foams or not _is_number(self.descriptions[name][key]):
            raise InputError(f"{key}:{name}: not a foam region whose {key} is a number "
                             f"(foam regions: {sorted(self.foams)})")
        self.descriptions[name][key] = float(value)
        for region in self.foams:
            if region == name or (region in self.blend_weight and name in self.blend_weight[region][:2]):
                self.resolve(region)

    def region_derivative(self, key: str, name: str) -> np.ndarray:
        """``∂(cell density or γ)/∂(region value)`` on every owned cell (zero outside the region and its blend)."""
        out = np.zeros(self.n_cells)
        if name not in self.foams or not _is_number(self.descriptions[name][key]):
            raise InputError(f"{key}:{name}: not a foam region whose {key} is a number "
                             f"(foam regions: {sorted(self.foams)})")
        for region, foam in self.foams.items():
            if region in self.blend_weight and name in self.blend_weight[region][:2]:
                a, _, weight = self.blend_weight[region]
                share = 1.0 - weight if name == a else weight
            elif region == name:
                share = np.ones(foam.cells.size)
            else:
                continue
            value = float(self.descriptions[name][key])
            out[foam.cells] = share if key == "density" else share * foam.gamma / value
        return out

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the DG0 moduli."""
        return MODULI_NAMES[self.isotropic]

    def _fixed_moduli(self, material) -> dict[str, float]:
        if self.isotropic:
            return dict(zip(MODULI_NAMES[True], material.lame))
        return material.spencer_moduli()

    def rho(self) -> np.ndarray:
        """Mass density per cell (kg/m³): the fixed materials' ``rho``, ``rho_solid · density`` of the foams."""
        rho = np.zeros(self.n_cells)
        for cells, material in self.fixed.values():
            rho[np.asarray(cells, dtype=np.int64)] = material.rho
        for f in self.foams.values():
            rho[f.cells] = f.rho_solid * f.density
        return rho

    def moduli(self) -> dict[str, np.ndarray]:
        """The DG0 moduli (Pa) per cell."""
        out = {n: np.zeros(self.n_cells) for n in self.names}
        for cells, material in self.fixed.values():
            for n, v in self._fixed_moduli(material).items():
                out[n][np.asarray(cells, dtype=np.int64)] = v
        for f in self.foams.values():
            values, _, _ = f.moduli(self.isotropic)
            for n in self.names:
                out[n][f.cells] = values[n]
        return out

    def derivatives(self) -> dict[str, dict[str, np.ndarray]]:
        """Per-cell derivatives of the moduli and of ``rho``: with respect to each cell's density and γ.

        Returns ``{"density": {name: (n_cells,)}, "gamma": {...}, "E_solid": {...}}``, the names being the
        moduli and ``"rho"``; ``E_solid`` is the derivative when every foam region's ``E_solid`` changes by the
        same amount (moduli scale linearly with it). Zero on the cells of fixed materials.
        """
        out = {k: {n: np.zeros(self.n_cells) for n in (*self.names, "rho")} for k in ("density", "gamma", "E_solid")}
        for f in self.foams.values():
            values, d_rho, d_gam = f.moduli(self.isotropic, with_derivatives=True)
            for n in self.names:
                out["density"][n][f.cells] = d_rho[n]
                out["gamma"][n][f.cells] = d_gam[n]
                out["E_solid"][n][f.cells] = values[n] / f.E_solid
            out["density"]["rho"][f.cells] = f.rho_solid
        return out

    def material_field(self, mesh, materials: Mapping[int, object] | None = None):
        """The :class:`~fenicsfoam.constitutive.MaterialField` of these cells (DG0 functions on ``mesh``)."""
        from fenicsfoam.constitutive import MaterialField
        from fenicsfoam.orientation import cell_function

        moduli = self.moduli()
        return MaterialField(materials=dict(materials or {}), isotropic=self.isotropic,
                             moduli={n: cell_function(mesh, moduli[n], name=n) for n in self.names},
                             rho=cell_function(mesh, self.rho(), name="rho"))

    def update(self, field) -> None:
        """Write the current per-cell data into an existing MaterialField (its DG0 values; ghosts updated)."""
        from fenicsfoam.orientation import set_cell_values

        moduli = self.moduli()
        for n in self.names:
            set_cell_values(field.moduli[n], moduli[n])
        set_cell_values(field.rho, self.rho())


# --------------------------------------------------------------------------------------------------
# Blends across a region boundary
# --------------------------------------------------------------------------------------------------
def smoothstep(t: np.ndarray) -> np.ndarray:
    """``3t² − 2t³`` on ``clip(t, 0, 1)``: C¹, 0 below 0, 1 above 1."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def interface_triangles(mesh, cell_tags, tags_a: Sequence[int], tags_b: Sequence[int]) -> np.ndarray:
    """Coordinates (k, 3, 3) of the facets shared by a cell tagged in ``tags_a`` and one in ``tags_b``.

    Every rank lists the facets of its owned cells of either set as sorted global vertex triples; the lists are
    gathered on every rank and intersected, so the result is the whole interface on every rank, whatever the
    partition and ghosting (facets are keyed by the input indices of their vertices' geometry nodes).
    Tetrahedral meshes.
    """
    from fenicsfoam.orientation import owned_cell_tags

    tags = owned_cell_tags(mesh, cell_tags)
    x = mesh.geometry.x
    geometry_dofs = mesh.geometry.dofmap
    global_node = np.asarray(mesh.geometry.input_global_indices, dtype=np.int64)

    def faces(selected):
        cells = np.flatnonzero(np.isin(tags, list(selected)))
        if cells.size == 0:
            return np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3, 3))
        nodes = np.array([geometry_dofs.links(c)[:4] for c in cells])  # (n, 4): the vertices' geometry nodes
        keys, coords = [], []
        for drop in range(4):
            keep = [i for i in range(4) if i != drop]
            keys.append(np.sort(global_node[nodes[:, keep]], axis=1))
            coords.append(x[nodes[:, keep]])
        return np.concatenate(keys), np.concatenate(coords)

    comm = mesh.comm
    ka, ca = faces(tags_a)
    kb, _ = faces(tags_b)
    ka_all = np.concatenate(comm.allgather(ka))
    ca_all = np.concatenate(comm.allgather(ca))
    kb_all = np.concatenate(comm.allgather(kb))
    if ka_all.size == 0 or kb_all.size == 0:
        return np.zeros((0, 3, 3))
    view = np.dtype((np.void, ka_all.dtype.itemsize * 3))
    va = np.ascontiguousarray(ka_all).view(view).ravel()
    vb = np.ascontiguousarray(kb_all).view(view).ravel()
    shared = np.isin(va, vb)
    _, first = np.unique(va[shared], return_index=True)
    return ca_all[np.flatnonzero(shared)[first]]


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Distance from each point (n, 3) to the nearest of the triangles (k, 3, 3), exactly (closest-point regions)."""
    points = np.asarray(points, dtype=float)
    out = np.full(points.shape[0], np.inf)
    if triangles.shape[0] == 0:
        return out
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac = b - a, c - a
    for start in range(0, points.shape[0], chunk):
        p = points[start:start + chunk, None, :]
        out[start:start + chunk] = np.sqrt(np.min(_squared_distance(p, a, b, c, ab, ac), axis=1))
    return out


def _squared_distance(p, a, b, c, ab, ac):
    """Squared distance from points p (n, 1, 3) to triangles (k, 3): Ericson's closest point, vectorised."""
    def dot(u, v):
        return np.einsum("...i,...i->...", u, v)

    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    # default: inside the face
    q = a + v_in[..., None] * ab + w_in[..., None] * ac
    regions = [
        ((d1 <= 0) & (d2 <= 0), a + 0 * p),
        ((d3 >= 0) & (d4 <= d3), b + 0 * p),
        ((d6 >= 0) & (d5 <= d6), c + 0 * p),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[..., None] * ab),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[..., None] * ac),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + t_bc[..., None] * (c - b)),
    ]
    decided = np.zeros(q.shape[:-1], dtype=bool)
    for mask, point in regions:
        use = mask & ~decided
        q = np.where(use[..., None], point, q)
        decided |= use
    return dot(p - q, p - q)


def blend_weights(mesh, cell_tags, tags_a: Sequence[int], tags_b: Sequence[int], width: float,
                  cells: np.ndarray | None = None) -> np.ndarray:
    """Weight of region B in the owned ``cells`` (default: all) for a blend of width ``width`` (m), module docstring.

    0 deep in A, 1 deep in B, ``S(1/2 + s/w)`` within ``w/2`` of the interface (``s``: signed distance of the
    cell's midpoint, positive in B); the indicator of B for ``w = 0``. Cells in neither region get the weight
    of their side as if they were in A (callers pass cells of A or B only).
    """
    from dolfinx.mesh import compute_midpoints

    from fenicsfoam.orientation import owned_cell_tags

    if not (np.isfinite(width) and width >= 0):
        raise InputError(f"blend width must be a length >= 0 (m), got {width!r}")
    n = num_owned_cells(mesh)
    cells = np.arange(n) if cells is None else np.asarray(cells, dtype=np.int64)
    in_b = np.isin(owned_cell_tags(mesh, cell_tags)[cells], list(tags_b))
    if width == 0.0:
        return in_b.astype(float)
    triangles = interface_triangles(mesh, cell_tags, tags_a, tags_b)
    if triangles.shape[0] == 0:
        raise InputError(f"regions with tags {list(tags_a)} and {list(tags_b)} share no facet: nothing to blend")
    midpoints = compute_midpoints(mesh, mesh.topology.dim, cells.astype(np.int32))
    s = point_triangle_distance(midpoints, triangles) * np.where(in_b, 1.0, -1.0)
    return smoothstep(0.5 + s / width)


# --------------------------------------------------------------------------------------------------
# Field descriptions of a scene
# --------------------------------------------------------------------------------------------------
def field_values(spec, mesh, cell_tags, cells: np.ndarray, what: str) -> np.ndarray:
    """Per-cell values of a field description on the owned ``cells``.

    ``spec``: a number; ``{"per_tag": {tag: value}}`` (every cell's tag must be listed); or
    ``{"function": "module:name"}``, called with the cells' midpoints (n, 3) and returning (n,) values.
    """
    from dolfinx.mesh import compute_midpoints

    from fenicsfoam.orientation import owned_cell_tags

    if isinstance(spec, int | float) and not isinstance(spec, bool):
        return np.full(cells.size, float(spec))
    if "per_tag" in spec:
        tags = owned_cell_tags(mesh, cell_tags)[cells]
        table = {int(t): float(v) for t, v in spec["per_tag"].items()}
        missing = sorted(set(np.unique(tags).tolist()) - set(table))
        missing = sorted(set().union(*mesh.comm.allgather(set(missing))))
        if missing:
            raise InputError(f"{what}: cell tags {missing} have no value (values given for {sorted(table)})")
        return np.array([table[int(t)] for t in tags])
    from foambase.mpi import on_every_rank

    midpoints = compute_midpoints(mesh, mesh.topology.dim, cells.astype(np.int32))

    def evaluate() -> np.ndarray:
        try:
            f = import_callable(spec["function"]) if isinstance(spec["function"], str) else spec["function"]
        except InputError as exc:
            raise InputError(f"{what}: {exc}") from exc
        try:
            values = np.asarray(f(midpoints))
        except (Exception, SystemExit) as exc:  # the user's function: named, on every rank (it may fail on one)
            raise InputError(f"{what}: {spec['function']}(x) raised {type(exc).__name__}: {exc}") from exc
        if np.iscomplexobj(values):
            raise InputError(f"{what}: the function returned complex values (e.g. {values.ravel()[:1]}); "
                             "it must return real numbers")
        values = np.asarray(values, dtype=float)
        if values.shape != (cells.size,):
            raise InputError(f"{what}: the function must map points ({cells.size}, 3) to values ({cells.size},), "
                             f"got shape {values.shape}")
        return values
    return on_every_rank(mesh.comm, evaluate, f"{what}: the function failed")


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def blend_log(a: float, b: float, weight: np.ndarray) -> np.ndarray:
    """``exp((1 − β) log a + β log b)`` (exactly ``a`` where β = 0 and ``b`` where β = 1)."""
    weight = np.asarray(weight, dtype=float)
    mixed = np.exp((1.0 - weight) * math.log(a) + weight * math.log(b))
    return np.where(weight == 0.0, a, np.where(weight == 1.0, b, mixed))
