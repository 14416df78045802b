# %% [markdown]
# # Predicting the paper's real robots: the datasheet modulus, then one calibrated on one beam
#
# This demo shows:
# - the Fig. 6 beams (`demos/scenes/beam_iso.toml`, `beam_ti_y.toml`, `beam_ti_z.toml`) and the three Tripods of
#   Table I as built (`tripod_silicone.toml`, `tripod_case_a.toml`, `tripod_case_b.toml`: the servos' set-up motion
#   pre-bends the plate, and the steps turn the horns from that rest) run twice:
#   (a) with the filament's datasheet modulus E_s = 12 MPa, as the scenes ship;
#   (b) with E_s calibrated on **one** measurement, the isotropic beam's real sag of −48 mm
#   (`fenicsfoam.calibrate.calibrate_E_solid`, the library call behind `fenicsfoam calibrate`), once per foam
#   table the scenes read, and taken by every foam region from its own table's calibration through the scene key
#   `E_solid = {calibration = "calibration.json"}`;
# - every prediction with its standard deviation over the foam table's seeds
#   (`fenicsfoam.uncertainty.run_with_uncertainty`, the library call behind `fenicsfoam run --uncertainty`);
# - one table, ours ± σ / the paper's simulation / the real robot, with our error and the paper's own error
#   beside it, against the targets below; `experiments.csv` and a parity plot `parity.png` under `--out`.
#
# ## What is calibrated, what is predicted
#
# Only `E_solid`, one scalar per foam table, and only on `beam_iso` (tip deflection at full gravity = −48 mm, the
# paper's real measurement). A calibrated E_s absorbs the bias of the table it was calibrated through (the same
# −48 mm gives a different E_s through another table), so it holds only for foams read from that table: for every
# foam table a scene's foam region reads, `beam_iso` is calibrated with its foam read from that table (its
# region's `table` key replaced), and each foam region takes the calibration of its own table (a scene refuses a
# calibration made through another table). When every scene reads one table this is one calibration. The table,
# the CSV and the plot give the calibrated E_s and the table of every row. Everything else is a prediction: the
# two anisotropic beams, and the Tripods (the silicone plate has no foam, so both columns are the same run).
# Nothing is tuned to the targets.
#
# The foams' moduli are proportional to E_s and their mass is not, so E_s sets how far a part sags under its
# own weight (the beams) and barely changes a part whose motion the servos prescribe (the Tripods): the
# calibration can move the beams, not the Tripods' twist.
#
# ## Targets (the real measurements are the ground truth)
#
# After calibration: the TI beams within 15 % of the real −23 (l along y) / −24 mm (l along z); the Tripod's
# Δangle within 5° and Δheight within 15 % of the real robot at middle and top for cases A and B. Errors:
# relative for lengths, `ours / real − 1`; for angles the difference of magnitudes, `|ours| − |real|`, since
# neither the paper's sign convention nor the sense of its layouts (case A's l axes, case B's spiral) is known.
# The paper's simulation is scored the same way.
#
# ## Uncertainty
#
# σ is the sample standard deviation over the foam table's seeds (per-seed tables; see `docs/cli.md`); for a
# change from rest it is the σ of the per-seed changes. With the calibrated modulus, σ is taken at the nominal
# calibrated E_s (the calibration is not repeated per seed), so the calibrated `beam_iso` keeps a σ although its
# nominal value is the target. σ describes 8-cell RVE samples and overstates a printed part's scatter.
#
# ## Checks (exit status 1 if one fails)
# Stated bands that hold, whatever the foam table (they are not the targets):
# - every calibration reaches −48 mm (1e-6 relative), and the calibrated `beam_iso` run through the calibration
#   file reproduces it (the scene key and the calibration agree); every calibrated run used its table's E_s;
# - Fig. 6's ordering: each γ = 0.1 beam that carries its full weight sags less than the isotropic one;
# - the calibration brings each γ = 0.1 beam closer to the real one than the datasheet modulus does, and within
#   `TI_BEAM_BAND` of it: 15 % at the paper's mesh (the target), 30 % at `--ci`'s 688 tetrahedra, where P1 locking
#   stiffens the shear-dominated beam with l along z;
# - the Tripod's changes from rest barely depend on E_s: with the calibrated modulus they move by less than
#   `TRIPOD_E_RTOL` = 2 % of the datasheet run's (the servos prescribe the motion);
# - a run that stops is a diagnosed material instability (loss of strong ellipticity), never an undiagnosed one;
# - the silicone plate does not twist (mirror symmetry), the two foam plates do (more than 1° at the top);
# - the Tripod's rise of the centre at the middle position (cases A, B) within `TABLE_I_RATIO_BAND` of the real
#   robot's, with both moduli. At the top the as-built scenes rise 27–33 % more than the real robot (P1, the paper's
#   mesh; 41–52 % at P2): a measured, open discrepancy that the foam's constants do not explain (docs' Tripod
#   validation page), printed as MISSED in the targets, not asserted.
# The targets are printed as met or MISSED; why each is missed is measured in the docs' validation pages.
#
# `--ci`: coarse meshes (beams 688, Tripods 2202 tetrahedra) and the seed scatter for the calibrated beams only.
#
# Run: `python demos/experiments.py --out out/experiments [--ci]`; under `mpirun -n 2` every run is shared by
# the two ranks (≈ 3 min serial at full size on a shared 2-core machine, plus a calibration per extra table).

