"""The paper's Fig. 4 (its authors' homogenized IceSL foams) against the shipped foam tables and candidate foams.

The data: three of the four densities of each series of the paper's Fig. 4, as published in its authors' SOFA
plugin (repository VannesteFelix/anisotropy, file examples/Tripod/homogenized_value.py), normalised by the solid's
Young's modulus (ν_s = 0.3), the foam's distinct axis l = x. The fourth density of each series
(:data:`HELD_OUT_ROWS`) was held out while the foam model was chosen and its one free parameter (the pores'
modulus) fitted, and is compared only as a check of the finished table. These are a peer's CrAFT FFT
homogenization of a geometry that is not public (IceSL's foams, the paper's ref. [11]): evidence about the printed
foam, not ground truth.

``compare`` (default)
    Prints, for every shipped table (``homogenization.tables.shipped_tables``, read through
    ``fenicsfoam.material.table.foam_table``) and every row the table covers, the table's value interpolated at the
    paper's density and γ with the seed scatter (the ``*_std`` column, ± one standard deviation over the seeds)
    and the ratio ours / paper, then the same for the held-out rows; the power laws ``q = C ρ^n`` of every paper
    series and quantity (least squares in log–log over its three rows); writes ``fig4_comparison.csv``,
    ``fig4_held_out.csv``, ``fig4_scaling.csv`` and the figure ``fig4.png`` (``--figure`` elsewhere). Candidate
    samples measured by ``measure`` (``--samples``, a CSV) are drawn as open symbols.
``measure``
    Homogenizes small candidate RVEs at the paper's densities (``--candidate``, ``--gamma``, ``--density``,
    ``--grid``, ``--discretization``, ``--seeds``), cached one JSON per sample under ``--cache`` by
    :func:`homogenization.tables.run_sweep` (rerunning resumes), and appends their rows to ``--samples``.
    Candidates: ``wall`` (the polyhedral wall foam, ``distance="polyhedral"``) and ``strut`` (the Euclidean strut
    foam), both 8 cells in the equiaxed box; ``edge`` (struts along the polyhedral diagram's edges,
    :func:`gauge_edge_image`). Built and homogenized here, uncached, with each image's connectivity
    (:func:`measure_direct`): ``wall-direct`` (the wall foam's own voxels on any grid), ``wall-normal`` (walls
    whose width is measured normal to the wall) and ``hybrid`` (walls and edge struts, ``--strut-fraction`` of
    the density in the struts, :func:`hybrid_image`); ``--cases normal`` solves the three normal load cases only
    (E's and ν's) and ``--void-modulus`` gives the pores a small stiffness instead of none.

Run: ``nice -n 10 python studies/fig4.py --out out/fig4 --figure docs/img/fig4.png`` (seconds; ``--ci`` is the same).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The paper's quantities (l = x) and the table columns that hold them (docs/conventions.md: ν_ij = −ε_j/ε_i
#: under σ_i, so the paper's ν_zx is ``nu31``).
QUANTITIES = {"E_x": "E1", "E_y": "E2", "E_z": "E3", "nu_xy": "nu12", "nu_zx": "nu31", "nu_yz": "nu23",
              "G_yz": "G23", "G_zx": "G13", "G_xy": "G12"}
MODULI = ("E_x", "E_y", "E_z", "G_yz", "G_zx", "G_xy")
#: The series of Fig. 4: name → γ.
SERIES = {"transverse": 0.1, "isotropic": 1.0}

#: Fig. 4, three densities per series (VannesteFelix/anisotropy, examples/Tripod/homogenized_value.py),
#: moduli / E_s, ν_s = 0.3, l = x. Columns: density, then QUANTITIES in order.
PAPER_ROWS = {
    "transverse": ((0.0918, 0.007191, 0.06771, 0.06181, 0.04032, 0.3896, 0.2404, 0.02697, 0.002804, 0.002701),
                   (0.2639, 0.009439, 0.2214, 0.2104, 0.02048, 0.4718, 0.2789, 0.08568, 0.005476, 0.005139),
                   (0.3422, 0.01094, 0.2943, 0.2843, 0.01908, 0.5058, 0.2816, 0.1143, 0.007109, 0.006673)),
    "isotropic": ((0.0901, 0.02622, 0.02631, 0.02156, 0.2901, 0.2295, 0.2830, 0.01192, 0.01166, 0.009776),
                  (0.2323, 0.07927, 0.07911, 0.06311, 0.2841, 0.2250, 0.2854, 0.03478, 0.03411, 0.03006),
                  (0.3297, 0.1317, 0.1316, 0.1098, 0.2705, 0.2348, 0.2826, 0.05683, 0.05588, 0.04992)),
}
#: Fig. 4, the fourth density of each series (same source and columns), kept out of every choice and fit.
HELD_OUT_ROWS = {
    "transverse": ((0.1798, 0.008230, 0.1463, 0.1372, 0.02435, 0.4297, 0.2725, 0.05667, 0.004074, 0.003833),),
    "isotropic": ((0.1534, 0.04699, 0.04697, 0.03684, 0.2908, 0.2210, 0.2853, 0.02093, 0.02044, 0.01755),),
}


def paper_rows(held_out: bool = False) -> list[dict]:
    """The Fig. 4 rows as dictionaries: ``series``, ``gamma``, ``density`` and every key of :data:`QUANTITIES`.

    ``held_out``: the held-out rows (:data:`HELD_OUT_ROWS`) instead of the three used ones (:data:`PAPER_ROWS`).
    """
    out = []
    for series, rows in (HELD_OUT_ROWS if held_out else PAPER_ROWS).items():
        for row in rows:
            out.append({"series": series, "gamma": SERIES[series], "density": row[0],
                        **dict(zip(QUANTITIES, row[1:]))})
    return out


def scaling(rows: list[dict]) -> list[dict]:
    """Power laws ``q = C ρ^n`` per series and quantity: least squares of ``log q`` on ``log ρ``.

    Returns one dict per (series, quantity) with ``n``, ``C`` and the largest relative misfit of the law on the
    rows (``max_misfit``); Poisson's ratios are fitted too (a small ``n`` means constant).
    """
    out = []
    for series in SERIES:
        sel = [r for r in rows if r["series"] == series]
        rho = np.log([r["density"] for r in sel])
        for q in QUANTITIES:
            y = np.log([r[q] for r in sel])
            n, logc = np.polyfit(rho, y, 1)
            misfit = float(np.max(np.abs(np.exp(logc + n * rho - y) - 1.0)))
            out.append({"series": series, "quantity": q, "n": float(n), "C": float(np.exp(logc)),
                        "max_misfit": misfit})
    return out


def compare_table(table, rows: list[dict], label: str) -> list[dict]:
    """Table ``table`` (a :class:`fenicsfoam.material.table.FoamTable`) at the rows it covers, quantity by quantity.

    Each result: ``table``, ``series``, ``gamma``, ``density``, ``quantity``, ``paper``, ``ours`` (the table's
    interpolation, the one every scene uses), ``ours_std`` (the seed standard deviation, its ``*_std`` column
    interpolated in the same way, linearly) and ``ratio = ours / paper``. Rows outside the table's density or γ
    range (it is never extrapolated) are left out.
    """
    lo, hi = table.density_range
    glo, ghi = table.gamma_range
    out = []
    for r in rows:
        if not (lo - 1e-12 <= r["density"] <= hi + 1e-12 and glo - 1e-12 <= r["gamma"] <= ghi + 1e-12):
            continue
        for q, col in QUANTITIES.items():
            ours = table.value(col, r["density"], r["gamma"])
            std = table.value(col + "_std", r["density"], r["gamma"])
            out.append({"table": label, "series": r["series"], "gamma": r["gamma"], "density": r["density"],
                        "quantity": q, "paper": r[q], "ours": ours, "ours_std": std, "ratio": ours / r[q]})
    return out


def table_nodes(table, label: str) -> list[dict]:
    """Every node of a table at the paper's two γ (for tables too small to interpolate at the paper's densities)."""
    out = []
    d = table.data
    for series, g in SERIES.items():
        for i in np.flatnonzero(np.isclose(d["gamma"], g)):
            out.append({"table": label, "series": series, "gamma": g, "density": float(d["density"][i]),
                        **{q: float(d[c][i]) for q, c in QUANTITIES.items()},
                        **{q + "_std": float(d[c + "_std"][i]) for q, c in QUANTITIES.items()}})
    return out


def _write_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def format_comparison(comparison: list[dict]) -> str:
    """A Markdown table: one line per (table, row), ``ours ± std (ratio)`` per quantity."""
    lines = ["| table | series | density | " + " | ".join(QUANTITIES) + " |",
             "|---|---|---|" + "---|" * len(QUANTITIES)]
    keys = sorted({(c["table"], c["series"], c["density"]) for c in comparison},
                  key=lambda k: (k[0], -SERIES[k[1]], k[2]))
    for key in keys:
        cells = {c["quantity"]: c for c in comparison if (c["table"], c["series"], c["density"]) == key}
        lines.append(f"| {key[0]} | {key[1]} | {key[2]:g} | " + " | ".join(
            f"{cells[q]['ours']:.3g} ± {cells[q]['ours_std']:.2g} ({cells[q]['ratio']:.2g})" for q in QUANTITIES)
            + " |")
    return "\n".join(lines)


def format_scaling(laws: list[dict]) -> str:
    lines = ["| series | " + " | ".join(QUANTITIES) + " |", "|---|" + "---|" * len(QUANTITIES)]
    for series in SERIES:
        cells = {l["quantity"]: l for l in laws if l["series"] == series}
        lines.append(f"| {series} (n; C) | " + " | ".join(f"{cells[q]['n']:.2f}; {cells[q]['C']:.3g}"
                                                          for q in QUANTITIES) + " |")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------------
# The figure
# --------------------------------------------------------------------------------------------------
_STYLE = {"cube": ("tab:blue", "-"), "equiaxed": ("tab:orange", "-"), "equiaxed_polyhedral": ("tab:green", "-")}
#: candidate samples: open symbols in the colour of the table of the same members (edge struts: red)
_CANDIDATE_COLOR = {"wall": "tab:green", "strut": "tab:orange", "edge": "tab:red"}


def figure(path: Path, rows: list[dict], tables: dict, samples: list[dict], held_out: list[dict] = ()) -> Path:
    """E's, G's and ν's against density, one row of panels per series: paper markers (held-out rows open),
    tables as lines ± std."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = (("E_x", "E_y", "E_z"), ("G_yz", "G_zx", "G_xy"), ("nu_xy", "nu_zx", "nu_yz"))
    fig, axes = plt.subplots(2, 9, figsize=(26, 6.5), sharex=True)
    for s, (series, gamma) in enumerate(SERIES.items()):
        paper = [r for r in rows if r["series"] == series]
        for g, group in enumerate(groups):
            for k, q in enumerate(group):
                ax = axes[s, 3 * g + k]
                ax.plot([r["density"] for r in paper], [r[q] for r in paper], "ks", ms=7, label="paper (Fig. 4)")
                held = [r for r in held_out if r["series"] == series]
                ax.plot([r["density"] for r in held], [r[q] for r in held], "ks", ms=7, mfc="none",
                        label="paper (Fig. 4), held out")
                for label, table in tables.items():
                    color, ls = _STYLE.get(label, ("tab:gray", "-"))
                    lo, hi = table.density_range
                    if gamma in table.grid and len(table.grid[gamma]) > 1:
                        x = np.linspace(lo, hi, 60)
                        col = QUANTITIES[q]
                        y = table.column(col, x, np.full_like(x, gamma)).value
                        e = table.column(col + "_std", x, np.full_like(x, gamma)).value
                        ax.plot(x, y, ls, color=color, label=label)
                        ax.fill_between(x, y - e, y + e, color=color, alpha=0.2, lw=0)
                    for node in table_nodes(table, label):
                        if node["series"] == series:
                            ax.errorbar(node["density"], node[q], yerr=node[q + "_std"], fmt="o", color=color,
                                        capsize=3, label=None if len(table.grid.get(gamma, ())) > 1 else label)
                for m in samples:
                    if float(m["gamma"]) == gamma:
                        mk = "^" if m.get("discretization", "rotated") == "hex8" else "v"
                        ax.plot(float(m["measured_density"]), float(m[QUANTITIES[q]]), mk, mfc="none",
                                color=_CANDIDATE_COLOR.get(m["candidate"], "tab:red"),
                                label=f"{m['candidate']} {m.get('discretization', 'rotated')}")
                if q in MODULI:
                    ax.set_yscale("log")
                ax.set_title(f"{series} (γ = {gamma:g}): {q}", fontsize=9)
                ax.tick_params(labelsize=7)
                if s == 1:
                    ax.set_xlabel("relative density", fontsize=8)
    handles = {}
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(list(handles.values()), list(handles), loc="lower center", ncol=len(handles), fontsize=8)
    fig.suptitle("Fig. 4 of the paper (squares; open: held out) against foam tables (lines ± seed std; points: "
                 "single-density tables) and candidate samples (▲ hex8, ▼ rotated; seed 0) — moduli / E_s, "
                 "ν_s = 0.3, l = x", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------------
# Candidate measurements
# --------------------------------------------------------------------------------------------------
CANDIDATES = {"wall": "polyhedral", "strut": "euclidean", "edge": None, "wall-direct": None, "wall-normal": None,
              "hybrid": None}
#: candidates built and homogenized by :func:`measure_direct`
DIRECT = ("wall-direct", "wall-normal", "hybrid")


def gauge_edge_skeleton(n_cells: int, gamma: float, seed: int, shape) -> tuple[np.ndarray, np.ndarray]:
    """The skeleton of the polyhedral diagram's edges on a voxel grid: ``(points, box)``.

    The seeds, box (γ, 1, 1) and polytope (:func:`meshes.gauge.default_polytope` shrunk by γ along x) of
    ``VoronoiFoam(n_cells, ·, gamma, seed, box="equiaxed", distance="polyhedral")``. Every voxel centre gets its
    gauge-nearest seed (exact: site images beyond the k examined are farther, :class:`meshes.gauge.GaugeWalls`);
    the skeleton is the set of voxel corners whose 2×2×2 voxels hold at least three cells (the diagram's edges, to
    within a voxel: at such a corner three seeds are gauge-nearest to within ``2 L |h|/2``, ``L`` the largest
    ``|ν_i|``).
    """
    from meshes.gauge import GaugeWalls, default_polytope

    box = np.array([gamma, 1.0, 1.0])
    seeds = np.random.default_rng(seed).random((n_cells, 3)) * box
    walls = GaugeWalls(seeds, box, default_polytope(), gamma)
    shape = tuple(shape)
    h = box / np.array(shape)
    centres = _centres(shape, box)
    labels = np.empty(len(centres), dtype=np.int64)
    for i0 in range(0, len(centres), 1 << 13):
        xs = centres[i0:i0 + (1 << 13)]
        k = 8
        while True:
            k = min(k, len(walls.images))
            e, idx, d = walls.gauge_nearest(xs, k)
            j = np.argmin(d, axis=1)
            if k == len(walls.images) or np.all(e[:, -1] / walls.R >= d[np.arange(len(xs)), j]):
                break
            k *= 2
        labels[i0:i0 + len(xs)] = walls.image_seed[idx[np.arange(len(xs)), j]]
    labels = labels.reshape(shape)
    corners = np.stack([np.roll(labels, (-a, -b, -c), axis=(0, 1, 2)) for a in (0, 1) for b in (0, 1)
                        for c in (0, 1)])
    distinct = 1 + np.count_nonzero(np.diff(np.sort(corners, axis=0), axis=0), axis=0)
    skeleton = np.argwhere(distinct >= 3) * h + h          # the block's centre: the shared voxel corner
    return np.where(skeleton >= box, skeleton - box, skeleton), box


def _centres(shape, box) -> np.ndarray:
    h = box / np.array(shape)
    axes = [(np.arange(n) + 0.5) * hh for n, hh in zip(shape, h)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def gauge_edge_image(n_cells: int, density: float, gamma: float, seed: int, shape) -> tuple[np.ndarray, dict]:
    """Voxels of struts along the edges of the polyhedral Voronoi diagram (a candidate, resolution-limited).

    The solid is the set of points within the Euclidean distance ``r`` of :func:`gauge_edge_skeleton`, ``r`` the
    ``density``-quantile of that distance over the voxel centres (their distances to the corner lattice take few
    values, so the voxel density is the target to within one shell of ties). Returns the bool image and
    ``{"radius", "measured_density" (of the voxels), "continuous_density" (of the foams' quasi-Monte-Carlo sample
    at r), "skeleton_points", "edge_dir_abs_cos_x"}`` (the mean |cos| with x of the principal direction of each
    skeleton point's neighbours within 2.5 voxels).
    """
    from scipy.spatial import cKDTree

    from meshes import foam as foam_mod

    shape = tuple(shape)
    skeleton, box = gauge_edge_skeleton(n_cells, gamma, seed, shape)
    h = box / np.array(shape)
    tree = cKDTree(skeleton, boxsize=box)
    dc = tree.query(_centres(shape, box))[0]
    rank = max(int(np.ceil(density * len(dc))) - 1, 0)
    r = float(np.partition(dc, rank)[rank])
    img = (dc <= r).reshape(shape)
    ds = tree.query(foam_mod._density_sample().reshape(-1, 3) * box)[0]
    along_x = []
    for i, nb in enumerate(tree.query_ball_point(skeleton, 2.5 * float(h.max()))):
        if len(nb) < 3:
            continue
        v = skeleton[nb] - skeleton[i]
        v -= np.rint(v / box) * box
        along_x.append(abs(np.linalg.eigh(v.T @ v)[1][0, -1]))
    return img, {"radius": r, "measured_density": float(img.mean()), "continuous_density": float(np.mean(ds <= r)),
                 "skeleton_points": len(skeleton),
                 "edge_dir_abs_cos_x": float(np.mean(along_x)) if along_x else float("nan")}


def measure_edge(args) -> list[dict]:
    """The ``edge`` candidate: :func:`gauge_edge_image` homogenized directly (not cached: it is not a table foam)."""
    import time

    from homogenization.fft import homogenize_fft
    from homogenization.tensors import engineering_constants, isotropic_voigt

    rows = []
    for grid in args.grid:
        gamma, _, res = grid.partition("=")
        gamma = float(gamma)
        box = np.array([gamma, 1.0, 1.0])
        shape = tuple(int(v) for v in res.split("x")) if "x" in res else tuple(
            int(round(int(res) * b)) for b in box)
        for density in args.density:
            for seed in args.seeds:
                t0 = time.perf_counter()
                img, info = gauge_edge_image(args.cells, density, gamma, seed, shape)
                built = time.perf_counter() - t0
                for disc in args.discretization:
                    t1 = time.perf_counter()
                    r = homogenize_fft(img.astype(np.int8), [np.zeros((6, 6)), isotropic_voigt(1.0, 0.3)],
                                       discretization=disc, box=tuple(box), tol=args.tol, maxiter=args.maxiter)
                    row = {"candidate": "edge", "discretization": disc, "density": density, "gamma": gamma,
                           "seed": seed, "resolution": "x".join(map(str, shape)), **info,
                           **engineering_constants(r.C), "iterations": int(sum(r.iterations)),
                           "wall_s": built + time.perf_counter() - t1}
                    rows.append(row)
    return rows


def wall_field(n_cells: int, gamma: float, seed: int, shape, upper: float) -> tuple[np.ndarray, np.ndarray]:
    """The polyhedral wall field at the voxel centres: ``(ψ, |n_xy|)``, each of the grid's shape.

    ``ψ`` is the in-layer (horizontal) distance to the nearest wall of the diagram of
    ``VoronoiFoam(n_cells, ·, gamma, seed, box="equiaxed", distance="polyhedral")`` (exact up to ``upper``, some
    value ``> upper`` beyond), the field whose level set ``ψ ≤ r`` is that foam's solid; ``|n_xy|`` the horizontal
    part of the unit normal of that wall (0 beyond ``upper``), so ``ψ |n_xy|`` is the distance measured normal to
    the wall (exact near a wall's face, away from the wall's edges).
    """
    from meshes.gauge import GaugeWalls, default_polytope

    box = np.array([gamma, 1.0, 1.0])
    seeds = np.random.default_rng(seed).random((n_cells, 3)) * box
    walls = GaugeWalls(seeds, box, default_polytope(), gamma)
    psi, _, _, n = walls.evaluate(_centres(tuple(shape), box), upper=upper, details=True)
    return psi.reshape(shape), np.linalg.norm(n[:, :2], axis=1).reshape(shape)


def _quantile_level(values: np.ndarray, count: int) -> float:
    """The ``count``-th smallest of ``values`` (so that ``values <= level`` holds at least ``count`` of them)."""
    count = int(np.clip(count, 1, values.size))
    return float(np.partition(values.ravel(), count - 1)[count - 1])


def hybrid_image(n_cells: int, density: float, gamma: float, seed: int, shape, strut_fraction: float,
                 fields: dict | None = None) -> tuple[np.ndarray, dict]:
    """Walls and edge struts of the polyhedral diagram together, as one voxel image (a candidate).

    The struts are :func:`gauge_edge_image`'s (voxel centres within ``r_s`` of the edge skeleton), ``r_s`` the
    ``strut_fraction × density``-quantile of the skeleton distance over the voxel centres; the walls are the
    polyhedral wall foam's level set ``ψ ≤ r_w`` (:func:`wall_field`), ``r_w`` chosen so that the union holds
    exactly ``ceil(density × voxels)`` voxels (up to ties of ``ψ``): the walls take the rest of the density outside
    the struts (at ``strut_fraction`` 1 there are no walls, and the struts hold the density to within one shell of
    ties of the skeleton distance). ``strut_fraction`` 0 is the wall foam on these voxels, 1 the ``edge``
    candidate. ``fields`` (``{"skeleton": distances, "psi": ψ}``, from an earlier call on the same grid) saves
    recomputing them.
    Returns the bool image and ``{"measured_density", "strut_density" (of the struts alone), "wall_radius",
    "strut_radius"}``.
    """
    from scipy.spatial import cKDTree

    if not (isinstance(strut_fraction, (int, float)) and 0.0 <= strut_fraction <= 1.0):
        raise ValueError(f"strut_fraction must lie in [0, 1], got {strut_fraction!r}")
    shape = tuple(shape)
    box = np.array([gamma, 1.0, 1.0])
    fields = {} if fields is None else fields
    if "skeleton" not in fields:
        skeleton, _ = gauge_edge_skeleton(n_cells, gamma, seed, shape)
        fields["skeleton"] = cKDTree(skeleton, boxsize=box).query(_centres(shape, box))[0].reshape(shape)
    if "psi" not in fields:
        from meshes.foam import VoronoiFoam

        r = VoronoiFoam(n_cells, min(density * 1.5, 0.45), gamma, seed=seed, box="equiaxed",
                        distance="polyhedral").radius
        fields["psi"] = wall_field(n_cells, gamma, seed, shape, upper=r)[0]
    dc, psi = fields["skeleton"], fields["psi"]
    total = int(np.ceil(density * dc.size))
    if strut_fraction > 0:
        r_s = _quantile_level(dc, int(np.ceil(strut_fraction * total)))
        struts = dc <= r_s
    else:
        r_s, struts = 0.0, np.zeros(shape, dtype=bool)
    rest = total - int(struts.sum())
    r_w = _quantile_level(psi[~struts], rest) if rest > 0 else 0.0
    if rest > 0 and not np.isfinite(r_w):
        raise ValueError(f"wall field computed up to too small a distance for density {density}")
    img = struts | ((psi <= r_w) if rest > 0 else False)
    return img, {"measured_density": float(img.mean()), "strut_density": float(struts.mean()),
                 "wall_radius": r_w, "strut_radius": r_s, "strut_fraction": strut_fraction}


def homogenize_image(img: np.ndarray, box, disc: str, tol: float, maxiter: int, cases: str = "all",
                     void_modulus: float = 0.0) -> dict:
    """Engineering constants, iterations and connectivity of one bool image (E_s = 1, ν_s = 0.3).

    ``void_modulus`` > 0 gives the pores an isotropic stiffness ``(void_modulus, 0.3)`` instead of zero (a
    compliant phase such as a fixed-point FFT scheme needs; see the validation page).

    ``cases="normal"`` solves the three normal load cases only and reads ``E_i``, ``ν_ij`` from the inverse of
    the normal 3×3 block of C (exact for an orthotropic C; the shear–normal couplings it leaves out are checked
    against the six-case C where both were run); the G's are then NaN.
    """
    import time

    from homogenization.connectivity import connectivity
    from homogenization.fft import homogenize_fft
    from homogenization.tensors import engineering_constants, isotropic_voigt

    t1 = time.perf_counter()
    strains = None if cases == "all" else np.eye(6)[:3]
    void = isotropic_voigt(void_modulus, 0.3) if void_modulus > 0 else np.zeros((6, 6))
    r = homogenize_fft(img.astype(np.int8), [void, isotropic_voigt(1.0, 0.3)], discretization=disc,
                       box=tuple(box), tol=tol, maxiter=maxiter, macro_strains=strains,
                       allow_singular=cases != "all")
    if cases == "all":
        out = engineering_constants(r.C)
        S = np.linalg.inv(np.asarray(r.C)[:3, :3])
        out["E1_normal_block"] = float(1.0 / S[0, 0])
    else:
        S = np.linalg.inv(np.asarray(r.C)[:3, :3])
        out = {f"E{i + 1}": float(1.0 / S[i, i]) for i in range(3)}
        out.update({f"nu{i + 1}{j + 1}": float(-S[i, j] / S[i, i]) for i in range(3) for j in range(3) if i != j})
        out.update({"G23": float("nan"), "G13": float("nan"), "G12": float("nan")})
        out["E1_normal_block"] = out["E1"]
    conn = connectivity(img)
    out.update({"cases": cases, "iterations": int(sum(r.iterations)), "solve_s": time.perf_counter() - t1,
                "edge_contacts_x": conn.edge_contacts[0], "edge_contacts_y": conn.edge_contacts[1],
                "edge_contacts_z": conn.edge_contacts[2], "corner_contacts": conn.corner_contacts,
                "islands": conn.hinged_islands + conn.floating_islands})
    return out


def _grid_shape(grid: str) -> tuple[float, tuple[int, int, int]]:
    gamma, _, res = grid.partition("=")
    gamma = float(gamma)
    box = np.array([gamma, 1.0, 1.0])
    shape = tuple(int(v) for v in res.split("x")) if "x" in res else tuple(int(round(int(res) * b)) for b in box)
    return gamma, shape


def measure_direct(args) -> list[dict]:
    """Candidates built here on the voxels (not cached; every row also has the image's connectivity).

    ``wall-direct``: the polyhedral wall foam voxelized by ``VoronoiFoam.voxelize`` (the table samples' image);
    ``wall-normal``: the same walls with their width measured normal to the wall (``ψ |n_xy| ≤ r``, ``r`` the
    density quantile over the voxel centres); ``hybrid``: :func:`hybrid_image` at each ``--strut-fraction``.
    """
    import time

    from meshes.foam import VoronoiFoam

    rows = []
    for grid in args.grid:
        gamma, shape = _grid_shape(grid)
        box = np.array([gamma, 1.0, 1.0])
        for seed in args.seeds:
            fields: dict = {}
            for density in args.density:
                fractions = args.strut_fraction if args.candidate == "hybrid" else [None]
                for phi in fractions:
                    t0 = time.perf_counter()
                    if args.candidate == "wall-direct":
                        foam = VoronoiFoam(args.cells, density, gamma, seed=seed, box="equiaxed",
                                           distance="polyhedral")
                        img = foam.voxelize(shape, cubic=False)
                        info = {"measured_density": float(img.mean()), "wall_radius": foam.radius}
                    elif args.candidate == "wall-normal":
                        if "normal" not in fields:
                            r = VoronoiFoam(args.cells, min(1.5 * max(args.density), 0.45), gamma, seed=seed,
                                            box="equiaxed", distance="polyhedral").radius
                            psi, nxy = wall_field(args.cells, gamma, seed, shape, upper=r)
                            near = np.isfinite(psi) & (psi <= r)
                            fields["normal"] = np.full(psi.shape, np.inf)
                            fields["normal"][near] = psi[near] * nxy[near]
                        level = _quantile_level(fields["normal"], int(np.ceil(density * np.prod(shape))))
                        img = fields["normal"] <= level
                        info = {"measured_density": float(img.mean()), "wall_radius": level}
                    else:
                        img, info = hybrid_image(args.cells, density, gamma, seed, shape, phi, fields)
                    built = time.perf_counter() - t0
                    for disc in args.discretization:
                        res = homogenize_image(img, box, disc, args.tol, args.maxiter, args.cases,
                                               args.void_modulus)
                        label = args.candidate if phi is None else f"hybrid{phi:g}"
                        if args.void_modulus > 0:
                            label += f"+void{args.void_modulus:g}"
                        rows.append({"candidate": label, "discretization": disc, "density": density,
                                     "gamma": gamma, "seed": seed, "resolution": "x".join(map(str, shape)),
                                     "void_modulus": args.void_modulus, **info, **res,
                                     "wall_s": built + res["solve_s"]})
                        _save(rows[-1:], args)
    return rows


def measure(args) -> list[dict]:
    from homogenization.tables import Sample, SweepSettings, run_sweep

    if args.candidate == "edge":
        return _save(measure_edge(args), args)
    if args.candidate in DIRECT:
        return measure_direct(args)
    rows = []
    for grid in args.grid:
        gamma, _, res = grid.partition("=")
        gamma = float(gamma)
        cubic = "x" not in res
        resolution = int(res) if cubic else res
        for disc in args.discretization:
            settings = SweepSettings(n_cells=args.cells, resolution=resolution, tol=args.tol, box="equiaxed",
                                     distance=CANDIDATES[args.candidate], maxiter=args.maxiter, cubic=cubic,
                                     discretization=disc)
            samples = [Sample(d, gamma, s) for d in args.density for s in args.seeds]
            for row in run_sweep(samples, settings, args.cache):
                rows.append({"candidate": args.candidate, "discretization": disc, **row})
    return _save(rows, args)


def _save(rows: list[dict], args) -> list[dict]:
    """Merge ``rows`` into the samples CSV (keyed by candidate, discretization, γ, density, seed, grid); print."""
    if rows:
        path = Path(args.samples)
        old = []
        if path.exists():
            with open(path, newline="") as f:
                old = list(csv.DictReader(f))
        keys = list(dict.fromkeys(["candidate", "discretization", *(k for r in old + rows for k in r)]))
        merged = {(r["candidate"], r["discretization"], str(r["gamma"]), str(r["density"]), str(r["seed"]),
                   str(r["resolution"])): r for r in old + rows}
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
            w.writeheader()
            w.writerows(merged.values())
        for r in rows:
            print(f"{r['candidate']:6s} {r['discretization']:8s} γ={r['gamma']:g} ρ={r['density']:g} seed "
                  f"{r['seed']} {r['resolution']}: " + "  ".join(f"{q}={r[c]:.4g}" for q, c in QUANTITIES.items())
                  + f"  ({r['iterations']} it, {r['wall_s']:.0f} s)")
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="out/fig4")
    p.add_argument("--figure", default=None, help="figure path (default OUT/fig4.png)")
    p.add_argument("--samples", default=None, help="candidate samples CSV written by 'measure'")
    p.add_argument("--ci", action="store_true", help="the comparison only (it takes seconds at any size)")
    p.add_argument("--table", nargs="+", default=[], metavar="CSV",
                   help="compare: also these aggregated table files (e.g. a sweep's table before it ships)")
    sub = p.add_subparsers(dest="command")
    sub.add_parser("compare")
    m = sub.add_parser("measure")
    m.add_argument("--candidate", choices=sorted(CANDIDATES), required=True)
    m.add_argument("--grid", nargs="+", required=True, help="GAMMA=N or GAMMA=N1xN2xN3 (non-cubic)")
    m.add_argument("--density", type=float, nargs="+", required=True)
    m.add_argument("--seeds", type=int, nargs="+", default=[0])
    m.add_argument("--cells", type=int, default=8)
    m.add_argument("--tol", type=float, default=1e-3)
    m.add_argument("--maxiter", type=int, default=6000)
    m.add_argument("--discretization", nargs="+", default=["rotated", "hex8"])
    m.add_argument("--cache", default="out/fig4-cache")
    m.add_argument("--samples", dest="samples_out", default="out/fig4/samples.csv")
    m.add_argument("--strut-fraction", type=float, nargs="+", default=[0.5],
                   help="hybrid: fraction of the density in the edge struts (0: walls only, 1: struts only)")
    m.add_argument("--void-modulus", type=float, default=0.0,
                   help="direct candidates: Young's modulus of the pores / E_s (default 0: void)")
    m.add_argument("--cases", choices=("all", "normal"), default="all",
                   help="direct candidates: all six load cases, or the three normal ones (E's and ν's only)")
    args = p.parse_args(argv)
    if args.command == "measure":
        args.samples = args.samples_out
        measure(args)
        return 0

    from mpi4py import MPI

    from fenicsfoam.material.table import foam_table
    from homogenization.tables import shipped_tables

    rows = paper_rows()
    tables = {name: foam_table(name) for name in shipped_tables()}
    tables.update({Path(path).stem.removeprefix("foam_table_"): foam_table(path) for path in args.table})
    comparison = [c for name, t in tables.items() for c in compare_table(t, rows, name)]
    held_out = [c for name, t in tables.items() for c in compare_table(t, paper_rows(held_out=True), name)]
    laws = scaling(rows)
    # checks: every covered row has all quantities; the interpolation is the table at its nodes
    failures = []
    for name, t in tables.items():
        covered = {(c["series"], c["density"]) for c in comparison if c["table"] == name}
        n = sum(1 for c in comparison if c["table"] == name)
        if n != len(QUANTITIES) * len(covered):
            failures.append(f"{name}: {n} comparisons for {len(covered)} rows")
        d = t.data
        for col in QUANTITIES.values():
            for i in range(len(d["density"])):
                v = t.value(col, float(d["density"][i]), float(d["gamma"][i]))
                if abs(v - d[col][i]) > 1e-9 * abs(d[col][i]):
                    failures.append(f"{name}: {col} at node {i} interpolates to {v}, not {d[col][i]}")
    if MPI.COMM_WORLD.rank != 0:
        return 1 if failures else 0
    samples = []
    if args.samples:
        with open(args.samples, newline="") as f:
            samples = list(csv.DictReader(f))
    out = Path(args.out)
    _write_csv(comparison, out / "fig4_comparison.csv")
    _write_csv(held_out, out / "fig4_held_out.csv")
    _write_csv(laws, out / "fig4_scaling.csv")
    print("Power laws q = C ρ^n of the paper's rows (n; C):\n" + format_scaling(laws) + "\n")
    print("Shipped tables at the paper's densities (ours ± seed std (ours / paper)):\n"
          + format_comparison(comparison) + "\n")
    print("The held-out rows (ours ± seed std (ours / paper)):\n" + format_comparison(held_out) + "\n")
    uncovered = sorted({(r["series"], r["density"]) for r in rows} - {(c["series"], c["density"])
                                                                     for c in comparison if c["table"] == "cube"})
    print(f"Rows outside the cube table's range: {uncovered}")
    law = {(l["series"], l["quantity"]): l for l in laws}
    for name, t in tables.items():
        if all(len(v) < 2 for v in t.grid.values()):
            print(f"{name}: one density per γ; its nodes against the paper's power law at the node's density "
                  "(ours ± seed std (ours / law)):")
            for node in table_nodes(t, name):
                at = {q: law[(node["series"], q)]["C"] * node["density"] ** law[(node["series"], q)]["n"]
                      for q in QUANTITIES}
                print(f"  {node['series']} {node['density']:g}: " + "  ".join(
                    f"{q} {node[q]:.3g} ± {node[q + '_std']:.2g} ({node[q] / at[q]:.2g})" for q in QUANTITIES))
    if samples:
        print("Candidate samples (value (value / the paper's power law at the sample's measured density)):")
    for m in samples:
        series = next(s for s, g in SERIES.items() if g == float(m["gamma"]))
        d = float(m["measured_density"])
        at = {q: law[(series, q)]["C"] * d ** law[(series, q)]["n"] for q in QUANTITIES}
        print(f"  {m['candidate']} {m['discretization']} γ={float(m['gamma']):g} ρ={d:.4g} {m['resolution']}: "
              + "  ".join(f"{q} {float(m[c]):.3g} ({float(m[c]) / at[q]:.2g})" for q, c in QUANTITIES.items()))
    path = figure(Path(args.figure) if args.figure else out / "fig4.png", rows, tables, samples,
                  paper_rows(held_out=True))
    print(f"wrote {out / 'fig4_comparison.csv'}, {out / 'fig4_held_out.csv'}, {out / 'fig4_scaling.csv'}, {path}")
    for f in failures:
        print("CHECK FAILED:", f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
