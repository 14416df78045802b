"""Periodic stochastic Voronoi strut foams in a periodic box: geometry, radius from density, voxels, surface.

Model (docs/conventions.md, paper §II-A)
----------------------------------------
* **Box**: the periodic RVE ``[0, L1) × [0, L2) × [0, L3)``; by default the unit cube. ``box="equiaxed"`` is
  ``(γ, 1, 1)``: the box follows the cells, which are flattened by γ along x, so that a given number of cells
  puts the same number of them across every direction (see "RVE box" below).
* **Seeds**: ``n_cells`` points drawn uniformly in the box by ``numpy.random.default_rng(seed)``
  (``rng.random((n_cells, 3)) * box``; for the unit cube exactly the historical seeds).
* **Anisotropy**: the Voronoi diagram under the metric ``|p - q|_γ² = (Δx/γ)² + Δy² + Δz²``, i.e. the
  isotropic Voronoi diagram of the seeds in the box stretched by ``1/γ`` along x, mapped back by ``x → γ x``.
  For ``γ < 1`` cells are flattened along x and the struts lie mostly in y–z.
* **Periodicity**: the diagram is computed with the seeds' periodic images (a ``(2m+1)³`` tiling of the
  stretched box, ``m = 1`` unless a Voronoi vertex's empty sphere reaches outside the tiling, then ``m = 2, 3``),
  and every Voronoi edge of a central cell is kept once modulo the lattice ``L1 ℤ × L2 ℤ × L3 ℤ``.
* **Struts**: the union of cylinders of radius ``r`` along the edges and spheres of radius ``r`` at the
  vertices, which is exactly the set ``{p : dist(p, E) ≤ r}`` with ``E`` the periodic union of edge segments.
  The solid fraction ``φ(r) = |{p ∈ box : dist(p, E) ≤ r}| / |box|`` is therefore monotone in ``r``.
* **Radius**: ``φ(r)`` is estimated on a fixed randomised quasi-Monte-Carlo sample of the box (scrambled Sobol',
  ``DENSITY_SAMPLE_REPLICATES`` independent scramblings of ``2**DENSITY_SAMPLE_LOG2`` points, the same for every
  foam and independent of any voxel resolution). ``r`` is the ``density``-quantile of the sampled distances,
  which is the exact root of the sampled equation ``φ̂(r) = density`` that a bisection would approximate.
  Its standard error is estimated from the spread of the replicates (``density_stderr``, ≈ 2e-4 at
  ``density = 0.18``).

Valid densities (a modelling choice, see :func:`VoronoiFoam.density_range`)
--------------------------------------------------------------------------
* Low end, printability: the strut diameter must be at least ``MIN_DIAMETER_TO_STRUT_LENGTH`` times the mean
  strut length (thinner struts are too slender to print with a fused-filament nozzle at the cell sizes of the
  paper and are not resolved by voxel solvers at practical resolutions).
* High end, open cells: the foam stops being a strut foam when its windows (Voronoi faces) close. A window
  closes when ``r`` reaches its inradius (the struts on its edges touch across it). The largest valid radius is
  the ``MAX_CLOSED_WINDOW_FRACTION``-quantile of the window inradii.

RVE box
-------
In the unit cube, ``n`` cells flattened by γ along x leave about ``(γ n)^(1/3)`` cells across y and z: at
γ = 0.1 and 8 cells about one, so the struts run straight across the period and the RVE measures itself, not
the foam. In the metric ``(Δx/γ, Δy, Δz)`` that makes the cells equiaxed, the box ``(γ, 1, 1)`` is a cube,
so ``box="equiaxed"`` with ``n = m³`` cells puts about ``m`` cells across every direction, for every γ. Voxels
stay cubic by default: the grid is ``(N1, N2, N3) = N (L1, L2, L3) / max(L)`` (see :meth:`VoronoiFoam.grid_shape`);
an explicit grid with ``cubic=False`` accepts non-cubic voxels.

Flat cells
----------
For small ``gamma`` with few cells in the unit cube the stretched cells are wider than the cube's y–z period, and
a cell meets its own periodic images: the diagram then does not close within a 7³ tiling and
:class:`FoamParameterError` names gamma, n_cells and the bound ``n_cells ≳ 1/gamma``. That bound is what was
observed, not a theorem (six seeds: gamma = 0.05 builds 6/6 with 20 cells, 4/6 with 14, 0/6 with 8; gamma = 0.02
builds 4/6 with 50, 1/6 with 35). An equiaxed box has no such bound.

Degenerate diagrams
-------------------
Voronoi vertices closer than ``VERTEX_MERGE_TOL`` times the mean cell size (numerically coincident vertices
that Qhull emits for 5 or more co-spherical seeds, e.g. seeds on a lattice) are merged into one; edges that
become zero-length are dropped and duplicates are kept once. Struts shorter than that are geometrically
irrelevant (they lie inside the joint sphere).
"""

from __future__ import annotations

import functools
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import QhullError, Voronoi, cKDTree
from scipy.stats import qmc

from foambase.errors import ComputationError
from meshes.errors import FoamParameterError
from meshes.gauge import GaugeWalls, Polytope, default_polytope
from meshes.rve import RVEMesh, mesh_rve  # the RVE mesher of a foam (meshes.rve), under its public path

__all__ = [
    "DENSITY_SAMPLE_LOG2",
    "DENSITY_SAMPLE_REPLICATES",
    "DISTANCES",
    "MAX_CLOSED_WINDOW_FRACTION",
    "MAX_WALL_DENSITY",
    "MIN_DIAMETER_TO_STRUT_LENGTH",
    "MIN_WALL_TO_CELL",
    "STRUT_SHAPES",
    "FoamParameterError",
    "FoamSummary",
    "Polytope",
    "RVEMesh",
    "VoronoiFoam",
    "default_polytope",
    "mesh_rve",
    "strut_distance",
]

log = logging.getLogger(__name__)