# %%
from __future__ import annotations

import copy
import csv
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from _demo import (
    FIG6_MM,
    SCENES,
    TABLE_I,
    TABLE_I_RATIO_BAND,
    deltas,
    load_scene_dict,
    parser,
    print0,
    ratio_check,
    report,
)
from mpi4py import MPI

from fenicsfoam.calibrate import Calibration, calibrate_E_solid, read_calibration
from fenicsfoam.scene import run_scene
from fenicsfoam.solver import ConvergenceError
from fenicsfoam.uncertainty import run_with_uncertainty
from foambase.files import atomic_open, atomic_path
from homogenization.tables import resolve_table

BEAMS = ("beam_iso", "beam_ti_y", "beam_ti_z")
TRIPODS = ("tripod_silicone", "tripod_case_a", "tripod_case_b")  # as built (the servos' set-up pre-bends the plate)
SILICONE, FOAM_TRIPODS = TRIPODS[0], TRIPODS[1:]
#: The one calibration: scene, probe, step, the real measurement (m).
CALIBRATION = ("beam_iso", "tip_deflection", "gravity", -0.048)
#: The paper's datasheet modulus of the filament, as the scenes ship it (Pa).
DATASHEET_E = 12e6
#: Targets after calibration: relative error of lengths, error of angle magnitudes (deg).
LENGTH_TARGET, ANGLE_TARGET_DEG = 0.15, 5.0
#: --ci mesh sizes (m).
CI_H = {"beam": 0.0075, "tripod": 0.006}
#: |ours / real − 1| of the calibrated γ = 0.1 beams (the paper's foam; full size, --ci): 13.3–14.0 % and 2.9–8.2 %.
TI_BEAM_BAND = {False: 0.15, True: 0.30}
#: |calibrated / datasheet − 1| of the Tripod's changes from rest (heights, twists at top): measured ≤ 0.6 %.
TRIPOD_E_RTOL = 0.02
POSITIONS = ("middle", "top")
CASES = ("datasheet", "calibrated")


# %% [markdown]
# ## Runs
# A `Prediction` holds, per quantity, our value and σ (mm or deg), or the reason the run stopped.


# %%
@dataclass
class Prediction:
    """Our values (mm, deg) and σ by (quantity, position), or ``stopped`` (the diagnosed reason).

    ``E_solid`` (Pa) and ``table`` (the foam table's label) of its foam regions, ``""`` without foam.
    """

    values: dict = field(default_factory=dict)
    sigma: dict = field(default_factory=dict)
    stopped: str = ""
    instability: bool = False
    E_solid: float = math.nan
    table: str = ""


def foam_regions(data: dict) -> list[dict]:
    """The foam regions of a scene dict."""
    return [r for r in data["regions"].values() if r["material"] == "foam"]


def table_label(region: dict) -> str:
    """The foam table a foam region reads: the shipped name (the default table without a ``table`` key) or the path."""
    return resolve_table(region.get("table"))[0]


