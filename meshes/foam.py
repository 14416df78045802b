"""Periodic stochastic Voronoi strut foams in the unit cube: geometry, radius from density, voxels, surface.

Model (docs/conventions.md, paper §II-A)
------------------------------
* **Seeds**: ``n_cells`` points drawn uniformly in ``[0, 1)³`` by ``numpy.random.default_rng(seed)``.
* **Anisotropy**: the Voronoi diagram under the metric ``|p - q|_γ² = (Δx/γ)² + Δy² + Δz²``, i.e. the
  isotropic Voronoi diagram of the seeds in the box ``[0, 1/γ) × [0, 1)²`` (x stretched by ``1/γ``), mapped
  back by ``x → γ x``. For ``γ < 1`` cells are flattened along x and the struts lie mostly in y–z.
* **Periodicity**: the diagram is computed with the seeds' periodic images (a ``(2m+1)³`` tiling of the
  stretched box, ``m = 1`` unless a Voronoi vertex's empty sphere reaches outside the tiling, then ``m = 2, 3``),
  and every Voronoi edge of a central cell is kept once modulo the lattice ``ℤ³``.
* **Struts**: the union of cylinders of radius ``r`` along the edges and spheres of radius ``r`` at the
  vertices, which is exactly the set ``{p : dist(p, E) ≤ r}`` with ``E`` the periodic union of edge segments.
  The solid fraction ``φ(r) = |{p ∈ [0,1)³ : dist(p, E) ≤ r}|`` is therefore monotone in ``r``.
* **Radius**: ``φ(r)`` is estimated on a fixed randomised quasi-Monte-Carlo sample of the cube (scrambled Sobol',
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

Flat cells
----------
For small ``gamma`` with few cells the stretched cells are wider than the cube's y–z period, and a cell meets its
own periodic images: the diagram then does not close within a 7³ tiling and :class:`FoamParameterError` names
gamma, n_cells and the bound ``n_cells ≳ 1/gamma``. That bound is what was observed, not a theorem (six seeds:
gamma = 0.05 builds 6/6 with 20 cells, 4/6 with 14, 0/6 with 8; gamma = 0.02 builds 4/6 with 50, 1/6 with 35).

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
from scipy.spatial import Voronoi, cKDTree
from scipy.stats import qmc

from foambase.errors import ComputationError
from meshes.errors import FoamParameterError
from meshes.rve import RVEMesh, mesh_rve  # the RVE mesher of a foam (meshes.rve), under its public path

__all__ = [
    "DENSITY_SAMPLE_LOG2",
    "DENSITY_SAMPLE_REPLICATES",
    "MAX_CLOSED_WINDOW_FRACTION",
    "MIN_DIAMETER_TO_STRUT_LENGTH",
    "STRUT_SHAPES",
    "FoamParameterError",
    "FoamSummary",
    "RVEMesh",
    "VoronoiFoam",
    "mesh_rve",
    "strut_distance",
]

log = logging.getLogger(__name__)

#: Strut cross-sections implemented: round struts (cylinders with spherical joints).
STRUT_SHAPES = ("cylinder",)
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
    """Strut statistics of a foam (unweighted means over the struts, each strut counted once).

    ``mean_abs_cos[a] = mean_e |t_e · e_a|`` with ``t_e`` the unit direction of strut ``e``; an isotropic
    foam has about ``(1/2, 1/2, 1/2)`` (the mean of ``|cos|`` over the sphere), a foam with struts in the
    y–z plane has ``mean_abs_cos[0] → 0``.
    """

    n_struts: int
    mean_strut_length: float
    mean_abs_cos: tuple[float, float, float]

    def as_dict(self) -> dict[str, float]:
        """Flat dictionary (for tables and CSV rows)."""
        cx, cy, cz = self.mean_abs_cos
        return {"n_struts": self.n_struts, "mean_strut_length": self.mean_strut_length,
                "mean_abs_cos_x": cx, "mean_abs_cos_y": cy, "mean_abs_cos_z": cz}


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


def _periodic_voronoi(seeds: np.ndarray, gamma: float):
    """Voronoi diagram of periodic seeds under the γ-metric: canonical vertices, edges and windows.

    Returns ``(vertices, edges, windows)`` in the original (unit-cube) coordinates: ``vertices`` (V, 3) in
    ``[0,1)³``; ``edges`` (E, 2, 3) endpoint pairs, the first in ``[0,1)³``, the second its lattice-consistent
    partner; ``windows`` a list of (k, 3) ordered polygons, each face once modulo the lattice.
    """
    n = len(seeds)
    box = np.array([1.0 / gamma, 1.0, 1.0])
    stretched = seeds * box
    cell_size = (np.prod(box) / n) ** (1.0 / 3.0)
    for m in (1, 2, 3):
        shifts = _lattice(m)
        points = (stretched[None] + shifts[:, None] * box).reshape(-1, 3)
        vor = Voronoi(points)
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
            if np.all(v - radius[:, None] > -m * box) and np.all(v + radius[:, None] < (m + 1) * box):
                break
        log.debug("periodic Voronoi: a %d³ tiling is not enough, enlarging", 2 * m + 1)
    else:
        # flat cells: stretched by 1/gamma, a cell wider than the y–z period touches its own images
        width = (1.0 / (gamma * n)) ** (1.0 / 3.0)
        raise FoamParameterError(
            f"gamma={gamma} is too flat for n_cells={n}: in the stretched metric the mean cell width "
            f"(1/(gamma·n_cells))^(1/3) = {width:.2f} × the RVE's y–z period, and the periodic Voronoi diagram of "
            f"these seeds does not close within a 7³ tiling of images; use n_cells ≥ about 1/gamma = "
            f"{math.ceil(1.0 / gamma)} (seed-dependent near that bound) or gamma ≥ about 1/n_cells = {1.0 / n:.3g}")

    # merge numerically coincident vertices modulo the lattice
    wrapped = _wrap(vor.vertices[used], box)
    pairs = cKDTree(wrapped, boxsize=box).query_pairs(VERTEX_MERGE_TOL * cell_size, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(used),) * 2)
    _, label = connected_components(graph, directed=False)
    _, rep = np.unique(label, return_index=True)        # lowest-index member represents each cluster
    canonical = wrapped[rep]
    lookup = np.full(len(vor.vertices), -1)
    lookup[used] = np.arange(len(used))
    v_label = label[lookup[used]]
    v_shift = np.rint((vor.vertices[used] - canonical[v_label]) / box).astype(int)

    # edges: consecutive vertices of the ordered face polygons, keyed modulo the lattice
    scale = np.array([gamma, 1.0, 1.0])
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
    edges = np.stack([vertices[keys[:, 0]], vertices[keys[:, 1]] + keys[:, 2:]], axis=1)
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

    def __init__(self, edges: np.ndarray, spacing: float):
        self.a = edges[:, 0]
        self.d = edges[:, 1] - edges[:, 0]
        self.dd = np.einsum("ij,ij->i", self.d, self.d)
        n_int = np.maximum(np.ceil(np.sqrt(self.dd) / spacing).astype(int), 1)
        self.segment = np.repeat(np.arange(len(edges)), n_int + 1)
        first = np.repeat(np.cumsum(n_int + 1) - (n_int + 1), n_int + 1)
        t = (np.arange(len(self.segment)) - first) / n_int[self.segment]
        self.samples = self.a[self.segment] + t[:, None] * self.d[self.segment]
        self.spacing = float(np.max(np.sqrt(self.dd) / n_int))
        self.tree = cKDTree(_wrap(self.samples, 1.0), boxsize=1.0)

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
        """Exact periodic distance from the points ``x`` (in ``[0,1)³``) to the nearest segment."""
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
            shift = np.rint(x[todo][:, None, :] - self.samples[idx])      # p - shift is the image next to a sample
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


def strut_distance(edges: np.ndarray, points: np.ndarray, spacing: float) -> np.ndarray:
    """Exact periodic distance from ``points`` (M, 3) in ``[0,1)³`` to the nearest segment of ``edges`` (E, 2, 3).

    ``spacing`` is the sampling step of the internal search (any positive value gives the exact result;
    about half the strut radius is fastest).
    """
    return _StrutDistance(np.asarray(edges, dtype=float), spacing).exact(np.asarray(points, dtype=float))


@functools.lru_cache(maxsize=1)
def _density_sample() -> np.ndarray:
    """The fixed RQMC sample of the unit cube: (replicates, 2**log2, 3), the same for every foam."""
    return np.stack([qmc.Sobol(3, scramble=True, seed=_DENSITY_SAMPLE_SEED + k).random_base2(DENSITY_SAMPLE_LOG2)
                     for k in range(DENSITY_SAMPLE_REPLICATES)])


def _voxel_centres(N: int, i0: int, i1: int) -> np.ndarray:
    """Centres ``((i+½)/N, (j+½)/N, (k+½)/N)`` of the voxel slab ``i0 ≤ i < i1``, C order, shape (·, 3)."""
    c = (np.arange(N) + 0.5) / N
    return np.stack(np.meshgrid(c[i0:i1], c, c, indexing="ij"), axis=-1).reshape(-1, 3)


# --------------------------------------------------------------------------------------------------
# The foam
# --------------------------------------------------------------------------------------------------
class VoronoiFoam:
    """A periodic stochastic Voronoi strut foam in the unit cube ``[0, 1)³`` (see the module docstring).

    Parameters
    ----------
    n_cells
        Number of Voronoi cells (seeds), ≥ 2.
    density
        Target solid volume fraction; must lie in :meth:`density_range` (a clear error gives that range).
    gamma
        Degree of anisotropy in ``(0, 1]``: the Voronoi metric stretches x by ``1/gamma``; 1 is isotropic.
        Flat cells need enough of them: about ``n_cells ≥ 1/gamma`` (see "Flat cells" in the module docstring).
    seed
        Seed of ``numpy.random.default_rng`` for the cell seeds (same seed → bitwise identical foam).
    strut
        Strut shape, one of :data:`STRUT_SHAPES`.

    Attributes
    ----------
    seeds : (n_cells, 3) array
        Cell seeds in ``[0, 1)³``.
    vertices : (V, 3) array
        Voronoi vertices, one per lattice class, in ``[0, 1)³``.
    edges : (E, 2, 3) array
        Strut segments, one per lattice class: ``edges[e, 0]`` lies in ``[0, 1)³``, ``edges[e, 1]`` is the other
        endpoint chosen so that the segment is straight (it may lie outside the unit cube; it is a vertex
        plus an integer lattice shift). The periodic strut network is ``∪_e ∪_{n∈ℤ³} [edges[e,0], edges[e,1]] + n``.
    radius : float
        Strut radius ``r`` (cylinders along the edges, spheres of radius ``r`` at the vertices).
    measured_density : float
        Solid fraction of the density sample at ``radius``.
    density_stderr : float
        Standard error of ``measured_density`` (spread of the ``DENSITY_SAMPLE_REPLICATES`` replicates).
    density_bounds : (float, float)
        The valid density range for these seeds and gamma (see :meth:`density_range`).
    summary : FoamSummary
        Number of struts, mean strut length and mean ``|cos|`` of strut directions with x, y, z.

    """

    def __init__(self, n_cells: int, density: float, gamma: float = 1.0, seed: int = 0, strut: str = "cylinder"):
        _check_int("n_cells", n_cells, 2)
        _check_int("seed", seed, 0)
        seeds = np.random.default_rng(seed).random((n_cells, 3))
        self._build(seeds, density, gamma, strut)
        self.seed = seed

    @classmethod
    def from_seeds(cls, seeds: np.ndarray, density: float, gamma: float = 1.0, strut: str = "cylinder") -> VoronoiFoam:
        """The foam of given seeds ``(n, 3)`` in ``[0, 1)³`` (``seed`` is then ``None``)."""
        seeds = np.array(seeds, dtype=float)
        if seeds.ndim != 2 or seeds.shape[1] != 3 or len(seeds) < 2:
            raise FoamParameterError(f"seeds must be an (n, 3) array with n ≥ 2, got shape {seeds.shape}")
        if np.any(seeds < 0) or np.any(seeds >= 1):
            raise FoamParameterError("seeds must lie in [0, 1)³")
        foam = cls.__new__(cls)
        foam._build(seeds, density, gamma, strut)
        foam.seed = None
        return foam

    def _build(self, seeds: np.ndarray, density: float, gamma: float, strut: str) -> None:
        if not (isinstance(gamma, (int, float)) and 0.0 < gamma <= 1.0):
            raise FoamParameterError(f"gamma must be in (0, 1] (1 = isotropic), got {gamma!r}")
        if strut not in STRUT_SHAPES:
            raise FoamParameterError(f"strut must be one of {STRUT_SHAPES}, got {strut!r}")
        if not (isinstance(density, (int, float)) and 0.0 < density < 1.0):
            raise FoamParameterError(f"density must be a solid volume fraction in (0, 1), got {density!r}")
        self.n_cells, self.density, self.gamma, self.strut = len(seeds), float(density), float(gamma), strut
        self.seeds = seeds
        self.vertices, self.edges, windows = _periodic_voronoi(seeds, gamma)
        lengths = np.linalg.norm(self.edges[:, 1] - self.edges[:, 0], axis=1)
        cosines = np.abs(self.edges[:, 1] - self.edges[:, 0]) / lengths[:, None]
        self.summary = FoamSummary(len(self.edges), float(lengths.mean()), tuple(map(float, cosines.mean(axis=0))))

        # valid radii: printable struts .. at most MAX_CLOSED_WINDOW_FRACTION of the windows closed
        r_min = 0.5 * MIN_DIAMETER_TO_STRUT_LENGTH * self.summary.mean_strut_length
        r_max = float(np.quantile([_window_inradius(w) for w in windows], MAX_CLOSED_WINDOW_FRACTION))

        # distance search sampled at about half the radius of a cylinder network of this density
        r_guess = math.sqrt(density / (math.pi * lengths.sum()))
        self._distance = _StrutDistance(self.edges, r_guess / _SAMPLES_PER_RADIUS)
        sample = _density_sample().reshape(-1, 3)
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
        if not self.density_bounds[0] <= density <= self.density_bounds[1]:
            lo, hi = self.density_bounds
            raise FoamParameterError(
                f"density {density} is outside the valid range [{lo:.4f}, {hi:.4f}] for n_cells={self.n_cells}, "
                f"gamma={gamma} (and these seeds): the low end is a strut diameter of {MIN_DIAMETER_TO_STRUT_LENGTH} "
                f"× the mean strut length, the high end {MAX_CLOSED_WINDOW_FRACTION:.0%} of the windows closed")

        # radius: the density-quantile of the sampled distances (the exact root of φ̂(r) = density)
        rank = max(math.ceil(density * len(sample)) - 1, 0)
        resolve(np.partition(d_lower, rank)[rank], np.partition(d_s, rank)[rank])
        self.radius = float(np.partition(d, rank)[rank])
        replicate = (d <= self.radius).reshape(DENSITY_SAMPLE_REPLICATES, -1).mean(axis=1)
        self.measured_density = float(replicate.mean())
        self.density_stderr = float(replicate.std(ddof=1) / math.sqrt(DENSITY_SAMPLE_REPLICATES))
        log.info("VoronoiFoam(n_cells=%d, density=%.4g, gamma=%.4g): %d struts, r=%.5g, measured density %.5f "
                 "± %.1e, valid density range [%.4f, %.4f]", self.n_cells, density, gamma, len(self.edges),
                 self.radius, self.measured_density, self.density_stderr, *self.density_bounds)
        for name in ("seeds", "vertices", "edges"):
            getattr(self, name).setflags(write=False)

    def __repr__(self) -> str:
        return (f"VoronoiFoam(n_cells={self.n_cells}, density={self.density}, gamma={self.gamma}, seed={self.seed}, "
                f"strut={self.strut!r}; radius={self.radius:.5g}, measured_density={self.measured_density:.5f})")

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Exact periodic distance from points (M, 3) to the strut network (segments, not the strut surface)."""
        points = _wrap(np.asarray(points, dtype=float).reshape(-1, 3), 1.0)
        return self._distance.exact(points)

    def closest_points(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact periodic distance from points (M, 3) to the strut network and the nearest network point.

        Returns ``(d, q)``: ``d[m] = min_{e, n∈ℤ³} dist(p_m, segment_e + n)`` and ``q[m]`` the minimiser, taken
        on the lattice image of the network next to ``p_m`` wrapped into ``[0,1)³`` (so ``|p̃_m - q[m]| = d[m]``
        with ``p̃_m = p_m mod 1``; ``q`` may lie slightly outside the unit cube).
        """
        points = _wrap(np.asarray(points, dtype=float).reshape(-1, 3), 1.0)
        return self._distance.closest(points)

    def voxelize(self, N: int) -> np.ndarray:
        """Solid indicator on an ``N³`` voxel grid: ``img[i, j, k] = dist(c_ijk, struts) ≤ radius``.

        Array axis ``a`` is coordinate ``x_a`` (axis 0 = x); voxel ``[i, j, k]`` has centre
        ``c_ijk = ((i+½)/N, (j+½)/N, (k+½)/N)``. Returns a C-ordered ``(N, N, N)`` bool array, True = solid.
        Exact point-in-union test, in slabs of bounded memory: voxels whose nearest strut sample is within
        ``r`` are solid, beyond ``sqrt(r² + s²/4)`` void, and the thin band between gets the exact distance.
        """
        _check_int("N", N, 8)
        r, s = self.radius, self._distance.spacing
        upper = math.sqrt(r**2 + 0.25 * s**2)
        img = np.empty((N, N, N), dtype=bool)
        step = max(1, _CHUNK * 4 // (N * N))
        for i0 in range(0, N, step):
            i1 = min(N, i0 + step)
            x = _voxel_centres(N, i0, i1)
            d_s = self._distance.nearest_sample(x, upper)
            solid = d_s <= r
            band = ~solid & (d_s <= upper)
            solid[band] = self._distance.exact(x[band]) <= r
            img[i0:i1] = solid.reshape(i1 - i0, N, N)
        return img

    def to_stl(self, path: str | os.PathLike, N: int) -> Path:
        """Write the closed surface of the solid ∩ unit cube as a binary STL (marching cubes), atomically.

        The level set ``f(p) = min(r - dist(p, struts), x, 1-x, y, 1-y, z, 1-z) = 0`` is sampled at the voxel
        centres of an ``N³`` grid padded by one voxel on each side (where ``f < 0``), so the surface is closed
        and caps the struts exactly on the cube faces. Returns the path.
        """
        import meshio
        from skimage.measure import marching_cubes

        _check_int("N", N, 8)
        path = Path(path)
        c = (np.arange(-1, N + 1) + 0.5) / N
        x = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)
        d = self._distance.nearest_sample(_wrap(x, 1.0))
        near = d <= self.radius + 2.0 / N
        d[near] = self._distance.exact(_wrap(x[near], 1.0))
        f = np.minimum(self.radius - d, np.minimum(x, 1.0 - x).min(axis=1)).reshape((N + 2,) * 3)
        verts, faces, _, _ = marching_cubes(f, 0.0, spacing=(1.0 / N,) * 3, allow_degenerate=False)
        verts += c[0]
        faces = faces[:, ::-1]          # outward normals (skimage orients them inwards for this axis order)
        tmp = path.with_name(f".{path.name}.tmp")
        try:
            meshio.write(tmp, meshio.Mesh(verts, [("triangle", faces)]), file_format="stl", binary=True)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        log.info("to_stl: %d triangles written to %s", len(faces), path)
        return path


def _check_int(name: str, value, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise FoamParameterError(f"{name} must be an integer ≥ {minimum}, got {value!r}")