#: Solid elements: round struts along the Voronoi edges (cylinders with spherical joints, the Euclidean foam) or
#: walls along the Voronoi faces, one printed track wide in every layer (the polyhedral foam).
STRUT_SHAPES = ("cylinder", "wall")
#: Voronoi distances: the Euclidean one (stretched by 1/γ along x) or the gauge of a convex polytope
#: (:func:`meshes.gauge.default_polytope` for ``"polyhedral"``, or any :class:`meshes.gauge.Polytope`).
DISTANCES = ("euclidean", "polyhedral")
#: Low end of the valid densities of wall foams: wall width ≥ this fraction of the mean cell size (V/n)^(1/3).
MIN_WALL_TO_CELL = 0.01
#: High end of the valid densities of wall foams: beyond half solid the walls are no longer thin printed tracks
#: between pores (at γ = 1 the wall width is then ~0.3 of the cell size).
MAX_WALL_DENSITY = 0.5
#: Low end of the valid densities: strut diameter ≥ this fraction of the mean strut length.
MIN_DIAMETER_TO_STRUT_LENGTH = 0.1
#: High end of the valid densities: at most this fraction of the windows (Voronoi faces) closed.
MAX_CLOSED_WINDOW_FRACTION = 0.5
#: Density sample: ``DENSITY_SAMPLE_REPLICATES`` scrambled Sobol' sets of ``2**DENSITY_SAMPLE_LOG2`` points.
DENSITY_SAMPLE_LOG2 = 16
DENSITY_SAMPLE_REPLICATES = 8
_DENSITY_SAMPLE_SEED = 20200
#: Voronoi vertices closer than this fraction of the mean cell size are merged.
VERTEX_MERGE_TOL = 1e-6
#: Points sampled along each strut for the distance search, per strut radius (spacing = radius / this).
_SAMPLES_PER_RADIUS = 2.0
_CHUNK = 1 << 16


@dataclass(frozen=True)
class FoamSummary:
    """Orientation statistics of a foam's solid elements.

    Struts (``strut="cylinder"``): ``n_struts``, ``mean_strut_length`` and ``mean_abs_cos[a] = mean_e |t_e · e_a|``
    (unweighted, each strut once; ``t_e`` the unit strut direction): an isotropic foam has about
    ``(1/2, 1/2, 1/2)``, a foam with struts in the y–z plane ``mean_abs_cos[0] → 0``.

    Walls (``strut="wall"``): ``n_struts = 0``, ``mean_strut_length = nan``, ``mean_abs_cos[a]`` the area-weighted
    mean ``|n · e_a|`` of the wall normals ``n`` (walls normal to x have ``mean_abs_cos[0] → 1``),
    ``wall_area_per_volume`` and ``max_overhang_deg`` (largest angle of a wall from the vertical, build direction z).

    Both: ``fabric``, the length- (struts) or area-weighted (walls) second moment of the material directions,
    ``Σ l t⊗t / Σ l`` for struts and ``Σ A (I − n⊗n)/2 / Σ A`` for walls (trace 1; isotropic ``I/3``):
    ``fabric[0][0]`` is the share of the load-carrying material directed along x.
    """

    n_struts: int
    mean_strut_length: float
    mean_abs_cos: tuple[float, float, float]
    fabric: tuple = ((1 / 3, 0.0, 0.0), (0.0, 1 / 3, 0.0), (0.0, 0.0, 1 / 3))
    wall_area_per_volume: float = float("nan")
    max_overhang_deg: float = float("nan")

    def as_dict(self) -> dict[str, float]:
        """Flat dictionary (for tables and CSV rows)."""
        cx, cy, cz = self.mean_abs_cos
        f = np.asarray(self.fabric)
        return {"n_struts": self.n_struts, "mean_strut_length": self.mean_strut_length,
                "mean_abs_cos_x": cx, "mean_abs_cos_y": cy, "mean_abs_cos_z": cz,
                "fabric_xx": float(f[0, 0]), "fabric_yy": float(f[1, 1]), "fabric_zz": float(f[2, 2]),
                "wall_area_per_volume": self.wall_area_per_volume, "max_overhang_deg": self.max_overhang_deg}


# --------------------------------------------------------------------------------------------------
# Periodic Voronoi diagram
# --------------------------------------------------------------------------------------------------
def _lattice(m: int) -> np.ndarray:
    """Integer shifts ``{-m..m}³`` as a (K, 3) array, the zero shift first."""
    r = np.arange(-m, m + 1)
    shifts = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    return shifts[np.argsort(np.abs(shifts).sum(axis=1), kind="stable")]