def scene(name: str, ci: bool, degree: int, calibrations: dict[str, Path] | None = None) -> dict:
    """A shipped scene as a dict: coarse with ``ci``, no XDMF/pictures, a relative table CSV made absolute.

    With ``calibrations`` (foam table label → calibration file), every foam region takes the E_s of its own table.
    """
    kind = "beam" if name.startswith("beam") else "tripod"
    data = load_scene_dict(name, ci_h=CI_H[kind] if ci else None, png=False)
    data["outputs"] = {"xdmf": False, "png": False}
    data["fem"]["degree"] = degree
    for region in foam_regions(data):
        table = region.get("table")
        if isinstance(table, str) and table.endswith(".csv") and not Path(table).is_absolute():
            region["table"] = str(SCENES / table)  # the dict has no scene file to be relative to
    if calibrations is not None:
        for region in foam_regions(data):
            region["E_solid"] = {"calibration": str(Path(calibrations[table_label(region)]).resolve())}
    return data


def scene_tables(datas: list[dict]) -> list[str]:
    """The distinct foam tables the scenes' foam regions read, in order of appearance."""
    return list(dict.fromkeys(table_label(r) for data in datas for r in foam_regions(data)))


def calibration_dirs(out: Path, tables: list[str]) -> dict[str, Path]:
    """Where the calibration through each table is written: ``out/calibration/<name>`` (a CSV: its stem), unique."""
    dirs: dict[str, Path] = {}
    for table in tables:
        stem = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(table).stem if table.endswith(".csv") else table)
        slug = next(name for name in (stem, *(f"{stem}_{i}" for i in range(1, len(tables) + 1)))
                    if out / "calibration" / name not in dirs.values())
        dirs[table] = out / "calibration" / slug
    return dirs


def calibrate_tables(base: dict, tables: list[str], out: Path, comm: MPI.Comm) -> dict[str, Calibration]:
    """E_s calibrated on the scene ``base`` (``beam_iso``) once per foam table, its foam regions reading that table.

    Each is written to ``<dir>/calibration.json`` (:func:`calibration_dirs`) and returned by table label.
    """
    _, probe, step, target = CALIBRATION
    calibrations = {}
    for table, directory in calibration_dirs(out, tables).items():
        data = copy.deepcopy(base)
        for region in foam_regions(data):
            region["table"] = table
        calibrations[table] = calibrate_E_solid(data, probe, step, target, out_dir=directory, comm=comm)
    return calibrations


def scene_E_solid(data: dict) -> float:
    """The E_s (Pa) of a scene dict's foam regions (a number or a calibration file's); NaN if none or several."""
    moduli = {read_calibration(r["E_solid"]["calibration"]) if isinstance(r["E_solid"], dict) else float(r["E_solid"])
              for r in foam_regions(data)}
    return moduli.pop() if len(moduli) == 1 else math.nan


def predict(name: str, data: dict, out: Path, seeds: bool, comm: MPI.Comm) -> Prediction:
    """Run one scene (with the seed scatter if ``seeds``); a stop is recorded with its diagnosis."""
    p = Prediction(table=", ".join(scene_tables([data])), E_solid=scene_E_solid(data))
    try:
        if seeds:
            u = run_with_uncertainty(data, out, comm=comm)
            result, std = u.nominal, u.probe_std
        else:
            result, std = run_scene(data, out, comm=comm), None
    except ConvergenceError as exc:
        lost = exc.ellipticity is not None and exc.ellipticity.lost
        p.stopped = (f"stops at {100 * exc.load_factor:.0f} % of step {exc.step!r}: "
                     + (f"strong ellipticity lost in {exc.ellipticity.lost_cells} cells (material instability)"
                        if lost else exc.reason))
        p.instability = lost
        return p
    if name.startswith("beam"):
        p.values[("tip deflection (mm)", "-")] = 1e3 * result.probe("tip_deflection")["gravity"]
        p.sigma[("tip deflection (mm)", "-")] = 1e3 * std("tip_deflection")["gravity"] if std else math.nan
        return p
    for quantity, probe, scale in (("Δheight (mm)", "center_height", 1e3), ("Δangle (deg)", "center_rotation", 1.0)):
        change = result.probe(probe, relative_to="rest")
        sigma = std(probe, relative_to="rest") if std else None
        for position in POSITIONS:
            p.values[(quantity, position)] = scale * change[position]
            p.sigma[(quantity, position)] = scale * sigma[position] if sigma else math.nan
    return p


