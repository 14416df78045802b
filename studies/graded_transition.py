"""Graded arm–centre transition of Tripod case A: the sharp scene against blends of growing width, on two meshes.

Printed transitions between foam regions are graded, not sharp. ``demos/scenes/tripod_case_a_graded_flat.toml`` blends
the density and γ of case A's arms (TI, 30 %, γ = 0.1) and centre (isotropic, 15 %, γ = 1) across their boundary
(r = 20 mm) over 5 mm (:mod:`fenicsfoam.grading`). This study runs case A sharp (no blend), with a blend of width 0
(which must reproduce the sharp scene: the check), and with widths 2.5, 5 and 10 mm, on the scene's mesh
(h = 3 mm) and on case A's own (h = 5.2 mm); it prints the centre's rise (top − rest, mm) and twist at the top
(deg; case A's l axes are 30° off the arms, so its plate twists), and their changes from the sharp scene, and
writes ``graded_transition.csv``. ``--ci``: h = 8 mm, widths 0 and 5 mm.
"""

import argparse
import sys
import time
import tomllib
from pathlib import Path

from mpi4py import MPI

from fenicsfoam.scene import parse_scene, run_scene
from foambase.cli import report_checks
from foambase.files import write_text_atomic
from foambase.logs import setup_logging

SCENE = Path(__file__).resolve().parents[1] / "demos" / "scenes" / "tripod_case_a_graded_flat.toml"


def run(h: float, width: float | None, comm) -> dict:
    data = tomllib.loads(SCENE.read_text())
    data["geometry"]["h"] = h
    data["outputs"] = {"png": False, "xdmf": False}
    if width is None:
        del data["blends"]
    else:
        data["blends"][0]["width"] = width
    t = time.perf_counter()
    result = run_scene(parse_scene(data), comm=comm)
    heights = [s.probes["center_height"] for s in result.steps]
    return {"h_mm": h * 1e3, "width_mm": "sharp" if width is None else width * 1e3, "cells": result.n_cells,
            "rise_mm": (heights[-1] - heights[0]) * 1e3, "twist_deg": result.steps[-1].probes["center_rotation"],
            "wall_s": time.perf_counter() - t}


def main(out: Path, ci: bool) -> int:
    comm = MPI.COMM_WORLD
    meshes = (0.008,) if ci else (0.003, 0.0052)
    widths = (None, 0.0, 0.005) if ci else (None, 0.0, 0.0025, 0.005, 0.010)
    rows, failures = [], []
    for h in meshes:
        sharp = None
        for width in widths:
            row = run(h, width, comm)
            sharp = row if width is None else sharp
            row["rise_change_pct"] = 100.0 * (row["rise_mm"] / sharp["rise_mm"] - 1.0)
            row["twist_change_pct"] = 100.0 * (row["twist_deg"] / sharp["twist_deg"] - 1.0)
            rows.append(row)
            for key, unit in (("rise_mm", "mm"), ("twist_deg", "deg")):
                if width == 0.0 and abs(row[key] - sharp[key]) > 1e-9 * abs(sharp[key]):
                    failures.append(f"h = {h}: a zero-width blend gives {key} = {row[key]!r} {unit}, the sharp "
                                    f"scene {sharp[key]!r} {unit}")
    if comm.rank == 0:
        print(f"{'h (mm)':>7} {'width (mm)':>11} {'cells':>6} {'rise (mm)':>10} {'change (%)':>11} "
              f"{'twist (deg)':>12} {'change (%)':>11} {'wall (s)':>9}")
        for r in rows:
            width = r["width_mm"] if isinstance(r["width_mm"], str) else f"{r['width_mm']:.1f}"
            print(f"{r['h_mm']:7.1f} {width:>11} {r['cells']:6d} {r['rise_mm']:10.4f} {r['rise_change_pct']:11.3f} "
                  f"{r['twist_deg']:12.4f} {r['twist_change_pct']:11.3f} {r['wall_s']:9.1f}")
        out.mkdir(parents=True, exist_ok=True)
        lines = [",".join(rows[0])] + [",".join(str(r[k]) for k in rows[0]) for r in rows]
        write_text_atomic(out / "graded_transition.csv", "\n".join(lines) + "\n")
    return report_checks(failures, comm)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--ci", action="store_true", help="one coarse mesh, widths 0 and 5 mm")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    args = parser.parse_args()
    setup_logging(args.verbose)
    sys.exit(main(args.out, args.ci))