def _wrap(x: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``x mod box`` into ``[0, box)`` (``np.mod`` may round a tiny negative up to ``box`` itself)."""
    w = np.mod(x, box)
    return np.where(w >= box, 0.0, w)


def _ordered_polygon(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Order the vertices of a planar convex polygon by angle about its centroid (returns a permutation)."""
    normal = normal / np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    rel = points - points.mean(axis=0)
    return np.argsort(np.arctan2(rel @ e2, rel @ e1))


def _too_flat(gamma: float, n: int, box: np.ndarray, stretched_box: np.ndarray) -> FoamParameterError:
    """The error for cells so flat that the periodic Voronoi diagram of the stretched seeds cannot be built."""
    # flat cells: stretched by 1/gamma, a cell wider than the y–z period touches its own images
    width = (np.prod(stretched_box) / n) ** (1.0 / 3.0) / min(stretched_box[1:])
    cells = math.ceil(1.0 / gamma) if gamma > 1e-9 else f"{1.0 / gamma:.3g}"
    return FoamParameterError(
        f"gamma={gamma} is too flat for n_cells={n} in the box {tuple(box.tolist())}: in the stretched metric "
        f"the mean cell width is {width:.3g} × the box's y–z period, and the periodic Voronoi diagram of these "
        f"seeds does not close within a 7³ tiling of images; use n_cells ≥ about 1/gamma = "
        f"{cells} in the unit cube (seed-dependent near that bound), or box='equiaxed'")


def _periodic_voronoi(seeds: np.ndarray, gamma: float, box: np.ndarray):
    """Voronoi diagram of periodic seeds under the γ-metric: canonical vertices, edges and windows.

    Returns ``(vertices, edges, windows)`` in the original (box) coordinates: ``vertices`` (V, 3) in the box;
    ``edges`` (E, 2, 3) endpoint pairs, the first in the box, the second its lattice-consistent partner;
    ``windows`` a list of (k, 3) ordered polygons, each face once modulo the lattice.
    """
    n = len(seeds)
    scale = np.array([gamma, 1.0, 1.0])
    stretch = np.array([1.0 / gamma, 1.0, 1.0])
    stretched_box = box * stretch
    stretched = seeds * stretch
    cell_size = (np.prod(stretched_box) / n) ** (1.0 / 3.0)
    for m in (1, 2, 3):
        shifts = _lattice(m)
        points = (stretched[None] + shifts[:, None] * stretched_box).reshape(-1, 3)
        try:
            vor = Voronoi(points)
        except QhullError as exc:  # e.g. gamma = 1e-300: the stretched seeds are degenerate in double precision
            raise _too_flat(gamma, n, box, stretched_box) from exc
        # ridges (faces) of the central cells, each once modulo the lattice
        rp = vor.ridge_points
        tile, cell = np.divmod(rp, n)
        rel = shifts[tile[:, 1]] - shifts[tile[:, 0]]
        central = (tile == 0).any(axis=1)
        swap = (cell[:, 0] > cell[:, 1]) | ((cell[:, 0] == cell[:, 1]) & (_lex_sign(rel) < 0))
        key = np.column_stack([np.where(swap, cell[:, 1], cell[:, 0]), np.where(swap, cell[:, 0], cell[:, 1]),
                               np.where(swap[:, None], -rel, rel)])
        ridge_ids = np.flatnonzero(central)
        _, first = np.unique(key[ridge_ids], axis=0, return_index=True)
        ridge_ids = ridge_ids[np.sort(first)]
        polys = [np.asarray(vor.ridge_vertices[i]) for i in ridge_ids]
        used = np.unique(np.concatenate(polys))
        if used[0] >= 0:
            v = vor.vertices[used]
            radius = cKDTree(points).query(v)[0]
            if (np.all(v - radius[:, None] > -m * stretched_box)
                    and np.all(v + radius[:, None] < (m + 1) * stretched_box)):
                break
        log.debug("periodic Voronoi: a %d³ tiling is not enough, enlarging", 2 * m + 1)
    else:
        raise _too_flat(gamma, n, box, stretched_box)

    # merge numerically coincident vertices modulo the lattice
    wrapped = _wrap(vor.vertices[used], stretched_box)
    pairs = cKDTree(wrapped, boxsize=stretched_box).query_pairs(VERTEX_MERGE_TOL * cell_size, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(used),) * 2)
    _, label = connected_components(graph, directed=False)
    _, rep = np.unique(label, return_index=True)        # lowest-index member represents each cluster
    canonical = wrapped[rep]
    lookup = np.full(len(vor.vertices), -1)
    lookup[used] = np.arange(len(used))
    v_label = label[lookup[used]]
    v_shift = np.rint((vor.vertices[used] - canonical[v_label]) / stretched_box).astype(int)

    # edges: consecutive vertices of the ordered face polygons, keyed modulo the lattice
    edge_keys, windows = [], []
    for i, poly in zip(ridge_ids, polys):
        a, b = vor.ridge_points[i]
        poly = poly[_ordered_polygon(vor.vertices[poly], points[b] - points[a])]
        k = lookup[poly]
        edge_keys.append(np.column_stack([v_label[k], np.roll(v_label[k], -1),
                                          v_shift[np.roll(k, -1)] - v_shift[k]]))
        # the window polygon without merged duplicates, in original coordinates
        distinct = np.flatnonzero((v_label[k] != np.roll(v_label[k], -1)) | np.any(
            v_shift[k] != v_shift[np.roll(k, -1)], axis=1))
        if len(distinct) >= 3:
            windows.append(vor.vertices[poly[distinct]] * scale)
    keys = np.concatenate(edge_keys)
    swap = (keys[:, 0] > keys[:, 1]) | ((keys[:, 0] == keys[:, 1]) & (_lex_sign(keys[:, 2:]) < 0))
    keys = np.where(swap[:, None], np.column_stack([keys[:, 1], keys[:, 0], -keys[:, 2:]]), keys)
    keys = keys[(keys[:, 0] != keys[:, 1]) | np.any(keys[:, 2:] != 0, axis=1)]   # zero-length edges
    keys = np.unique(keys, axis=0)

    vertices = canonical * scale
    edges = np.stack([vertices[keys[:, 0]], vertices[keys[:, 1]] + keys[:, 2:] * box], axis=1)
    n_merged = len(used) - len(canonical)
    if n_merged:
        log.debug("periodic Voronoi: merged %d coincident vertex images", n_merged)
    return vertices, edges, windows


def _lex_sign(v: np.ndarray) -> np.ndarray:
    """Sign of the first non-zero component of each row (0 for zero rows)."""
    v = np.asarray(v)
    nz = v != 0
    first = np.argmax(nz, axis=1)
    return np.sign(v[np.arange(len(v)), first]) * nz.any(axis=1)