def run_experiments(out: Path, ci: bool, degree: int, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Calibrate E_s on beam_iso per foam table, then run every scene with both moduli (each foam region with its
    table's calibration); returns everything the table needs."""
    tables = scene_tables([scene(name, ci, degree) for name in BEAMS + TRIPODS])
    calibrations = calibrate_tables(scene(CALIBRATION[0], ci, degree), tables, out, comm)
    files = {table: directory / "calibration.json" for table, directory in calibration_dirs(out, tables).items()}
    predictions = {}
    for case in CASES:
        for name in BEAMS + TRIPODS:
            if case == "calibrated" and name == SILICONE:
                predictions[(case, name)] = predictions[("datasheet", name)]  # no foam: E_s does not enter
                continue
            data = scene(name, ci, degree, files if case == "calibrated" else None)
            seeds = not ci or (name.startswith("beam") and case == "calibrated")
            predictions[(case, name)] = predict(name, data, out / case / name, seeds, comm)
    return {"calibrations": calibrations, "predictions": predictions, "ci": ci, "degree": degree}


# %% [markdown]
# ## The table: ours ± σ / paper sim / real, our error and the paper's


# %%
def references(name: str) -> dict:
    """(quantity, position) → (paper sim, real) of an experiment (mm, deg); the silicone plate has none."""
    if name in FIG6_MM:
        real, sim = FIG6_MM[name]
        return {("tip deflection (mm)", "-"): (sim, real)}
    if name not in TABLE_I:
        return {}
    out = {}
    for quantity, key in (("Δheight (mm)", "height"), ("Δangle (deg)", "angle")):
        sim, real = (deltas(v) for v in TABLE_I[name][key])
        for k, position in enumerate(POSITIONS):
            out[(quantity, position)] = (sim[k], real[k])
    return out


def error(quantity: str, value: float, real: float) -> float:
    """Lengths: ours / real − 1 (%); angles: |ours| − |real| (deg)."""
    if "deg" in quantity:
        return abs(value) - abs(real)
    return 100.0 * (value / real - 1.0)


def target(name: str, quantity: str) -> tuple[str, float] | None:
    """The target of a quantity (the module docstring's), as (description, bound of |error|), or None."""
    if name in ("beam_ti_y", "beam_ti_z"):
        return "within 15 %", 100 * LENGTH_TARGET
    if name in FOAM_TRIPODS:
        return ("within 5°", ANGLE_TARGET_DEG) if "deg" in quantity else ("within 15 %", 100 * LENGTH_TARGET)
    return None


def rows(results: dict) -> list[dict]:
    """One row per modulus, experiment, quantity and position."""
    out = []
    for case in CASES:
        for name in BEAMS + TRIPODS:
            p = results["predictions"][(case, name)]
            refs = references(name)
            keys = list(refs) if refs else list(p.values) or [("Δheight (mm)", pos) for pos in POSITIONS]
            for quantity, position in keys:
                sim, real = refs.get((quantity, position), (math.nan, math.nan))
                ours = p.values.get((quantity, position), math.nan)
                goal = target(name, quantity)
                err = error(quantity, ours, real) if refs and not p.stopped else math.nan
                out.append({
                    "E_solid": case, "E_solid_Pa": p.E_solid, "foam_table": p.table, "experiment": name,
                    "quantity": quantity,
                    "position": position, "ours": ours, "sigma": p.sigma.get((quantity, position), math.nan),
                    "paper_sim": sim, "real": real, "error_ours": err,
                    "error_paper": error(quantity, sim, real) if refs else math.nan,
                    "target": goal[0] if goal else ("calibrated on" if name == CALIBRATION[0] and case ==
                                                    "calibrated" else ""),
                    "met": "" if goal is None else ("yes" if abs(err) <= goal[1] else "no"),
                    "stopped": p.stopped})
    return out


def fmt(value: float, digits: int = 2) -> str:
    return "–" if not math.isfinite(value) else f"{value:.{digits}f}"


def short(table: str) -> str:
    """A foam table's label as printed: the shipped name, or a CSV's file name."""
    return Path(table).name if table.endswith(".csv") else table


def calibration_lines(results: dict) -> list[str]:
    """One line per calibration: its table, E_s and how it compares with the datasheet."""
    return [f"E_s calibrated on {cal.scene} ({cal.probe} = {1e3 * cal.target:g} mm) through foam table "
            f"{short(table)!r}: {cal.E_solid / 1e6:.4g} MPa ({cal.E_solid / DATASHEET_E:.3g} × the datasheet, "
            f"{cal.runs} runs)" for table, cal in results["calibrations"].items()]


def table(results: dict) -> str:
    """The printed table (errors: % for lengths, degrees for angles); each row's E_s (MPa) and foam table."""
    lines = [f"E_s: datasheet {DATASHEET_E / 1e6:g} MPa", *calibration_lines(results),
             f"{'E_s':10s} {'MPa':>5s} {'table':9s} {'experiment':15s} {'quantity':19s} {'pos':6s} {'ours':>8s} "
             f"{'± σ':>6s} {'paper':>7s} {'real':>7s} {'err ours':>9s} {'err paper':>9s}  target"]
    for r in rows(results):
        unit = "°" if "deg" in r["quantity"] else "%"
        head = (f"{r['E_solid']:10s} {fmt(r['E_solid_Pa'] / 1e6, 1):>5s} {short(r['foam_table']) or '–':9s} "
                f"{r['experiment']:15s} {r['quantity']:19s} {r['position']:6s} ")
        if r["stopped"]:
            lines.append(f"{head}{r['stopped']}  (paper {fmt(r['paper_sim'], 1)}, real {fmt(r['real'], 1)})")
            continue
        err_ours = "–" if not math.isfinite(r["error_ours"]) else f"{r['error_ours']:+.1f}{unit}"
        err_paper = "–" if not math.isfinite(r["error_paper"]) else f"{r['error_paper']:+.1f}{unit}"
        verdict = r["target"] + ("" if not r["met"] else (": met" if r["met"] == "yes" else ": MISSED"))
        lines.append(f"{head}{fmt(r['ours']):>8s} {fmt(r['sigma']):>6s} {fmt(r['paper_sim']):>7s} "
                     f"{fmt(r['real']):>7s} {err_ours:>9s} {err_paper:>9s}  {verdict}")
    return "\n".join(lines)


def misses(results: dict) -> list[str]:
    """The targets missed after calibration (the reasons are measured in the docs' validation pages)."""
    out = []
    for r in rows(results):
        if r["E_solid"] != "calibrated" or r["met"] != "no":
            continue
        unit = "°" if "deg" in r["quantity"] else " %"
        what = r["stopped"] or (f"ours {fmt(r['ours'])} vs real {fmt(r['real'])}, error {r['error_ours']:+.1f}{unit}"
                                f" (the paper's simulation: {r['error_paper']:+.1f}{unit})")
        out.append(f"{r['experiment']} {r['quantity']} {r['position']}: {what}; target {r['target']}")
    return out


# %% [markdown]
# ## Outputs: CSV and the parity plot


# %%
def write_csv(results: dict, path: Path) -> None:
    table_rows = rows(results)
    with atomic_open(path) as f:
        writer = csv.DictWriter(f, fieldnames=list(table_rows[0]))
        writer.writeheader()
        writer.writerows(table_rows)


def parity_plot(results: dict, path: Path) -> None:
    """Predicted against measured magnitudes (lengths | angles), error bars ±σ, the targets' bands shaded."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    table_rows = [r for r in rows(results) if math.isfinite(r["real"])]
    calibrations = results["calibrations"]
    styles = {("datasheet", ""): dict(marker="o", mfc="none", color="C0", label="ours, datasheet E_s"),
              **{("calibrated", t): dict(marker="osD^v"[k % 5], color=f"C{3 + k}",
                                         label=f"ours, E_s = {cal.E_solid / 1e6:.3g} MPa calibrated on beam_iso "
                                               f"through {short(t)!r}")
                 for k, (t, cal) in enumerate(calibrations.items())},
              "paper": dict(marker="x", color="0.4", ls="none", label="paper's simulation")}
    for ax, angles in zip(axes, (False, True)):
        sel = [r for r in table_rows if ("deg" in r["quantity"]) == angles]
        top = max(max(abs(r["real"]) for r in sel), max(abs(r["paper_sim"]) for r in sel),
                  max((abs(r["ours"]) for r in sel if math.isfinite(r["ours"])), default=0.0)) * 1.15
        low = 0.0 if angles else 0.7 * min(abs(r["real"]) for r in sel)
        x = [low, top]
        if angles:
            ax.fill_between(x, [v - ANGLE_TARGET_DEG for v in x], [v + ANGLE_TARGET_DEG for v in x], color="0.92",
                            label=f"±{ANGLE_TARGET_DEG:g}° (target)")
        else:
            ax.fill_between(x, [v * (1 - LENGTH_TARGET) for v in x], [v * (1 + LENGTH_TARGET) for v in x],
                            color="0.92", label=f"±{100 * LENGTH_TARGET:g} % (target)")
        ax.plot(x, x, color="0.5", lw=0.8)
        for case, foam_table in [key for key in styles if key != "paper"]:
            pts = [r for r in sel if r["E_solid"] == case and math.isfinite(r["ours"])
                   and (case == "datasheet" or r["foam_table"] == foam_table)]
            if not pts:
                continue
            ax.errorbar([abs(r["real"]) for r in pts], [abs(r["ours"]) for r in pts],
                        yerr=[r["sigma"] if math.isfinite(r["sigma"]) else 0.0 for r in pts], ls="none",
                        capsize=3, **styles[(case, foam_table)])
            for r in pts:
                label = r["experiment"].replace("tripod_case_", "").replace("beam_", "") + (
                    "" if r["position"] == "-" else f" {r['position'][0]}")
                ax.annotate(label, (abs(r["real"]), abs(r["ours"])), fontsize=6, xytext=(3, 2),
                            textcoords="offset points")
        paper = [r for r in sel if r["E_solid"] == "datasheet"]
        ax.plot([abs(r["real"]) for r in paper], [abs(r["paper_sim"]) for r in paper], **styles["paper"])
        if not angles:  # lengths span 10–125 mm: logarithmic axes keep the cluster near the real values legible
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.set_xlim(low, top)
        ax.set_ylim(low, top)
        ax.set_aspect("equal")
        ax.set_xlabel("measured, real robot (|deg|)" if angles else "measured, real robot (|mm|)")
        ax.set_ylabel("predicted (|deg|)" if angles else "predicted (|mm|)")
        ax.set_title("Tripod Δangle from rest (a: case A, b: case B; m/t: middle/top)" if angles else
                     "Fig. 6 tip sag (iso, ti_y, ti_z) and Tripod Δheight from rest (log scales)", fontsize=9)
        ax.legend(fontsize=7, loc="upper left" if angles else "lower right")
    through = ", ".join(f"{cal.E_solid / 1e6:.3g} MPa through {short(t)!r}" for t, cal in calibrations.items())
    fig.suptitle(f"Predicted vs measured: datasheet E_s = {DATASHEET_E / 1e6:g} MPa and E_s calibrated on beam_iso "
                 f"(−48 mm) per foam table ({through});\nerror bars ±σ over foam seeds", fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


# %% [markdown]
# ## Checks


# %%
def check(results: dict) -> list[str]:
    """Failed checks, as messages (empty if all pass); the stated bands of the module docstring."""
    failures = []
    _, _, _, goal = CALIBRATION
    calibrations = results["calibrations"]
    for foam_table, cal in calibrations.items():
        if not abs(cal.achieved - goal) <= 1e-6 * abs(goal):
            failures.append(f"calibration through {foam_table!r} reached {cal.achieved!r} m instead of {goal!r} m")
    predictions = results["predictions"]
    for (case, name), p in predictions.items():
        if case == "calibrated" and p.table in calibrations and p.E_solid != calibrations[p.table].E_solid:
            failures.append(f"{name} reads foam table {p.table!r} but ran with E_s = {p.E_solid!r} Pa, not that "
                            f"table's calibrated {calibrations[p.table].E_solid!r} Pa")
    iso = predictions[("calibrated", "beam_iso")].values.get(("tip deflection (mm)", "-"), math.nan)
    if not abs(iso - 1e3 * goal) <= 1e-6 * abs(1e3 * goal):
        failures.append(f"beam_iso with the calibration file sags {iso!r} mm, not the calibrated {1e3 * goal} mm")
    for (case, name), p in predictions.items():
        if p.stopped and not p.instability:
            failures.append(f"{name} ({case}): {p.stopped}, without a diagnosed material instability")
        if p.stopped and name in ("beam_iso", *TRIPODS):
            failures.append(f"{name} ({case}) must run through: {p.stopped}")
    for name in ("beam_ti_y", "beam_ti_z"):
        real = FIG6_MM[name][0]
        tip = {case: predictions[(case, name)].values.get(("tip deflection (mm)", "-"), math.nan) for case in CASES}
        band = TI_BEAM_BAND[results["ci"]]
        if not abs(tip["calibrated"] / real - 1) <= band:
            failures.append(f"{name}: calibrated tip {tip['calibrated']:.4g} mm is not within {100 * band:g} % of the "
                            f"real {real} mm")
        if math.isfinite(tip["datasheet"]) and not abs(tip["calibrated"] - real) < abs(tip["datasheet"] - real):
            failures.append(f"{name}: the calibration does not bring the tip closer to the real {real} mm "
                            f"({tip['datasheet']:.4g} → {tip['calibrated']:.4g} mm)")
    for name in FOAM_TRIPODS:
        a, b = (predictions[(case, name)].values for case in CASES)
        for key in (("Δheight (mm)", "middle"), ("Δheight (mm)", "top"), ("Δangle (deg)", "top")):
            if not abs(b[key] / a[key] - 1) < TRIPOD_E_RTOL:
                failures.append(f"{name} {key}: {a[key]:.4g} with the datasheet E_s, {b[key]:.4g} calibrated: "
                                f"more than {100 * TRIPOD_E_RTOL:g} % apart")
    for case in CASES:
        tips = {n: predictions[(case, n)].values.get(("tip deflection (mm)", "-")) for n in BEAMS}
        for name in ("beam_ti_y", "beam_ti_z"):
            if tips[name] is not None and tips["beam_iso"] is not None and not tips[name] > tips["beam_iso"]:
                failures.append(f"{name} ({case}) sags more than beam_iso: {tips[name]:.4g} vs "
                                f"{tips['beam_iso']:.4g} mm")
        twist_b = abs(predictions[(case, "tripod_case_b")].values.get(("Δangle (deg)", "top"), math.nan))
        silicone = predictions[(case, SILICONE)].values
        if not abs(silicone.get(("Δangle (deg)", "top"), math.nan)) < 1e-9 * twist_b:
            failures.append(f"{SILICONE} twists ({case}): {silicone.get(('Δangle (deg)', 'top'))}°")
        for name in FOAM_TRIPODS:
            v = predictions[(case, name)].values
            if not abs(v.get(("Δangle (deg)", "top"), math.nan)) > 1.0:
                failures.append(f"{name} ({case}): twist at top {v.get(('Δangle (deg)', 'top'))}°, expected > 1°")
            for position in ("middle",):  # the top rise is an open discrepancy (module docstring)
                real = references(name)[("Δheight (mm)", position)][1]
                failures += ratio_check(f"{name} ({case})", v.get(("Δheight (mm)", position), math.nan), real,
                                        TABLE_I_RATIO_BAND, f"rise of the centre at {position} (mm) vs the real robot")
    return failures


# %%
def main(argv: list[str] | None = None) -> int:
    p = parser("The paper's experiments predicted with the datasheet and the calibrated E_s, with error bars.",
               "out/experiments", "coarse meshes, seed scatter for the calibrated beams only: a fast run")
    p.add_argument("--degree", type=int, default=1, choices=(1, 2),
                   help="finite-element degree of every run (1: the paper's P1; 2: closer to mesh convergence)")
    args = p.parse_args(argv)
    comm = MPI.COMM_WORLD
    results = run_experiments(args.out, args.ci, args.degree, comm)
    print0(table(results))
    if comm.rank == 0:
        write_csv(results, args.out / "experiments.csv")
        parity_plot(results, args.out / "parity.png")
    missed = misses(results)
    print0("targets after calibration: " + ("all met" if not missed else f"{len(missed)} missed"))
    for line in missed:
        print0(f"  MISSED {line}")
    print0(f"outputs: {args.out}/experiments.csv, parity.png, calibration/<table>/calibration.json, "
           "<E_s>/<scene>/summary.json")
    return report(check(results), comm)


if __name__ == "__main__":
    sys.exit(main())
