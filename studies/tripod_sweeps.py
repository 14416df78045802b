"""Design sweeps of the Tripod's foam plates: what twist and lift a designer gets for each layout.

- Case A (`demos/scenes/tripod_case_a_flat.toml`): the angle between each arm's l axis and the arm, 0°–90°, turned
  counter-clockwise (seen from above) on all three arms; 0° and 90° are mirror symmetric layouts (no twist).
- Case B (`demos/scenes/tripod_case_b_flat.toml`): the pitch of the counter-clockwise spiral, 0° (circles) to 90°
  (radial); both ends are mirror symmetric (no twist).

Everything else is the shipped scene (its foam from today's foam table, its servo schedule rest / middle 19° /
top 38°); each point reports the changes of the centre's height and twist from rest to middle and top. A run that
does not converge is a row with its status (and a gap in the plot). Writes `case_a_offset.csv`,
`case_b_pitch.csv` and one plot each (`case_a_offset.png`, `case_b_pitch.png`) in ``--out``.

Checks (exit status 1 if one fails): every point converges, the centre rises from rest to middle to top, and
the mirror-symmetric end points (0° and 90°) twist by less than 1e-9° (round-off: the mesh is D3-invariant).

Run: `python studies/tripod_sweeps.py --out out/tripod_sweeps [--degrees 1 2] [--step 10] [--ci]`
(serial or under `mpirun -n 2`; P1 ≈ 1 min, P2 ≈ 10 min on a shared 2-core machine; ``--ci``: the end points
0° and 90° only, P1 on the 2202-tetrahedron mesh, seconds).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import tomllib
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fenicsfoam.scene import run_scene
from fenicsfoam.solver import ConvergenceError
from foambase.cli import report_checks
from foambase.logs import setup_logging

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"
ARM_DEG = (0.0, 120.0, 240.0)  # meshes.tripod.ARM_ANGLES_DEG
#: Mesh size of ``--ci`` (2202 tetrahedra, D3-invariant).
CI_H = 0.006
#: |twist| of a mirror-symmetric end point at the top (deg): round-off.
SYMMETRIC_TWIST_DEG = 1e-9
FIELDS = ("design", "value_deg", "degree", "status", "dh_middle_mm", "dh_top_mm", "da_middle_deg", "da_top_deg")


def case_a(offset_deg: float) -> dict:
    """Case A with each arm's l axis ``offset_deg`` counter-clockwise from the arm."""
    scene = tomllib.loads((SCENES / "tripod_case_a_flat.toml").read_text())
    scene["orientation"]["directions"] = {
        f"arm{i}": [math.cos(math.radians(a + offset_deg)), math.sin(math.radians(a + offset_deg)), 0.0]
        for i, a in enumerate(ARM_DEG)}
    return scene


def case_b(pitch_deg: float) -> dict:
    """Case B with a counter-clockwise spiral of pitch ``pitch_deg``."""
    scene = tomllib.loads((SCENES / "tripod_case_b_flat.toml").read_text())
    scene["orientation"]["pitch_deg"] = pitch_deg
    return scene


def run_point(design: str, value: float, degree: int, comm, h: float | None = None) -> dict:
    """One scene run (``h``: another mesh size); the changes from rest (mm, degrees), or the failure."""
    scene = case_a(value) if design == "case_a_offset" else case_b(value)
    scene["fem"]["degree"] = degree
    if h is not None:
        scene["geometry"]["h"] = h
    scene["outputs"] = {"xdmf": False, "png": False}
    row = dict.fromkeys(FIELDS, math.nan) | {"design": design, "value_deg": value, "degree": degree, "status": "ok"}
    try:
        result = run_scene(scene, comm=comm)
    except ConvergenceError as exc:
        row["status"] = f"failed in {exc.step} at {exc.load_factor:.0%}: {exc.reason}"
        return row
    height = result.probe("center_height", relative_to="rest")
    angle = result.probe("center_rotation", relative_to="rest")
    row.update(dh_middle_mm=1e3 * height["middle"], dh_top_mm=1e3 * height["top"],
               da_middle_deg=angle["middle"], da_top_deg=angle["top"])
    return row


def write_csv(rows: list[dict], path: Path) -> None:
    """Rows as CSV, atomically."""
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