def _window_inradius(polygon: np.ndarray) -> float:
    """Inradius of a planar convex polygon: ``max_c min_i dist(c, edge line i)`` (a linear programme).

    With unit in-plane outward edge normals ``n_i`` through vertices ``p_i``: maximise ``t`` subject to
    ``n_i · c + t ≤ n_i · p_i``.
    """
    centre = polygon.mean(axis=0)
    _, _, vt = np.linalg.svd(polygon - centre)
    p2 = (polygon - centre) @ vt[:2].T
    edge = np.roll(p2, -1, axis=0) - p2
    normal = np.column_stack([edge[:, 1], -edge[:, 0]])
    length = np.linalg.norm(normal, axis=1)
    keep = length > 0
    normal = normal[keep] / length[keep, None]
    offset = np.einsum("ij,ij->i", normal, p2[keep])
    if np.mean(offset) < 0:          # clockwise polygon: the normals point inwards
        normal, offset = -normal, -offset
    res = linprog([0.0, 0.0, -1.0], A_ub=np.column_stack([normal, np.ones(len(normal))]), b_ub=offset,
                  bounds=[(None, None), (None, None), (0.0, None)], method="highs")
    if res.status != 0:  # pragma: no cover - a convex polygon always has a Chebyshev centre
        raise ComputationError(f"window inradius LP failed: {res.message}")
    return float(res.x[2])


