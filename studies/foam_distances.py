"""Euclidean strut foam and polyhedral wall foam side by side at γ = 1, 0.5, 0.1: pictures and statistics.

For each distance and γ: one foam (27 cells, density 0.18, seed 1, equiaxed box (γ, 1, 1)), its measured
density, radius (strut radius / half wall width), the orientation statistics of :class:`meshes.foam.FoamSummary`
(mean |cos| with x, y, z — of strut directions for struts, of wall normals for walls —, the fabric tensor's
diagonal: the share of material directed along x, y, z; wall area per volume and the largest wall overhang from
the build direction z) and the histogram of element angles to x (length-weighted strut angle, area-weighted
wall-normal angle).

Pictures (``--out``, and with ``--docs`` also ``docs/img/``):

* ``foam_distances.png``: for each foam a horizontal section (x–y, the printed layer, at z = ½) and a vertical
  section (x–z at y = ½), solid black, at 500 pixels per unit length, in the box's true proportions;
* ``foam_orientation.png``: the angle histograms.

Also writes ``foam_distances.csv``. ``--ci``: 8 cells at γ = 1 only, coarse sections. ``--pixels``: pixels per
unit length of the sections (default 500).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import matplotlib
import numpy as np
from mpi4py import MPI

from homogenization.tables import to_csv
from meshes.foam import VoronoiFoam

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

GAMMAS = (1.0, 0.5, 0.1)
DISTANCES = ("euclidean", "polyhedral")
DOCS_IMG = Path(__file__).resolve().parents[1] / "docs" / "img"


def section(foam: VoronoiFoam, plane: str, pixels_per_unit: int) -> np.ndarray:
    """Solid indicator of the section ``plane`` ("xy" at z = ½ L3, "xz" at y = ½ L2), shape (n_x, n_other)."""
    L = foam.box
    a, b = (0, 1) if plane == "xy" else (0, 2)
    na, nb = max(2, round(L[a] * pixels_per_unit)), max(2, round(L[b] * pixels_per_unit))
    ua = (np.arange(na) + 0.5) / na * L[a]
    ub = (np.arange(nb) + 0.5) / nb * L[b]
    A, B = np.meshgrid(ua, ub, indexing="ij")
    x = np.empty((A.size, 3))
    x[:, a], x[:, b] = A.ravel(), B.ravel()
    x[:, 3 - a - b] = 0.5 * L[3 - a - b]
    return foam._inside(x).reshape(na, nb)


def describe(foam: VoronoiFoam, distance: str) -> dict:
    s = foam.summary.as_dict()
    edges, w = foam.orientation_histogram(9)
    row = {"distance": distance, "gamma": foam.gamma, "n_cells": foam.n_cells, "density": foam.density,
           "measured_density": foam.measured_density, "radius": foam.radius} | s
    row.update({f"angle_{int(e0)}_{int(e1)}": float(v) for e0, e1, v in zip(edges[:-1], edges[1:], w)})
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--docs", action="store_true", help="also copy the pictures into docs/img")
    p.add_argument("--pixels", type=int, default=500, help="pixels per unit length of the sections")
    p.add_argument("--ci", action="store_true")
    a = p.parse_args(argv)
    rank0 = MPI.COMM_WORLD.rank == 0
    n_cells, ppu, gammas = (8, 60, (1.0,)) if a.ci else (27, a.pixels, GAMMAS)
    a.out.mkdir(parents=True, exist_ok=True)
    foams = {(d, g): VoronoiFoam(n_cells, 0.18, g, seed=1, box="equiaxed", distance=d)
             for d in DISTANCES for g in gammas}
    rows = [describe(f, d) for (d, _), f in foams.items()]
    failures = [f"{r['distance']} γ = {r['gamma']}: density {r['measured_density']:.4f}" for r in rows
                if abs(r["measured_density"] - r["density"]) > 0.002]
    failures += [f"polyhedral γ = {r['gamma']}: overhang {r['max_overhang_deg']:.1f}° > 45°" for r in rows
                 if r["distance"] == "polyhedral" and r["max_overhang_deg"] > 45.0 + 1e-9]
    if not rank0:
        return 1 if failures else 0
    print(f"{'distance':>10} {'gamma':>5} {'radius':>8} {'|cos x|':>7} {'|cos y|':>7} {'|cos z|':>7} "
          f"{'fab_xx':>6} {'fab_yy':>6} {'fab_zz':>6} {'area/V':>7} {'overhang':>8}")
    for r in rows:
        print(f"{r['distance']:>10} {r['gamma']:5.2f} {r['radius']:8.5f} {r['mean_abs_cos_x']:7.3f} "
              f"{r['mean_abs_cos_y']:7.3f} {r['mean_abs_cos_z']:7.3f} {r['fabric_xx']:6.3f} {r['fabric_yy']:6.3f} "
              f"{r['fabric_zz']:6.3f} {r['wall_area_per_volume']:7.2f} {r['max_overhang_deg']:8.1f}")
    to_csv(rows, a.out / "foam_distances.csv")

    fig, axes = plt.subplots(4, len(gammas), figsize=(11 * len(gammas) / 3, 13), gridspec_kw={"hspace": 0.35},
                             squeeze=False)
    for col, g in enumerate(gammas):
        for row, (d, plane) in enumerate([(d, pl) for d in DISTANCES for pl in ("xy", "xz")]):
            img = section(foams[d, g], plane, ppu)
            ax = axes[row, col]
            L = foams[d, g].box
            other = 1 if plane == "xy" else 2
            ax.imshow(~img.T, cmap="gray", origin="lower", extent=(0, L[0], 0, L[other]), interpolation="nearest")
            ax.set_xlabel("x")
            ax.set_ylabel("y" if plane == "xy" else "z (build)")
            ax.set_title(f"{d}, γ = {g:g}: {plane} section", fontsize=9)
    fig.suptitle(f"Euclidean strut foam and polyhedral wall foam, {n_cells} cells, 18 %, equiaxed box (γ, 1, 1)")
    png = a.out / "foam_distances.png"
    fig.savefig(png, dpi=110, bbox_inches="tight")
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, d in zip(axes, DISTANCES):
        for g in gammas:
            edges, w = foams[d, g].orientation_histogram(9)
            ax.step(edges, np.r_[w, w[-1]], where="post", label=f"γ = {g:g}")
        ax.set_xlabel("strut angle to x (deg)" if d == "euclidean" else "wall-normal angle to x (deg)")
        ax.set_ylabel("length share" if d == "euclidean" else "area share")
        ax.set_title(f"{d} foam")
        ax.legend()
    png2 = a.out / "foam_orientation.png"
    fig.savefig(png2, dpi=110, bbox_inches="tight")
    plt.close(fig)
    if a.docs:
        DOCS_IMG.mkdir(parents=True, exist_ok=True)
        for path in (png, png2):
            shutil.copyfile(path, DOCS_IMG / path.name)
    print(f"wrote {png}, {png2}, {a.out / 'foam_distances.csv'}")
    for f in failures:
        print(f"FAILED: {f}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