def plot(rows: list[dict], path: Path, xlabel: str, title: str) -> None:
    """Δangle (left) and Δheight (right) at top (solid) and middle (dashed) against the design variable."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax2 = ax.twinx()
    for degree, marker in ((1, "o"), (2, "s")):
        sel = [r for r in rows if r["degree"] == degree]
        if not sel:
            continue
        x = [r["value_deg"] for r in sel]
        for key, style, axis, color, what in (("da_top_deg", "-", ax, "C0", "Δangle top"),
                                              ("da_middle_deg", "--", ax, "C0", "Δangle middle"),
                                              ("dh_top_mm", "-", ax2, "C3", "Δheight top"),
                                              ("dh_middle_mm", "--", ax2, "C3", "Δheight middle")):
            axis.plot(x, [r[key] for r in sel], style, marker=marker, color=color, label=f"{what}, P{degree}")
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("change of twist from rest (deg)", color="C0")
    ax2.set_ylabel("change of height from rest (mm)", color="C3")
    lines = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
    labels = ax.get_legend_handles_labels()[1] + ax2.get_legend_handles_labels()[1]
    ax.legend(lines, labels, fontsize=7, loc="best")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp, dpi=120)
    plt.close(fig)
    os.replace(tmp, path)


def table(rows: list[dict], name: str) -> str:
    """The sweep as printed text."""
    lines = [f"{name:>8s} {'P':>2s} {'Δh mid':>8s} {'Δh top':>8s} {'Δa mid':>8s} {'Δa top':>8s}  status"]
    for r in rows:
        lines.append(f"{r['value_deg']:8.1f} {r['degree']:2d} {r['dh_middle_mm']:8.2f} {r['dh_top_mm']:8.2f} "
                     f"{r['da_middle_deg']:8.2f} {r['da_top_deg']:8.2f}  {r['status']}")
    return "\n".join(lines)


def check(rows: list[dict]) -> list[str]:
    """Failed checks (messages; see the module docstring)."""
    failures = []
    for r in rows:
        where = f"{r['design']} = {r['value_deg']:g}° (P{r['degree']})"
        if r["status"] != "ok":
            failures.append(f"{where}: {r['status']}")
            continue
        if not 0 < r["dh_middle_mm"] < r["dh_top_mm"]:
            failures.append(f"{where}: the centre does not rise from rest to middle to top "
                            f"({r['dh_middle_mm']:.4g}, {r['dh_top_mm']:.4g} mm)")
        if r["value_deg"] in (0.0, 90.0) and not abs(r["da_top_deg"]) < SYMMETRIC_TWIST_DEG:
            failures.append(f"{where}: a mirror-symmetric layout twists by {r['da_top_deg']:.3g}° at the top "
                            f"(bound {SYMMETRIC_TWIST_DEG:g}°)")
    return failures


def main(out: Path, degrees: list[int], step: float, ci: bool = False) -> int:
    """Run both sweeps, print and write them (rank 0), check them; the exit status."""
    comm = MPI.COMM_WORLD
    if ci:
        degrees, step = [1], 90.0
    values = np.arange(0.0, 90.0 + 1e-9, step)
    sweeps = {"case_a_offset": ("l axis from the arm, counter-clockwise (deg)",
                                "Tripod case A: l axes turned from the arms"),
              "case_b_pitch": ("spiral pitch (deg): 0 circles, 90 radial", "Tripod case B: spiral pitch")}
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    failures: list[str] = []
    for design, (xlabel, title) in sweeps.items():
        rows = [run_point(design, float(v), degree, comm, CI_H if ci else None) for degree in degrees for v in values]
        failures += check(rows)
        if comm.rank == 0:
            print(f"{design} (changes from rest: height mm, twist deg)")
            print(table(rows, "offset" if design == "case_a_offset" else "pitch"))
            write_csv(rows, out / f"{design}.csv")
            plot(rows, out / f"{design}.png", xlabel, title)
    if comm.rank == 0:
        print(f"CSV and PNG in {out}")
    return report_checks(failures, comm)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Tripod design sweeps: case A l-axis offset, case B spiral pitch.")
    parser.add_argument("--out", type=Path, default=Path("out/tripod_sweeps"))
    parser.add_argument("--degrees", type=int, nargs="+", default=[1], choices=(1, 2))
    parser.add_argument("--step", type=float, default=10.0, help="step of the swept angle (deg)")
    parser.add_argument("--ci", action="store_true", help="the end points 0° and 90° only, P1, h = 6 mm")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v INFO, -vv DEBUG)")
    args = parser.parse_args()
    setup_logging(args.verbose)
    sys.exit(main(args.out, args.degrees, args.step, args.ci))