# --------------------------------------------------------------------------------------------------
# Periodic distance to the strut network
# --------------------------------------------------------------------------------------------------
class _StrutDistance:
    """Exact periodic distance from points to the nearest of a set of segments.

    The segments are sampled at spacing ``≤ s`` (endpoints included) and the samples put in a periodic KD-tree.
    With ``d_s`` the distance to the nearest sample, the true distance satisfies
    ``sqrt(max(d_s² - s²/4, 0)) ≤ d ≤ d_s``, and the nearest segment has a sample within
    ``ρ = sqrt(d_s² + s²/4)``; the exact distance is the minimum of the point–segment distances
    over the segments of all samples within ``ρ`` (found by k-nearest queries, doubling ``k`` until the
    ``k``-th neighbour lies beyond ``ρ``).
    """

    def __init__(self, edges: np.ndarray, spacing: float, box: np.ndarray | None = None):
        self.box = np.ones(3) if box is None else np.asarray(box, dtype=float)
        self.a = edges[:, 0]
        self.d = edges[:, 1] - edges[:, 0]
        self.dd = np.einsum("ij,ij->i", self.d, self.d)
        n_int = np.maximum(np.ceil(np.sqrt(self.dd) / spacing).astype(int), 1)
        self.segment = np.repeat(np.arange(len(edges)), n_int + 1)
        first = np.repeat(np.cumsum(n_int + 1) - (n_int + 1), n_int + 1)
        t = (np.arange(len(self.segment)) - first) / n_int[self.segment]
        self.samples = self.a[self.segment] + t[:, None] * self.d[self.segment]
        self.spacing = float(np.max(np.sqrt(self.dd) / n_int))
        self.tree = cKDTree(_wrap(self.samples, self.box), boxsize=self.box)

    def nearest_sample(self, x: np.ndarray, upper: float = np.inf) -> np.ndarray:
        """Distance ``d_s`` to the nearest sample (``inf`` beyond ``upper``), in chunks."""
        out = np.empty(len(x))
        for i in range(0, len(x), _CHUNK):
            out[i:i + _CHUNK] = self.tree.query(x[i:i + _CHUNK], distance_upper_bound=upper)[0]
        return out

    def lower_bound(self, d_s: np.ndarray) -> np.ndarray:
        """Lower bound of the exact distance given the nearest-sample distance."""
        return np.sqrt(np.maximum(d_s**2 - 0.25 * self.spacing**2, 0.0))

    def exact(self, x: np.ndarray) -> np.ndarray:
        """Exact periodic distance from the points ``x`` (in the box) to the nearest segment."""
        out = np.empty(len(x))
        for i in range(0, len(x), _CHUNK):
            out[i:i + _CHUNK] = self._exact_chunk(x[i:i + _CHUNK])
        return out

    def _exact_chunk(self, x: np.ndarray, foot: bool = False):
        out = np.empty(len(x))
        feet = np.empty_like(x) if foot else None
        todo = np.arange(len(x))
        k = 16
        while todo.size:
            k = min(k, self.tree.n)
            dist, idx = self.tree.query(x[todo], k=k)
            rho = np.sqrt(dist[:, 0] ** 2 + 0.25 * self.spacing**2)
            # p - shift is the image next to a sample
            shift = np.rint((x[todo][:, None, :] - self.samples[idx]) / self.box) * self.box
            seg = self.segment[idx]
            rel = x[todo][:, None, :] - shift - self.a[seg]
            t = np.clip(np.einsum("ijk,ijk->ij", rel, self.d[seg]) / self.dd[seg], 0.0, 1.0)
            dseg = np.linalg.norm(rel - t[..., None] * self.d[seg], axis=-1)
            best = np.argmin(dseg, axis=1)
            done = (dist[:, -1] > rho) | (k == self.tree.n)
            rows = np.arange(len(todo))
            out[todo[done]] = dseg[rows, best][done]
            if foot:
                b = (rows, best)
                q = self.a[seg[b]] + t[b][:, None] * self.d[seg[b]] + shift[b]
                feet[todo[done]] = q[done]
            todo = todo[~done]
            k *= 2
        return (out, feet) if foot else out

    def closest(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact distance and the nearest point of the segment network (the image next to ``x``)."""
        d, q = np.empty(len(x)), np.empty_like(x)
        for i in range(0, len(x), _CHUNK):
            d[i:i + _CHUNK], q[i:i + _CHUNK] = self._exact_chunk(x[i:i + _CHUNK], foot=True)
        return d, q


def strut_distance(edges: np.ndarray, points: np.ndarray, spacing: float, box=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Exact periodic distance from ``points`` (M, 3) in the box to the nearest segment of ``edges`` (E, 2, 3).

    ``spacing`` is the sampling step of the internal search (any positive value gives the exact result;
    about half the strut radius is fastest); ``box`` the periodic box lengths (default the unit cube).
    """
    box = np.asarray(box, dtype=float)
    return _StrutDistance(np.asarray(edges, dtype=float), spacing, box).exact(np.asarray(points, dtype=float))


@functools.lru_cache(maxsize=1)
def _density_sample() -> np.ndarray:
    """The fixed RQMC sample of the unit cube: (replicates, 2**log2, 3), the same for every foam.

    A foam in a box scales it by the box lengths.
    """
    return np.stack([qmc.Sobol(3, scramble=True, seed=_DENSITY_SAMPLE_SEED + k).random_base2(DENSITY_SAMPLE_LOG2)
                     for k in range(DENSITY_SAMPLE_REPLICATES)])


def _voxel_centres(shape: tuple[int, int, int], box: np.ndarray, i0: int, i1: int) -> np.ndarray:
    """Centres ``((i+½) L1/N1, (j+½) L2/N2, (k+½) L3/N3)`` of the voxel slab ``i0 ≤ i < i1``, C order, (·, 3)."""
    c = [(np.arange(n) + 0.5) / n * length for n, length in zip(shape, box)]
    return np.stack(np.meshgrid(c[0][i0:i1], c[1], c[2], indexing="ij"), axis=-1).reshape(-1, 3)


# --------------------------------------------------------------------------------------------------
# The foam
# --------------------------------------------------------------------------------------------------
class VoronoiFoam:
    """A periodic stochastic Voronoi foam in a periodic box (see the module docstring).

    Parameters
    ----------
    n_cells
        Number of Voronoi cells (seeds), ≥ 2.
    density
        Target solid volume fraction; must lie in :attr:`density_bounds` (a clear error gives that range).
    gamma
        Degree of anisotropy in ``(0, 1]``; 1 is isotropic. Euclidean distance: the Voronoi metric stretches x by
        ``1/gamma``. Polyhedral distance: the polytope is shrunk by ``gamma`` along x. Either way cells are flattened
        along x. In the unit cube flat cells need enough of them (about ``n_cells ≥ 1/gamma``); ``box="equiaxed"``
        has no such bound.
    seed
        Seed of ``numpy.random.default_rng`` for the cell seeds (same seed → bitwise identical foam).
    strut
        Solid elements, one of :data:`STRUT_SHAPES`: ``"cylinder"`` (struts along the Voronoi edges, the default of
        the Euclidean distance) or ``"wall"`` (walls along the Voronoi faces, the default and only element of the
        polyhedral distance: see :mod:`meshes.gauge` for the fabrication argument).
    box
        The periodic box: ``None`` (the unit cube), ``"equiaxed"`` (``(gamma, 1, 1)``: about ``n_cells^(1/3)``
        cells across every direction) or three positive lengths ``(L1, L2, L3)``.
    distance
        ``"euclidean"`` (default), ``"polyhedral"`` (the gauge of :func:`meshes.gauge.default_polytope`, the
        hexagonal pyramid, build direction z) or a :class:`meshes.gauge.Polytope`.

    Attributes
    ----------
    box : (3,) array
        Box lengths ``(L1, L2, L3)``.
    seeds : (n_cells, 3) array
        Cell seeds in the box.
    vertices, edges : arrays or None
        Struts only. ``vertices`` (V, 3): Voronoi vertices, one per lattice class, in the box. ``edges``
        (E, 2, 3): strut segments, one per lattice class; ``edges[e, 0]`` lies in the box, ``edges[e, 1]`` is the
        other endpoint chosen so that the segment is straight (a vertex plus a lattice vector ``n · L``). The
        periodic network is ``∪_e ∪_n [edges[e,0], edges[e,1]] + n · L``. ``None`` for wall foams.
    polytope : Polytope or None
        The polytope of a polyhedral distance (``None`` for the Euclidean one).
    radius : float
        Struts: strut radius ``r`` (cylinders along the edges, spheres at the vertices). Walls: half the wall
        width, measured in the horizontal layer.
    measured_density : float
        Solid fraction of the density sample at ``radius``.
    density_stderr : float
        Standard error of ``measured_density`` (spread of the ``DENSITY_SAMPLE_REPLICATES`` replicates).
    density_bounds : (float, float)
        The valid density range for these seeds, gamma and elements.
    summary : FoamSummary
        Orientation statistics of the struts or walls.

    """

    def __init__(self, n_cells: int, density: float, gamma: float = 1.0, seed: int = 0, strut: str | None = None,
                 *, box=None, distance="euclidean"):
        _check_int("n_cells", n_cells, 2)
        _check_int("seed", seed, 0)
        _check_gamma(gamma)
        box = _check_box(box, gamma)
        seeds = np.random.default_rng(seed).random((n_cells, 3)) * box
        self.seed = seed  # before _build: its log line prints the foam's repr
        self._build(seeds, density, gamma, strut, box, distance)

    @classmethod
    def from_seeds(cls, seeds: np.ndarray, density: float, gamma: float = 1.0, strut: str | None = None, *,
                   box=None, distance="euclidean") -> VoronoiFoam:
        """The foam of given seeds ``(n, 3)`` in the box (``seed`` is then ``None``)."""
        _check_gamma(gamma)
        box = _check_box(box, gamma)
        seeds = np.array(seeds, dtype=float)
        if seeds.ndim != 2 or seeds.shape[1] != 3 or len(seeds) < 2:
            raise FoamParameterError(f"seeds must be an (n, 3) array with n ≥ 2, got shape {seeds.shape}")
        if np.any(seeds < 0) or np.any(seeds >= box):
            raise FoamParameterError(f"seeds must lie in the box [0, {box.tolist()})")
        foam = cls.__new__(cls)
        foam.seed = None
        foam._build(seeds, density, gamma, strut, box, distance)
        return foam

    # ------------------------------------------------------------------------------------------------
    def _build(self, seeds: np.ndarray, density: float, gamma: float, strut, box: np.ndarray, distance) -> None:
        if isinstance(distance, Polytope):
            polytope = distance
        elif distance == "polyhedral":
            polytope = default_polytope()
        elif distance == "euclidean":
            polytope = None
        else:
            raise FoamParameterError(f"distance must be one of {DISTANCES} or a meshes.gauge.Polytope, "
                                     f"got {distance!r}")
        if strut is None:
            strut = "cylinder" if polytope is None else "wall"
        if strut not in STRUT_SHAPES:
            raise FoamParameterError(f"strut must be one of {STRUT_SHAPES}, got {strut!r}")
        if (polytope is None) != (strut == "cylinder"):
            raise FoamParameterError(
                f"strut={strut!r} with distance={distance!r} is not implemented: the Euclidean foam has struts "
                "(strut='cylinder'), the polyhedral foam walls (strut='wall')")
        if not (isinstance(density, (int, float)) and 0.0 < density < 1.0):
            raise FoamParameterError(f"density must be a solid volume fraction in (0, 1), got {density!r}")
        self.n_cells, self.density, self.gamma, self.strut = len(seeds), float(density), float(gamma), strut
        self.box = np.asarray(box, dtype=float)
        self.polytope = polytope
        self.metric = "euclidean" if polytope is None else polytope.name
        self.seeds = seeds
        if strut == "cylinder":
            self._build_struts(density, gamma)
        else:
            self._build_walls(density, gamma)
        replicate = self._replicate_density
        self.measured_density = float(replicate.mean())
        self.density_stderr = float(replicate.std(ddof=1) / math.sqrt(DENSITY_SAMPLE_REPLICATES))
        log.info("%r: measured density %.5f ± %.1e, valid density range [%.4f, %.4f]", self, self.measured_density,
                 self.density_stderr, *self.density_bounds)
        for name in ("seeds", "vertices", "edges", "box"):
            value = getattr(self, name)
            if value is not None:
                value.setflags(write=False)

    def _sample(self) -> np.ndarray:
        return _density_sample().reshape(-1, 3) * self.box

    def _check_range(self, density: float, low_reason: str, high_reason: str) -> None:
        lo, hi = self.density_bounds
        if not lo <= density <= hi:
            raise FoamParameterError(
                f"density {density} is outside the valid range [{lo:.4f}, {hi:.4f}] for n_cells={self.n_cells}, "
                f"gamma={self.gamma}, box={tuple(self.box.tolist())}, {self.strut}s (and these seeds): the low end "
                f"is {low_reason}, the high end {high_reason}")

    def _build_struts(self, density: float, gamma: float) -> None:
        self.vertices, self.edges, windows = _periodic_voronoi(self.seeds, gamma, self.box)
        lengths = np.linalg.norm(self.edges[:, 1] - self.edges[:, 0], axis=1)
        t = (self.edges[:, 1] - self.edges[:, 0]) / lengths[:, None]
        fabric = (t * lengths[:, None]).T @ t / lengths.sum()
        self.summary = FoamSummary(len(self.edges), float(lengths.mean()), tuple(map(float, np.abs(t).mean(axis=0))),
                                   tuple(map(tuple, fabric.tolist())))

        # valid radii: printable struts .. at most MAX_CLOSED_WINDOW_FRACTION of the windows closed
        r_min = 0.5 * MIN_DIAMETER_TO_STRUT_LENGTH * self.summary.mean_strut_length
        r_max = float(np.quantile([_window_inradius(w) for w in windows], MAX_CLOSED_WINDOW_FRACTION))

        # distance search sampled at about half the radius of a cylinder network of this density
        r_guess = math.sqrt(density * np.prod(self.box) / (math.pi * lengths.sum()))
        self._distance = _StrutDistance(self.edges, r_guess / _SAMPLES_PER_RADIUS, self.box)
        sample = self._sample()
        d_s = self._distance.nearest_sample(sample, upper=math.hypot(r_max, 0.5 * self._distance.spacing))
        d_lower = self._distance.lower_bound(d_s)
        d, exact = d_s.copy(), np.zeros(len(d_s), dtype=bool)

        def resolve(lo: float, hi: float) -> None:
            """Exact distances for the sample points whose distance bounds overlap [lo, hi]."""
            band = ~exact & (d_s >= lo) & (d_lower <= hi)
            d[band] = self._distance.exact(sample[band])
            exact[band] = True

        resolve(r_min, r_min)
        resolve(r_max, r_max)
        self.density_bounds = (float(np.mean(d <= r_min)), float(np.mean(d <= r_max)))
        self._check_range(density, f"a strut diameter of {MIN_DIAMETER_TO_STRUT_LENGTH} × the mean strut length",
                          f"{MAX_CLOSED_WINDOW_FRACTION:.0%} of the windows closed")

        # radius: the density-quantile of the sampled distances (the exact root of φ̂(r) = density)
        rank = max(math.ceil(density * len(sample)) - 1, 0)
        resolve(np.partition(d_lower, rank)[rank], np.partition(d_s, rank)[rank])
        self.radius = float(np.partition(d, rank)[rank])
        self._replicate_density = (d <= self.radius).reshape(DENSITY_SAMPLE_REPLICATES, -1).mean(axis=1)

    def _build_walls(self, density: float, gamma: float) -> None:
        self.vertices = self.edges = None
        self._distance = GaugeWalls(self.seeds, self.box, self.polytope, gamma)
        cell = float((np.prod(self.box) / self.n_cells) ** (1.0 / 3.0))
        r_min = 0.5 * MIN_WALL_TO_CELL * cell
        sample = self._sample()
        rank = max(math.ceil(density * len(sample)) - 1, 0)
        # exact ψ up to an upper bound that doubles until it holds the density-quantile (and r_min); the first
        # guess is about twice the half-width of walls of area ~2.9 γ^(-2/3) per cell size (Poisson–Voronoi)
        upper = max(r_min, density * cell * gamma ** (2.0 / 3.0) / 2.9)
        psi = self._distance.evaluate(sample, upper=upper)
        while np.count_nonzero(psi <= upper) <= rank:
            upper *= 2.0
            redo = psi > upper / 2.0          # the values beyond the former bound were not exact
            psi[redo] = self._distance.evaluate(sample[redo], upper=upper)
        self.density_bounds = (float(np.mean(psi <= r_min)), MAX_WALL_DENSITY)
        self._check_range(density, f"a wall width of {MIN_WALL_TO_CELL} × the mean cell size (V/n)^(1/3)",
                          f"{MAX_WALL_DENSITY} (thicker walls are no longer thin printed tracks)")
        self.radius = float(np.partition(psi, rank)[rank])
        inside = psi <= self.radius
        self._replicate_density = inside.reshape(DENSITY_SAMPLE_REPLICATES, -1).mean(axis=1)

        # wall statistics from the sample points in the walls: normal n, volume per area w |n_xy|
        _, _, _, n = self._distance.evaluate(sample[inside], upper=self.radius, details=True)
        per_area = 1.0 / np.maximum(np.linalg.norm(n[:, :2], axis=1), 1e-12)     # ∝ area per sample point
        area = float(per_area.sum() / (2.0 * self.radius * len(sample)))          # wall area per box volume
        weight = per_area / per_area.sum()
        fabric = 0.5 * (np.eye(3) - np.einsum("i,ij,ik->jk", weight, n, n))
        self.summary = FoamSummary(0, float("nan"), tuple(map(float, weight @ np.abs(n))),
                                   tuple(map(tuple, fabric.tolist())), area,
                                   self.polytope.max_overhang_deg(gamma))

    def __repr__(self) -> str:
        box = "" if np.all(self.box == 1.0) else f", box={tuple(round(b, 6) for b in self.box.tolist())}"
        metric = "" if self.polytope is None else f", distance={self.metric!r}"
        return (f"VoronoiFoam(n_cells={self.n_cells}, density={self.density}, gamma={self.gamma}, seed={self.seed}, "
                f"strut={self.strut!r}{box}{metric}; radius={self.radius:.5g})")

    # ------------------------------------------------------------------------------------------------
    def distance(self, points: np.ndarray, upper: float = np.inf) -> np.ndarray:
        """Exact periodic distance from points (M, 3) to the skeleton (segments, not the strut surface).

        Struts: Euclidean distance to the edge network. Walls: the in-layer (horizontal) distance to the face
        network. Wall distances are exact up to ``upper`` and some value ``> upper`` beyond (struts: always exact).
        """
        points = _wrap(np.asarray(points, dtype=float).reshape(-1, 3), self.box)
        if self.strut == "wall":
            return self._distance.evaluate(points, upper=upper)
        return self._distance.exact(points)

    def closest_points(self, points: np.ndarray, upper: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Exact periodic distance from points (M, 3) to the skeleton and the nearest skeleton point.

        Returns ``(d, q)``: ``d[m]`` the distance of :meth:`distance` and ``q[m]`` the minimiser, taken on the
        lattice image next to ``p_m`` wrapped into the box (so ``|p̃_m - q[m]| = d[m]`` with ``p̃_m`` the wrapped
        point; ``q`` may lie slightly outside the box). For walls ``q`` is the horizontal foot; beyond ``upper`` it is
        the point itself.
        """
        points = _wrap(np.asarray(points, dtype=float).reshape(-1, 3), self.box)
        if self.strut == "wall":
            d, q, _, _ = self._distance.evaluate(points, upper=upper, details=True)
            return d, q
        return self._distance.closest(points)

    def grid_shape(self, N, cubic: bool = True) -> tuple[int, int, int]:
        """The voxel grid for resolution ``N``: cubic voxels unless ``cubic=False``.

        ``N`` an integer: ``N`` voxels along the longest box edge and ``N_a = N L_a / max(L)`` along the others,
        which must be integers (e.g. ``N`` a multiple of 10 for ``box = (0.1, 1, 1)``). ``N`` a triple
        ``(N1, N2, N3)``: its voxels must be cubic (``L_a / N_a`` equal) unless ``cubic=False``. The unit cube
        gives ``(N, N, N)``.

        ``cubic=False`` (a triple only) is an explicit numerical choice: voxels of edges ``L_a / N_a`` that may
        differ. It pays where the thin members have one orientation: the walls of the polyhedral foam at
        γ = 0.1 are sheets nearly normal to x, whose width is resolved by the x spacing alone, so a grid with
        voxels longer along y and z resolves them at a fraction of the cubic grid's cost. Members of other
        orientations are resolved by the coarser spacing; check the result against a refinement of the grid
        (docs/foam.md, "Non-cubic voxels").
        """
        if isinstance(N, (tuple, list, np.ndarray)):
            shape = tuple(N)
            if len(shape) != 3:
                raise FoamParameterError(f"N must be an integer or three integers (N1, N2, N3), got {N!r}")
            for n in shape:
                _check_int("N", n, 2)
            h = self.box / np.array(shape)
            if cubic and not np.allclose(h, h[0], rtol=1e-9, atol=0):
                raise FoamParameterError(f"N = {tuple(shape)} gives non-cubic voxels {h.tolist()} for the box "
                                         f"{self.box.tolist()}; use N_a proportional to L_a, or cubic=False to "
                                         "accept non-cubic voxels")
            return tuple(int(n) for n in shape)
        if not cubic:
            raise FoamParameterError(f"cubic=False needs the grid as three integers (N1, N2, N3), got N={N!r}")
        _check_int("N", N, 8)
        exact = N * self.box / self.box.max()
        shape = np.rint(exact).astype(int)
        if np.any(np.abs(exact - shape) > 1e-6) or np.any(shape < 2):
            raise FoamParameterError(
                f"N={N} does not give cubic voxels in the box {self.box.tolist()}: N L_a / max(L) = "
                f"{exact.tolist()} must be integers ≥ 2")
        return tuple(int(n) for n in shape)

    def voxelize(self, N, cubic: bool = True) -> np.ndarray:
        """Solid indicator on a voxel grid: ``img[i, j, k] = dist(c_ijk, skeleton) ≤ radius``.

        ``N`` and ``cubic`` as in :meth:`grid_shape` (the unit cube gives ``(N, N, N)``; ``cubic=False`` with a
        triple accepts non-cubic voxels, an explicit numerical choice). Array axis ``a`` is coordinate ``x_a``
        (axis 0 = x); voxel ``[i, j, k]`` has centre ``c_ijk = ((i+½) h1, (j+½) h2, (k+½) h3)``,
        ``h_a = L_a / N_a``. Returns a C-ordered bool array, True = solid. Exact point-in-solid test, in slabs of
        bounded memory.
        """
        shape = self.grid_shape(N, cubic)
        img = np.empty(shape, dtype=bool)
        N1, N2, N3 = shape
        step = max(1, _CHUNK * 4 // (N2 * N3))
        for i0 in range(0, N1, step):
            i1 = min(N1, i0 + step)
            x = _voxel_centres(shape, self.box, i0, i1)
            img[i0:i1] = self._inside(x).reshape(i1 - i0, N2, N3)
        return img

    def _inside(self, x: np.ndarray) -> np.ndarray:
        """Exact solid test ``dist ≤ radius`` at points in the box."""
        r = self.radius
        if self.strut == "wall":
            return self._distance.evaluate(x, upper=r) <= r
        # struts: nearest strut sample within r → solid, beyond sqrt(r² + s²/4) void, exact distance in between
        s = self._distance.spacing
        upper = math.sqrt(r**2 + 0.25 * s**2)
        d_s = self._distance.nearest_sample(x, upper)
        solid = d_s <= r
        band = ~solid & (d_s <= upper)
        solid[band] = self._distance.exact(x[band]) <= r
        return solid

    def to_stl(self, path: str | os.PathLike, N) -> Path:
        """Write the closed surface of the solid ∩ box as a binary STL (marching cubes), atomically.

        The level set ``f(p) = min(r − dist(p, skeleton), distance of p to the box faces) = 0`` is sampled at the
        voxel centres of the grid of :meth:`grid_shape` padded by one voxel on each side (where ``f < 0``), so the
        surface is closed and caps the solid exactly on the box faces. Returns the path.
        """
        import meshio
        from skimage.measure import marching_cubes

        from foambase.files import check_output_file

        shape = self.grid_shape(N)
        h = float(self.box[0] / shape[0])
        path = check_output_file(path, "to_stl path")  # a directory, a missing folder: InputError, before any work
        c = [(np.arange(-1, n + 1) + 0.5) * h for n in shape]
        x = np.stack(np.meshgrid(*c, indexing="ij"), axis=-1).reshape(-1, 3)
        d = self.distance(x, upper=self.radius + 2.0 * h)
        wall = np.minimum(x, self.box - x).min(axis=1)
        f = np.minimum(self.radius - np.minimum(d, self.radius + 2.0 * h), wall).reshape(tuple(n + 2 for n in shape))
        verts, faces, _, _ = marching_cubes(f, 0.0, spacing=(h, h, h), allow_degenerate=False)
        verts += c[0][0]
        faces = faces[:, ::-1]          # outward normals (skimage orients them inwards for this axis order)
        tmp = path.with_name(f".{path.name}.tmp")
        try:
            meshio.write(tmp, meshio.Mesh(verts, [("triangle", faces)]), file_format="stl", binary=True)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        log.info("to_stl: %d triangles written to %s", len(faces), path)
        return path

    def orientation_histogram(self, bins: int = 9) -> tuple[np.ndarray, np.ndarray]:
        """Histogram of element angles to the x axis on ``[0°, 90°]``, normalised to sum 1.

        Struts: the angle between the strut and x, length-weighted. Walls: the angle between the wall *normal* and
        x, area-weighted (0° = a wall normal to x). Returns ``(edges_deg, weights)``.
        """
        edges_deg = np.linspace(0.0, 90.0, bins + 1)
        if self.strut == "cylinder":
            v = self.edges[:, 1] - self.edges[:, 0]
            length = np.linalg.norm(v, axis=1)
            angle = np.degrees(np.arccos(np.clip(np.abs(v[:, 0]) / length, 0.0, 1.0)))
            w, _ = np.histogram(angle, edges_deg, weights=length)
        else:
            sample = self._sample()
            psi, _, _, n = self._distance.evaluate(sample, upper=self.radius, details=True)
            n = n[psi <= self.radius]
            angle = np.degrees(np.arccos(np.clip(np.abs(n[:, 0]), 0.0, 1.0)))
            w, _ = np.histogram(angle, edges_deg, weights=1.0 / np.maximum(np.linalg.norm(n[:, :2], axis=1), 1e-12))
        return edges_deg, w / w.sum()


def _check_gamma(gamma) -> None:
    if isinstance(gamma, bool) or not (isinstance(gamma, (int, float, np.floating)) and 0.0 < gamma <= 1.0):
        raise FoamParameterError(f"gamma must be in (0, 1] (1 = isotropic), got {gamma!r}")


def _check_box(box, gamma: float) -> np.ndarray:
    """Box lengths: None → unit cube, "equiaxed" → (gamma, 1, 1), else three positive finite lengths."""
    if box is None:
        return np.ones(3)
    if isinstance(box, str):
        if box == "equiaxed":
            return np.array([float(gamma), 1.0, 1.0])
        raise FoamParameterError(f"box must be None, 'equiaxed' or three positive lengths (L1, L2, L3), got {box!r}")
    try:
        b = np.array(box, dtype=float)
    except (TypeError, ValueError):
        raise FoamParameterError(f"box must be three positive lengths (L1, L2, L3), got {box!r}") from None
    if b.shape != (3,) or not np.all(np.isfinite(b)) or np.any(b <= 0):
        raise FoamParameterError(f"box must be three positive finite lengths (L1, L2, L3), got {box!r}")
    return b


def _check_int(name: str, value, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise FoamParameterError(f"{name} must be an integer ≥ {minimum}, got {value!r}")
