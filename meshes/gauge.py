"""Convex polyhedral distances (gauges of polytopes) and the wall field of their periodic Voronoi diagrams.

A convex polytope ``P = {v : n_i · v ≤ h_i}`` with the origin inside (``h_i > 0``) defines the **gauge**

    g_P(v) = min{λ ≥ 0 : v ∈ λ P} = max_i ν_i · v,      ν_i = n_i / h_i  (the vertices of the polar body P°),

a convex, positively homogeneous "distance" that need not be symmetric (``g_P(−v) ≠ g_P(v)`` unless ``P = −P``).
The Voronoi cell of a site ``p`` is ``{x : g_P(x − p) ≤ g_P(x − q) for every other site q}``. Where site ``p`` is
reached through face ``i`` and site ``q`` through face ``j`` (``x − p`` in the cone of face ``i`` ...), the bisector
``g(x − p) = g(x − q)`` is a piece of the plane with normal ``ν_i − ν_j``: **every wall of the diagram has one of the
normals ``ν_i − ν_j``**, whatever the sites. This is what makes a polyhedral distance printable: choosing ``P``
bounds the orientations of all walls (Martínez, Hornus, Song, Lefebvre, "Polyhedral Voronoi diagrams for additive
manufacturing", ACM TOG 37(4), 2018).

Fabrication argument for the default polytope (:func:`default_polytope`)
-----------------------------------------------------------------------
Fused filament fabrication deposits each horizontal layer as tracks of one nozzle width ``w`` on the layer
below; the build direction is +z. Its constraints, and what they ask of the foam:

* **continuity**: every layer must be continuous paths. The slice of a strut is an isolated island (one start
  and stop of the extrusion per strut and layer); the slice of a wall is a line of the planar network cut from
  the diagram's faces. So the printed foam is made of the Voronoi **faces** (walls of one track width), not of its
  edges (struts): see :class:`GaugeWalls`.
* **self-support / bounded overhang**: a wall must rise at no more than the printable overhang from the vertical,
  45° here (the usual FFF rule; steeper walls sag). A horizontal wall is a bridge. With walls of normals
  ``ν_i − ν_j`` this asks ``|(ν_i − ν_j)_z| ≤ |(ν_i − ν_j)_xy|`` for every pair of faces: the polar vertices must be
  pairwise no steeper than 45°. A polytope with two downward faces (a prism, a bipyramid) fails: two sites on a
  vertical line meet on a horizontal wall. A **pyramid** has a single downward face (its base): its side faces'
  polar vertices lie in one horizontal plane (walls between side faces are vertical) and the base–side walls are
  inclined at ``atan(b/ρ)`` from the horizontal, with ``b`` the depth of the base below the site and ``ρ`` the
  base polygon's inradius: ``b = ρ`` gives exactly the 45° bound.
* **in-plane behaviour**: a ``k``-gonal base gives the foam ``k``-fold symmetry about the build axis. ``k = 6`` is
  the smallest ``k`` for which a fourth-order (elasticity) tensor with that symmetry is transversely isotropic
  about z, i.e. the γ = 1 foam has no preferred direction in the layer plane; a square base would make it
  tetragonal.
* **cells about as tall as wide at γ = 1**: the apex height ``a`` sets how tall the cells are; ``a = b = ρ = 1``
  (the hexagonal pyramid whose apex height, base depth and base inradius are equal, the site at mid-height) is
  the choice, not a calibration.
* **anisotropy γ**: the polytope is shrunk by γ along x (a horizontal axis, as the layer plane is the only one
  in which a deformation keeps the walls printable): ``P_γ = diag(γ, 1, 1) P``, ``ν_i → diag(1/γ, 1, 1) ν_i``.
  Cells are then flattened along x; shrinking along a horizontal axis only steepens the walls.

The IceSL slicer exposes the same family for its polyhedral foams: a ``k``-gon-based distance with an ``x``
shrink (anisotropy) and an in-plane angle.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection, cKDTree

from foambase.errors import ComputationError
from meshes.errors import FoamParameterError

__all__ = ["GaugeWalls", "Polytope", "PolytopeError", "default_polytope", "pyramid"]

log = logging.getLogger(__name__)

_CHUNK = 1 << 12
_MAX_IMAGES = 1 << 18


class PolytopeError(FoamParameterError):
    """A polytope is not a bounded convex polytope with the origin in its interior (a foam parameter error)."""


@dataclass(frozen=True)
class Polytope:
    """A convex polytope ``{v : n_i · v ≤ h_i}`` given by its face normals and offsets (origin inside).

    Parameters
    ----------
    normals
        (K, 3) outward face normals (any length; they are normalised).
    offsets
        (K,) distances ``h_i > 0`` of the faces from the origin along the unit normals; default all 1.
    name
        A label for logs and reports.

    """

    normals: tuple
    offsets: tuple
    name: str = "polytope"

    def __init__(self, normals, offsets=None, name: str = "polytope"):
        n = np.asarray(normals, dtype=float)
        if n.ndim != 2 or n.shape[1] != 3 or len(n) < 4 or not np.all(np.isfinite(n)):
            raise PolytopeError(f"normals must be a (K, 3) array of finite vectors with K ≥ 4, got shape "
                                f"{np.shape(normals)}")
        length = np.linalg.norm(n, axis=1)
        if np.any(length == 0):
            raise PolytopeError(f"face normal {int(np.argmin(length))} is the zero vector")
        n = n / length[:, None]
        h = np.ones(len(n)) if offsets is None else np.asarray(offsets, dtype=float)
        if h.shape != (len(n),) or not np.all(np.isfinite(h)) or np.any(h <= 0):
            raise PolytopeError(f"offsets must be {len(n)} positive numbers (the origin strictly inside), got "
                                f"{offsets!r}")
        # bounded: the normals must positively span R³, i.e. max e·v over P is finite for ±e_x, ±e_y, ±e_z
        for axis in range(3):
            for sign in (1.0, -1.0):
                c = np.zeros(3)
                c[axis] = -sign
                res = linprog(c, A_ub=n, b_ub=h, bounds=[(None, None)] * 3, method="highs")
                if res.status == 3:
                    raise PolytopeError(f"the polytope of these {len(n)} face normals is unbounded along "
                                        f"{'+' if sign > 0 else '-'}{'xyz'[axis]}: the normals must positively "
                                        "span space")
        object.__setattr__(self, "normals", tuple(map(tuple, n.tolist())))
        object.__setattr__(self, "offsets", tuple(h.tolist()))
        object.__setattr__(self, "name", str(name))

    @property
    def polar_vertices(self) -> np.ndarray:
        """``ν_i = n_i / h_i`` (K, 3): ``g(v) = max_i ν_i · v``."""
        return np.asarray(self.normals) / np.asarray(self.offsets)[:, None]

    def deformed(self, gamma: float) -> np.ndarray:
        """Polar vertices of ``diag(γ, 1, 1) P`` (the polytope shrunk by γ along x)."""
        return self.polar_vertices * np.array([1.0 / gamma, 1.0, 1.0])

    def vertices(self, gamma: float = 1.0) -> np.ndarray:
        """Vertices of ``diag(γ, 1, 1) P`` (for pictures and the Euclidean bounds of the gauge)."""
        nu = self.deformed(gamma)
        hs = HalfspaceIntersection(np.column_stack([nu, -np.ones(len(nu))]), np.zeros(3))
        pts = hs.intersections
        return pts[ConvexHull(pts).vertices]

    def gauge(self, v: np.ndarray, gamma: float = 1.0) -> np.ndarray:
        """``g(v) = max_i ν_i · v`` for vectors ``v`` (..., 3) under the γ-deformed polytope."""
        return np.max(np.asarray(v, dtype=float) @ self.deformed(gamma).T, axis=-1)

    def wall_normals(self, gamma: float = 1.0) -> np.ndarray:
        """Unit normals of every wall orientation the diagram can have: ``ν_i − ν_j`` for ``i < j``, normalised."""
        nu = self.deformed(gamma)
        i, j = np.triu_indices(len(nu), 1)
        d = nu[i] - nu[j]
        return d / np.linalg.norm(d, axis=1)[:, None]

    def max_overhang_deg(self, gamma: float = 1.0) -> float:
        """Largest angle between a wall of the diagram and the vertical (build direction z), degrees.

        A wall with unit normal ``m`` makes the angle ``asin |m_z|`` with the vertical; 90° is a horizontal wall.
        """
        return float(np.degrees(np.arcsin(np.clip(np.abs(self.wall_normals(gamma)[:, 2]).max(), 0.0, 1.0))))


def pyramid(k: int = 6, apex: float = 1.0, depth: float = 1.0, inradius: float = 1.0, name: str | None = None):
    """The pyramid over a regular ``k``-gon of inradius ``inradius`` at ``z = −depth``, apex at ``z = apex``.

    The base polygon has a vertex on +x (vertices at azimuths ``2π m / k``, side normals at ``π (2m + 1) / k``), the
    usual vertex-first parametrisation of a regular polygon; for ``k = 6`` two sides are normal to ±y, so the walls
    between those faces and the base contain x and keep their 45° under the shrink along x. Its polar vertices are
    ``((apex + depth)/(inradius · apex)) u_m + (1/apex) e_z`` for the sides (``u_m`` the unit horizontal side
    directions) and ``−e_z / depth`` for the base, so base–side walls rise at ``atan(depth/inradius)`` from the
    horizontal and side–side walls are vertical.
    """
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 3:
        raise PolytopeError(f"k must be an integer ≥ 3 (sides of the base polygon), got {k!r}")
    for label, value in (("apex", apex), ("depth", depth), ("inradius", inradius)):
        if not (np.isfinite(value) and value > 0):
            raise PolytopeError(f"{label} must be > 0, got {value!r}")
    az = np.pi * (2.0 * np.arange(k) + 1.0) / k
    sides = np.column_stack([(apex + depth) * np.cos(az), (apex + depth) * np.sin(az), np.full(k, inradius)])
    normals = np.vstack([sides, [0.0, 0.0, -1.0]])
    offsets = np.concatenate([np.full(k, inradius * apex) / np.linalg.norm(sides, axis=1), [depth]])
    return Polytope(normals, offsets, name=name or f"pyramid(k={k}, apex={apex:g}, depth={depth:g}, "
                                                     f"inradius={inradius:g})")


def default_polytope() -> Polytope:
    """The printable default: the hexagonal pyramid with apex height = base depth = base inradius = 1.

    Walls at most 45° from the vertical, one track wide in every layer; cells equiaxed at γ = 1 (module docstring).
    """
    return pyramid(6, 1.0, 1.0, 1.0, name="hexagonal pyramid (apex 1, base depth 1, base inradius 1)")


# --------------------------------------------------------------------------------------------------
# The wall field
# --------------------------------------------------------------------------------------------------
class GaugeWalls:
    """Horizontal distance from points to the walls of a periodic gauge-Voronoi diagram.

    The walls are the Voronoi faces; a printed wall is one track of width ``w`` in every layer, so the solid is
    ``{x : ψ(x) ≤ w/2}`` with ``ψ(x)`` the distance from ``x`` to the face network *within the horizontal layer
    through x* (the slicer's view: each layer prints the cut of the diagram as tracks of width ``w``).

    Exact evaluation
    ----------------
    Let site 1 be the gauge-nearest site of ``x`` (``d_1 = g(x − p_1)``). The nearest wall point in the layer lies on
    the boundary of cell 1, hence on a bisector ``{y : g(y − p_1) = g(y − p_j)}``; conversely any bisector point is
    on or outside cell 1, so ``ψ = min_j dist(x, B_1j ∩ layer)``. In the layer each bisector is a polyline: its piece
    where face ``a`` is active for ``p_1`` and face ``b`` for ``p_j`` lies on the line ``(ν_a − ν_b) · y = ν_a · p_1 −
    ν_b · p_j`` and is the interval of that line on which both activity conditions ``(ν_a − ν_c) · (y − p_1) ≥ 0``,
    ``(ν_b − ν_c) · (y − p_j) ≥ 0`` hold (linear in the line parameter). The distance to every piece is computed in
    closed form; pairs ``a = b`` have no bisector (generic sites), and pieces with no horizontal normal component
    (horizontal walls, which a printable polytope does not have) are skipped.

    Which sites can matter: for ``y`` at horizontal distance ``t`` from ``x``, ``g(y − x), g(x − y) ≤ G t`` with ``G =
    max_i |ν_i,xy|``, so a bisector point needs ``d_j − d_1 ≤ 2 G t``: ``ψ_j ≥ (d_j − d_1)/(2G)``. The candidates are
    the site images nearest to ``x`` in the undeformed coordinates ``u = (x/γ, y, z)`` (a KD-tree over a tiling of
    the seeds), where ``g(v) ≥ |v_u| / R`` (``R`` the largest vertex norm of ``P``). The sites are taken in order of
    that lower bound until it exceeds the current ``ψ`` (or ``upper``); the result is exact, not a bound.
    """

    def __init__(self, seeds: np.ndarray, box: np.ndarray, polytope: Polytope, gamma: float):
        self.box = np.asarray(box, dtype=float)
        self.nu = polytope.deformed(gamma)
        F = len(self.nu)
        a, b = np.nonzero(~np.eye(F, dtype=bool))
        dn = self.nu[a] - self.nu[b]
        nn = np.einsum("ij,ij->i", dn[:, :2], dn[:, :2])
        keep = nn > 1e-24 * np.abs(self.nu).max() ** 2          # horizontal walls (none if printable) skipped
        self.pa, self.pb, self.dn, self.nn = a[keep], b[keep], dn[keep], nn[keep]
        self.tangent = np.column_stack([-self.dn[:, 1], self.dn[:, 0]]) / np.sqrt(self.nn)[:, None]
        # activity constraints of every piece: (ν_a − ν_c)·(y − p_1) ≥ 0 and (ν_b − ν_c)·(y − p_j) ≥ 0, all c
        self.D1 = self.nu[self.pa][:, None, :] - self.nu[None]        # (P, F, 3)
        self.D2 = self.nu[self.pb][:, None, :] - self.nu[None]
        self.rate1 = np.einsum("pfk,pk->pf", self.D1[..., :2], self.tangent)
        self.rate2 = np.einsum("pfk,pk->pf", self.D2[..., :2], self.tangent)
        self.Dn1 = np.einsum("pfk,pk->pf", self.D1[..., :2], self.dn[:, :2])
        self.Dn2 = np.einsum("pfk,pk->pf", self.D2[..., :2], self.dn[:, :2])
        self.pos = [r > 1e-14 for r in (self.rate1, self.rate2)]
        self.neg = [r < -1e-14 for r in (self.rate1, self.rate2)]
        self.sloped = [p | n for p, n in zip(self.pos, self.neg)]     # flat constraints must hold at s = 0
        self.G = float(np.linalg.norm(self.nu[:, :2], axis=1).max())
        # candidates are searched in u = (x/γ, y, z), where the gauge is P's own: g(v) ≥ |v_u| / R
        self.stretch = np.array([1.0 / gamma, 1.0, 1.0])
        self.R = float(np.linalg.norm(polytope.vertices(1.0), axis=1).max())
        self.n_seeds = len(seeds)
        self.seeds = np.asarray(seeds, dtype=float)
        self.box_u = self.box * self.stretch
        self._tile(np.ones(3, dtype=int))
        from meshes import _gauge_native

        self._native = _gauge_native.load()
        c = lambda a, t=np.float64: np.ascontiguousarray(a, dtype=t)  # noqa: E731
        self._c = {"nu": c(self.nu), "pa": c(self.pa, np.int32), "pb": c(self.pb, np.int32), "dn": c(self.dn),
                   "nn": c(self.nn), "t": c(self.tangent), "D1": c(self.D1), "r1": c(self.rate1), "Dn1": c(self.Dn1),
                   "D2": c(self.D2), "r2": c(self.rate2), "Dn2": c(self.Dn2)}

    def _tile(self, m: np.ndarray) -> None:
        """Site images over ``{−m_a..m_a}`` periods along each axis ``a``."""
        if np.prod(2 * m + 1) * self.n_seeds > _MAX_IMAGES:
            raise ComputationError(f"gauge walls: the cells span more than {m.tolist()} periods of the box "
                               f"{self.box.tolist()}; use more cells or a box that follows the cells")
        r = [np.arange(-k, k + 1) for k in m]
        shifts = np.stack(np.meshgrid(*r, indexing="ij"), axis=-1).reshape(-1, 3)
        self.m = m
        self.images = np.ascontiguousarray((self.seeds[None] + shifts[:, None] * self.box).reshape(-1, 3))
        self.image_seed = np.tile(np.arange(self.n_seeds), len(shifts))
        self.tree = cKDTree(self.images * self.stretch)
        self.reach = m * self.box_u          # every site within reach[a] of a box point along a is tiled

    def gauge_nearest(self, x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The ``k`` site images nearest to ``x`` in ``u``: Euclidean ``u``-distances, indices, gauge distances."""
        while True:
            e, idx = self.tree.query(x * self.stretch, k=k)
            far = float(e[:, -1].max()) if len(e) else 0.0
            if far < self.reach.min():
                break
            self._tile(np.maximum(self.m, np.ceil(far / self.box_u).astype(int) + 1))
        v = x[:, None, :] - self.images[idx]
        d = np.max(v @ self.nu.T, axis=-1)
        return e, idx, d

    def evaluate(self, x: np.ndarray, upper: float = np.inf, details: bool = False):
        """``ψ`` at points ``x`` (M, 3) in the box: exact where ``ψ ≤ upper``, some value ``> upper`` elsewhere.

        With ``details=True`` returns ``(ψ, foot, cell, normal)``: the foot of ``x`` on its nearest wall in the
        layer (on the site images next to ``x``; ``x`` itself where ``ψ > upper``), the cell (seed index) of ``x``
        and the unit normal ``ν_a − ν_b`` of that wall (zero where ``ψ > upper``).
        """
        x = np.asarray(x, dtype=float).reshape(-1, 3)
        parts = [self._evaluate_chunk(x[i:i + _CHUNK], upper) for i in range(0, len(x), _CHUNK)] or \
            [self._evaluate_chunk(x, upper)]
        out = tuple(np.concatenate([p[i] for p in parts]) for i in range(4))
        return out if details else out[0]

    def _evaluate_chunk(self, x: np.ndarray, upper: float):
        if self._native is not None:
            return self._evaluate_native(x, upper)
        return self._evaluate_numpy(x, upper)

    def _evaluate_native(self, x: np.ndarray, upper: float):
        """The compiled kernel (``_gauge_kernel.c``).

        The same algebra as :meth:`_evaluate_numpy`, one point at a time with early exits.
        """
        ffi, lib = self._native
        M = len(x)
        psi = np.full(M, np.inf)
        feet = x.copy()
        piece = np.full(M, -1, dtype=np.int32)
        first = np.zeros(M, dtype=np.int64)
        todo = np.arange(M)
        k = 16
        c = self._c

        def ptr(a, kind="double *"):
            return ffi.cast(kind, a.ctypes.data)

        while todo.size:
            k = min(k, len(self.images))
            xt = np.ascontiguousarray(x[todo])
            e, idx = self._query(xt, k)
            m = len(todo)
            out = (np.empty(m), np.empty((m, 3)), np.empty(m, dtype=np.int32), np.empty(m, dtype=np.int64),
                   np.empty(m, dtype=np.int32))
            idx = np.ascontiguousarray(idx, dtype=np.int64)
            e = np.ascontiguousarray(e)
            lib.gw_evaluate(m, ptr(xt), k, ptr(idx, "int64_t *"), ptr(e), ptr(self.images), len(self.nu),
                            ptr(c["nu"]), len(self.pa), ptr(c["pa"], "int *"), ptr(c["pb"], "int *"),
                            ptr(c["dn"]), ptr(c["nn"]), ptr(c["t"]), ptr(c["D1"]), ptr(c["r1"]), ptr(c["Dn1"]),
                            ptr(c["D2"]), ptr(c["r2"]), ptr(c["Dn2"]), self.R, self.G, float(upper),
                            int(k == len(self.images)), ptr(out[0]), ptr(out[1]), ptr(out[2], "int *"),
                            ptr(out[3], "int64_t *"), ptr(out[4], "int *"))
            done = out[4].astype(bool)
            rows = todo[done]
            psi[rows], feet[rows], piece[rows], first[rows] = out[0][done], out[1][done], out[2][done], \
                out[3][done]
            todo = todo[~done]
            k *= 2
        normals = np.zeros_like(x)
        has = piece >= 0
        normals[has] = self.dn[piece[has]] / np.linalg.norm(self.dn[piece[has]], axis=1)[:, None]
        feet[~np.isfinite(psi)] = x[~np.isfinite(psi)]
        return psi, feet, self.image_seed[first], normals

    def _query(self, x: np.ndarray, k: int):
        """The ``k`` Euclidean nearest site images in ``u``, enlarging the tiling when they reach its edge."""
        while True:
            e, idx = self.tree.query(x * self.stretch, k=k)
            far = float(e[:, -1].max()) if len(e) else 0.0
            if far < self.reach.min():
                return e, idx
            self._tile(np.maximum(self.m, np.ceil(far / self.box_u).astype(int) + 1))

    def _evaluate_numpy(self, x: np.ndarray, upper: float):
        M = len(x)
        psi = np.full(M, np.inf)
        feet = x.copy()
        normals = np.zeros_like(x)
        cells = np.empty(M, dtype=np.int64)
        todo = np.arange(M)
        k = 16
        while todo.size:
            k = min(k, len(self.images))
            e, idx, d = self.gauge_nearest(x[todo], k)
            rows = np.arange(len(todo))
            first = np.argmin(d, axis=1)
            d1 = d[rows, first]
            cells[todo] = self.image_seed[idx[rows, first]]
            lower = (d - d1[:, None]) / (2.0 * self.G)             # ψ_j ≥ this
            lower[rows, first] = np.inf
            outside = (e[:, -1] / self.R - d1) / (2.0 * self.G)    # ψ_j ≥ this for every site not among the k
            order = np.argsort(lower, axis=1)
            best = np.full(len(todo), np.inf)
            for col in range(order.shape[1] - 1):
                j = order[:, col]
                lj = lower[rows, j]
                active = lj <= np.minimum(best, upper)
                if not active.any():
                    break
                sel = np.flatnonzero(active)
                dist, foot, normal = self._bisector_distance(x[todo[sel]], self.images[idx[sel, first[sel]]],
                                                            self.images[idx[sel, j[sel]]])
                better = dist < best[sel]
                upd = sel[better]
                best[upd] = dist[better]
                feet[todo[upd]] = foot[better]
                normals[todo[upd]] = normal[better]
            # the candidates skipped above have a lower bound > min(ψ, upper) (sorted, and ψ only decreases); the
            # result is exact once every site not among the k has one too
            done = (outside >= np.minimum(best, upper)) | (k == len(self.images))
            psi[todo[done]] = best[done]
            todo = todo[~done]
            k *= 2
        return psi, feet, cells, normals

    def _bisector_distance(self, x: np.ndarray, p1: np.ndarray, pj: np.ndarray):
        """In-layer distance from ``x`` (M, 3) to the bisector polyline of sites ``p1``, ``pj`` (M, 3 each).

        Returns the distance (M,), the nearest point (M, 3) and the unit normal of its piece (M, 3).
        """
        z = x[:, 2]
        dn, nn, t = self.dn, self.nn, self.tangent                                  # (P, 3), (P,), (P, 2)
        P, F = self.D1.shape[:2]
        c = p1 @ self.nu[self.pa].T - pj @ self.nu[self.pb].T - z[:, None] * dn[:, 2]   # (M, P)
        s_perp = (x[:, :2] @ dn[:, :2].T - c) / nn                                  # (M, P): foot y0 = x − s_perp n
        lo = np.full(s_perp.shape, -np.inf)
        hi = np.full(s_perp.shape, np.inf)
        ok = lo <= hi
        for D, Dn, rate, p in ((self.D1, self.Dn1, self.rate1, p1), (self.D2, self.Dn2, self.rate2, pj)):
            # D·((y0 + s t, z) − p) = D·(x − p) − s_perp (D_xy·n) + s (D_xy·t) ≥ 0
            val0 = ((x - p) @ D.reshape(-1, 3).T).reshape(-1, P, F) - s_perp[..., None] * Dn
            with np.errstate(divide="ignore", invalid="ignore"):
                bound = -val0 / rate
            lo = np.maximum(lo, np.where(self.pos[rate is self.rate2], bound, -np.inf).max(axis=2))
            hi = np.minimum(hi, np.where(self.neg[rate is self.rate2], bound, np.inf).min(axis=2))
            ok &= np.all(self.sloped[rate is self.rate2] | (val0 >= -1e-12), axis=2)
        ok &= lo <= hi
        s = np.clip(0.0, lo, hi)
        dist = np.where(ok, np.sqrt(s_perp**2 * nn + s**2), np.inf)
        piece = np.argmin(dist, axis=1)
        rows = np.arange(len(x))
        foot = x[:, :2] - s_perp[rows, piece][:, None] * dn[piece, :2] + s[rows, piece][:, None] * t[piece]
        normal = dn[piece] / np.linalg.norm(dn[piece], axis=1)[:, None]
        return dist[rows, piece], np.column_stack([foot, z]), normal
