"""The polyhedral wall foam homogenized: its resolution study and its table at the Fig. 6 beams' density.

Foams ``VoronoiFoam(n, density, γ, seed, box="equiaxed", distance="polyhedral")`` (walls one track wide along the
faces of the polyhedral Voronoi diagram, docs/foam.md), 8 cells in the equiaxed box ``(γ, 1, 1)`` unless
``--cells``, homogenized by :func:`homogenization.tables.run_sweep` (cached one JSON per sample under ``--cache``,
so the two studies and reruns share their samples).

A grid is given per γ as ``--grid GAMMA=N`` (cubic voxels, ``N`` along the longest box edge) or
``--grid GAMMA=N1xN2xN3`` (the grid itself, non-cubic voxels allowed: ``SweepSettings(cubic=False)``). At γ = 0.1
the walls are sheets nearly normal to x (area-weighted mean |cos(normal, x)| ≈ 0.94), so their width is resolved
by the x spacing: ``60x300x300`` in the box ``(0.1, 1, 1)`` (voxels twice as long along y and z as along x) puts
about three voxels across a wall at a quarter of the cubic ``(60, 600, 600)`` grid's voxels. That is a numerical
choice, checked by ``resolution``.

``resolution``
    Seeds ``--seeds`` (default 0) at every ``--grid`` of each γ; prints the moduli per grid with the voxels across
    a wall along x and y (``2 × half width / h``), and for each family of grids of one voxel aspect with at least
    three members a Richardson estimate (``q = q0 + c h^p`` through the three finest,
    :func:`homogenization.convergence.richardson`, in the x spacing) with the remaining bias of each level. With
    ``--discretization bracket`` each sample is the midpoint of its rotated and hex8 samples (each computed and
    cached on its own, so a rotated and a hex8 study of the same grids cost nothing more;
    :func:`homogenization.tables.bracket_samples`), and each level's midpoint and hex8 side are set against the
    finest level's bracket (:func:`against_finest_bracket`): which estimate a bracket table should ship.
``table``
    Every ``--density`` × one grid per γ (``--grid``, the last given for a γ wins), seeds ``--seeds`` (default
    0 1 2), in one resumable run: with ``--reference-density REF`` each ``--grid`` is the grid at ``REF``, scaled
    at the other densities by :func:`homogenization.tables.scaled_resolution` (constant voxels across a wall).
    Writes one table ``equiaxed_polyhedral`` (``_hex8`` with ``--discretization hex8``, ``_pores0p0045`` with
    ``--pore-modulus 0.0045``: pores of that stiffness, :attr:`SweepSettings.name`) over the whole grid with its
    samples and provenance (every node's settings) under ``--out``, and with ``--ship`` into
    ``homogenization/data``. Exits 1 if a sample misses its density by more than 0.002.
``merge``
    ``--from DIR [DIR ...]``: the tables of earlier ``table`` runs merged into one under ``--out``
    (:func:`homogenization.tables.merge_tables`; refuses a (density, γ) node at different settings in two runs).
    With ``--name NAME`` the merged table is ``NAME`` and its sources may be different tables (e.g. one γ from a
    hex8 table, another from a bracket table); each node keeps its source's settings.
``bracket``
    ``--from ROTATED_DIR HEX8_DIR``: a rotated and a hex8 table of the same samples as one ``"bracket"`` table
    under ``--out`` (:func:`homogenization.tables.bracket_tables`: the mean stiffness of the two discretizations of
    each sample, with the bracket's relative half width per modulus; the same rows as a ``--discretization
    bracket`` sweep). ``--estimate hex8``: each row the hex8 sample, with the same widths.

Run: ``OMP_NUM_THREADS=1 python studies/wall_foam.py table --grid 0.1=60x300x300 --grid 1=96 --cache
out/wall-cache --out out/wall-table`` (``mpirun -n 2`` deals the samples to two ranks; with ``--distribute fft``
each sample is computed by both ranks together, for a grid too slow for one). ``--ci``: both studies on tiny
samples (4 cells, 45 %).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from foam_rve_study import summarize
from mpi4py import MPI

from homogenization import tables
from homogenization.convergence import richardson

MODULI = ("E1", "E2", "E3", "G23", "G13", "G12", "ti_E_t", "ti_E_l", "ti_G_l", "iso_E")


def parse_grid(text: str) -> tuple[float, object]:
    """``'0.1=60x300x300'`` → ``(0.1, (60, 300, 300))``; ``'1=96'`` → ``(1.0, 96)``."""
    try:
        gamma, grid = text.split("=")
        if "x" in grid:
            shape = tuple(int(n) for n in grid.split("x"))
            if len(shape) != 3:
                raise ValueError
            return float(gamma), shape
        return float(gamma), int(grid)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a grid is GAMMA=N or GAMMA=N1xN2xN3, got {text!r}") from None


def parse_seeds(text: str) -> tuple[float, list[int]]:
    """``'1=0,1,2'`` → ``(1.0, [0, 1, 2])``."""
    try:
        gamma, seeds = text.split("=")
        return float(gamma), [int(s) for s in seeds.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"seeds per γ are GAMMA=S1,S2,..., got {text!r}") from None


def settings_for(grid, a) -> tables.SweepSettings:
    cubic = not isinstance(grid, tuple)
    return tables.SweepSettings(n_cells=a.cells, resolution=grid, tol=a.tol, box="equiaxed", distance="polyhedral",
                                maxiter=a.maxiter, cubic=cubic, discretization=a.discretization,
                                pore_modulus=a.pore_modulus)


def spacing(gamma: float, grid) -> np.ndarray:
    """Voxel edges ``(h1, h2, h3)`` of a grid in the equiaxed box ``(γ, 1, 1)``."""
    box = np.array([gamma, 1.0, 1.0])
    shape = np.array(grid if isinstance(grid, tuple) else np.rint(grid * box / box.max()), dtype=float)
    return box / shape


def resolution_study(a, comm) -> int:
    rows, side_rows = [], {"rotated": [], "hex8": []}
    for gamma, grid in a.grid:
        samples, settings = tables.grid(a.density, (gamma,), a.seeds), settings_for(grid, a)
        kinds = ("rotated", "hex8") if a.discretization == "bracket" else (a.discretization,)
        sides = [tables.run_sweep(samples, replace(settings, discretization=kind), a.cache, comm, threads=1,
                                  progress=False, distribute=a.distribute) for kind in kinds]
        rows += tables.bracket_samples(*sides) if a.discretization == "bracket" else sides[0]
        if a.discretization == "bracket":
            for kind, side in zip(kinds, sides, strict=True):
                side_rows[kind] += side
    if comm.rank != 0:
        return 0
    rows = [r | {"resolution": str(r["resolution"])} for r in rows]  # N or 'N1xN2xN3', one type to sort
    summary = summarize(rows, ("gamma", "n_cells", "resolution"))
    for s in summary:
        members = [r for r in rows if (r["gamma"], r["resolution"]) == (s["gamma"], s["resolution"])]
        res = s["resolution"]
        grid = tuple(int(n) for n in res.split("x")) if "x" in res else int(res)
        h = spacing(s["gamma"], grid)
        half = float(np.mean([r["radius"] for r in members]))
        s.update(h_x=h[0], aspect=h[1] / h[0], across_x=2 * half / h[0], across_y=2 * half / h[1],
                 iterations=float(np.mean([r["iterations"] for r in members])),
                 wall_s=float(np.mean([r["wall_s"] for r in members])))
    summary.sort(key=lambda s: (s["gamma"], round(s["aspect"], 6), -s["h_x"]))
    print(f"{'gamma':>5} {'grid':>12} {'aspect':>6} {'across x':>8} {'iters':>6} {'wall s':>7} "
          + " ".join(f"{n:>10}" for n in MODULI))
    for s in summary:
        print(f"{s['gamma']:5.2f} {str(s['resolution']):>12} {s['aspect']:6.2f} {s['across_x']:8.2f} "
              f"{s['iterations']:6.0f} {s['wall_s']:7.0f} " + " ".join(f"{s[n]:10.4e}" for n in MODULI))
    extrapolated = []
    for gamma, aspect, family in families(summary, 3):
        h = np.array([s["h_x"] for s in family])
        print(f"γ = {gamma}, voxel aspect {aspect:g}: grids {[s['resolution'] for s in family]}")
        for name in MODULI:
            q = np.array([s[name] for s in family])
            est = richardson(h, q)
            q0, p = est.value, est.order
            bias = (q - q0) / q0
            order = f"p = {p:.2f}" if est.asymptotic else f"p = {p:g} assumed: {est.reason}"
            print(f"  {name:>7}: " + " ".join(f"{v:9.4e}" for v in q) + f" → {q0:9.4e} ({order}); bias "
                  + " ".join(f"{b:+.1%}" for b in bias))
            extrapolated += [{"gamma": gamma, "aspect": aspect, "resolution": s["resolution"], "name": name,
                              "value": s[name], "extrapolated": q0, "order": p, "asymptotic": est.asymptotic,
                              "bias": float(b)} for s, b in zip(family, bias, strict=True)]
    against = []
    if a.discretization == "bracket":
        keys = ("gamma", "n_cells", "resolution")
        lower, upper = (summarize([r | {"resolution": str(r["resolution"])} for r in side_rows[kind]], keys)
                        for kind in ("rotated", "hex8"))
        against = against_finest_bracket(summary, lower, upper)
    a.out.mkdir(parents=True, exist_ok=True)
    tables.to_csv(rows, a.out / "resolution.csv")
    tables.to_csv(summary, a.out / "resolution_summary.csv")
    if extrapolated:
        tables.to_csv(extrapolated, a.out / "resolution_richardson.csv")
    if against:
        tables.to_csv(against, a.out / "resolution_bracket.csv")
    print(f"wrote {a.out / 'resolution.csv'}")
    return density_check(rows)


def families(summary: list[dict], minimum: int):
    """``(γ, voxel aspect, levels)`` for every family of grids of one γ and voxel aspect with at least ``minimum``
    levels, the levels coarse to fine."""
    for gamma, aspect in sorted({(s["gamma"], round(s["aspect"], 6)) for s in summary}):
        family = sorted((s for s in summary if (s["gamma"], round(s["aspect"], 6)) == (gamma, aspect)),
                        key=lambda s: -s["h_x"])
        if len(family) >= minimum:
            yield gamma, aspect, family


def against_finest_bracket(summary: list[dict], lower: list[dict], upper: list[dict]) -> list[dict]:
    """Each level's two estimates against the finest level's bracket, per family (γ, voxel aspect) and modulus.

    ``summary``, ``lower``, ``upper``: the seed means per level of the midpoint, rotated and hex8 rows
    (``summary`` with each level's ``h_x`` and ``aspect``). On the assumption that the rotated scheme converges
    from below and hex8 from above (measured on void foams, docs/benchmarks/2026-11-27-void-homogenization.md;
    the levels show whether each side is monotone), the converged value lies in the finest level's bracket
    ``[q_rot, q_hex8]``, so an estimate ``q`` of a level (its midpoint, or its hex8 side) is off by between
    ``q / q_hex8 − 1`` and ``q / q_rot − 1``. Printed as its offset from the finest bracket's middle
    ``(q_rot + q_hex8) / 2`` with that interval; returned as rows (also written as ``resolution_bracket.csv``).
    """
    low, high = ({(s["gamma"], s["resolution"]): s for s in rows} for rows in (lower, upper))
    out = []
    for gamma, aspect, family in families(summary, 2):
        f_lo, f_hi = low[(gamma, family[-1]["resolution"])], high[(gamma, family[-1]["resolution"])]
        print(f"γ = {gamma}, voxel aspect {aspect:g}: each grid's estimates against the finest "
              f"({family[-1]['resolution']}) bracket: offset from its middle (error range if the converged value "
              "lies in it)")
        for q in MODULI:
            lo, hi = sorted((f_lo[q], f_hi[q]))
            cells = []
            for s in family:
                for estimate, value in (("midpoint", s[q]), ("hex8", high[(gamma, s["resolution"])][q])):
                    row = {"gamma": gamma, "aspect": aspect, "resolution": s["resolution"], "name": q,
                           "estimate": estimate, "value": value, "finest_rotated": f_lo[q], "finest_hex8": f_hi[q],
                           "offset": value / (0.5 * (lo + hi)) - 1, "error_low": value / hi - 1,
                           "error_high": value / lo - 1}
                    out.append(row)
                    cells.append(f"{s['resolution']} {estimate} {row['offset']:+.1%} ({row['error_low']:+.1%} … "
                                 f"{row['error_high']:+.1%})")
            print(f"  {q:>7}: " + "; ".join(cells))
    return out


def node_grid(a, density: float, gamma: float, grid):
    """The grid of one (density, γ) node: ``grid`` itself, or scaled by ``--reference-density`` (the wall rule)."""
    if a.reference_density is None:
        return grid
    return tables.scaled_resolution(grid, density, a.reference_density, gamma, box="equiaxed")


def table(a, comm) -> int:
    start = time.perf_counter()
    grids = dict(a.grid)
    seeds = dict(a.gamma_seeds or [])
    node = {(d, g): settings_for(node_grid(a, d, g, grids[g]), a) for d in a.density for g in grids}
    samples = sorted(tables.Sample(float(d), float(g), int(s)) for d in a.density for g in grids
                     for s in seeds.get(g, a.seeds))
    rows = tables.run_sweep(samples, lambda s: node[(s.density, s.gamma)], a.cache, comm, threads=1,
                            progress=False, distribute=a.distribute)
    if comm.rank != 0:
        return 0
    name = next(iter(node.values())).name
    launcher = f"mpirun -n {comm.size} " if comm.size > 1 else ""
    settings, across = {}, {}
    for (d, g), s in sorted(node.items()):
        key = f"density={d:g},gamma={g:g}"
        settings[key] = tables.settings_dict(s) | {"seeds": seeds.get(g, a.seeds)}
        half = np.mean([r["radius"] for r in rows if (r["density"], r["gamma"]) == (d, g)])  # over the seeds
        across[key] = float(2 * half / spacing(g, s.resolution)[0])
    provenance = {"command": launcher + " ".join(["python", "studies/wall_foam.py", *sys.argv[1:]]),
                  "date": datetime.now(UTC).isoformat(timespec="seconds"), "ranks": comm.size,
                  "wall_s_this_run": time.perf_counter() - start,
                  "sample_wall_s_total": float(sum(r["wall_s"] for r in rows)), "n_samples": len(rows),
                  "grid_rule": ({"reference_density": a.reference_density,
                                 "grids_at_reference_density": {str(g): grids[g] for g in grids},
                                 "rule": "homogenization.tables.scaled_resolution"}
                                if a.reference_density is not None else "the --grid of each gamma at every density"),
                  "voxels_across_a_wall_along_x": across,
                  "settings_per_node": settings}
    paths = tables.write_tables(rows, a.out, provenance, name)
    if a.ship:
        tables.write_tables(rows, tables.DATA_DIR, provenance, name)
    print(tables.format_table(tables.aggregate(rows)))
    print("written: " + ", ".join(str(v) for v in paths.values()))
    return density_check(rows)


def merge(a, comm) -> int:
    if comm.rank == 0:
        paths = tables.merge_tables(a.sources, a.out, name=a.name)
        print("written: " + ", ".join(str(v) for v in paths.values()))
    return 0


def bracket(a, comm) -> int:
    if comm.rank == 0:
        paths = tables.bracket_tables(*a.sources, a.out, estimate=a.estimate)
        rows = tables.aggregate(tables.read_samples(paths["samples"]))
        print(tables.format_table(rows))
        print("widest bracket (relative half width) per modulus: " + ", ".join(
            f"{q} {max(r[f'bracket_{q}'] for r in rows):.1%}" for q in tables.BRACKETED))
        print("written: " + ", ".join(str(v) for v in paths.values()))
    return 0


def density_check(rows: list[dict]) -> int:
    off = [r for r in rows if abs(r["measured_density"] - r["density"]) > 0.002]
    for r in off:
        print(f"FAILED: sample density {r['measured_density']:.4f} for target {r['density']}")
    return 1 if off else 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("study", choices=("resolution", "table", "merge", "bracket"), nargs="?", default="table")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--cache", type=Path, default=None, help="sample cache (default OUT/cache)")
    p.add_argument("--grid", type=parse_grid, action="append", default=None,
                   help="GAMMA=N (cubic voxels) or GAMMA=N1xN2xN3 (the grid, non-cubic voxels allowed)")
    p.add_argument("--density", type=float, nargs="+", default=[0.18],
                   help="relative densities (table: every one × every --grid γ; resolution: one)")
    p.add_argument("--reference-density", type=float, default=None,
                   help="table: each --grid is the grid at this density, scaled by REF/density at the others "
                        "(tables.scaled_resolution: constant voxels across a wall)")
    p.add_argument("--discretization", choices=tables.SWEEP_DISCRETIZATIONS, default="rotated",
                   help="voxels: rotated (default here: the shipped table's, one-point, from below) or hex8 (fully "
                        "integrated, from above; the library's default for new tables)")
    p.add_argument("--pore-modulus", type=float, default=0.0,
                   help="Young's modulus of the pores / E_s (default 0: void pores; 0.0045 reproduces the paper's "
                        "Fig. 4, docs/validation/2026-11-27-fig4.md section 7); the table name ends in _pores...")
    p.add_argument("--from", dest="sources", type=Path, nargs="+", default=None,
                   help="merge: the table directories (--out of earlier table runs) to merge into --out")
    p.add_argument("--estimate", choices=tables.BRACKET_ESTIMATES, default="midpoint",
                   help="bracket: each row the midpoint of the two discretizations (default) or the hex8 sample, "
                        "with the bracket's widths either way")
    p.add_argument("--name", default=None,
                   help="merge: the merged table's name; lets tables of different settings (e.g. discretizations "
                        "chosen per γ) be merged, node by node")
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="default 0 (resolution), 0 1 2 (table)")
    p.add_argument("--gamma-seeds", type=parse_seeds, action="append", default=None,
                   help="GAMMA=S1,S2,...: the seeds of one γ (table; default --seeds)")
    p.add_argument("--cells", type=int, default=8)
    p.add_argument("--tol", type=float, default=1e-3)
    p.add_argument("--maxiter", type=int, default=20000, help="CG iterations per load case")
    p.add_argument("--ship", action="store_true", help="table: also write it into homogenization/data")
    p.add_argument("--distribute", choices=("samples", "fft"), default="samples",
                   help="under mpirun: deal the samples to the ranks (default) or compute each sample on all ranks "
                        "together (the distributed FFT, for one large grid)")
    p.add_argument("--ci", action="store_true", help="both studies on tiny samples (seconds)")
    a = p.parse_args(argv)
    a.cache = a.cache or a.out / "cache"
    comm = MPI.COMM_WORLD
    if a.study == "merge":
        if not a.sources:
            p.error("merge needs --from DIR [DIR ...]")
        return merge(a, comm)
    if a.study == "bracket":
        if not a.sources or len(a.sources) != 2:
            p.error("bracket needs --from ROTATED_DIR HEX8_DIR")
        return bracket(a, comm)
    if a.ci:
        a.cells, a.density, a.seeds, a.ship = 4, [0.45], [0], False
        a.grid = [(1.0, (16, 12, 12)), (1.0, (20, 15, 15)), (1.0, (24, 18, 18))]
        status = resolution_study(a, comm)
        a.grid = [(1.0, (24, 18, 18)), (0.5, (16, 24, 24))]  # the first from the cache
        return max(status, table(a, comm))
    if not a.grid:
        p.error("give at least one --grid GAMMA=N or GAMMA=N1xN2xN3")
    if a.study == "resolution" and len(a.density) != 1:
        p.error(f"resolution takes one --density, got {a.density}")
    a.seeds = a.seeds or ([0] if a.study == "resolution" else [0, 1, 2])
    return resolution_study(a, comm) if a.study == "resolution" else table(a, comm)


if __name__ == "__main__":
    sys.exit(main())
