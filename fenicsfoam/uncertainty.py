"""Prediction uncertainty from the foam table's seed scatter: every probe as value ± standard deviation.

The foam table holds, at every (relative density, γ), the homogenized constants of several foam samples that
differ only by their random seed (``homogenization/data/foam_table_samples.csv``); the shipped table is their
mean. :func:`run_with_uncertainty` runs a scene with the mean table (the nominal prediction, as ``run_scene``)
and once more per seed with the table of that seed alone, and reports per step the sample standard deviation
(ddof = 1) of every probe over the seeds as ``probes_std`` beside ``probes``.

Method: per-seed tables, chosen over the alternatives because
- one seed's constants come from one foam sample, so their correlations (a sample stiffer in one direction is
  usually stiffer in shear too) are kept; ±σ runs per constant, or a linearised sensitivity with the table's
  per-constant ``_std`` columns, would treat the constants as independent;
- it needs no linearisation: the Tripod is strongly nonlinear (large rotations, close to material instabilities),
  and a finite-difference sensitivity would cost one run per constant and region (7 for case A) against one run
  per seed (3) here;
- it is exact for what it claims: zero scatter in the samples gives zero ``probes_std`` (every per-seed table is
  then the mean table).

What the number means: the scatter of the prediction over foam realisations of the size of the table's RVE
(8 Voronoi cells), which overstates the scatter of a printed part made of many more cells, and with 3 seeds the
standard deviation itself is uncertain by about ±50 % (a χ² estimate with 2 degrees of freedom). Between table
nodes a per-seed table is interpolated as the mean table is (``foam_material``). A seed whose run does not
converge is recorded with its error (and logged) and the steps it completed; a step's standard deviation is over
the seeds that reached it, NaN with fewer than two. Every per-seed scene is made and checked
(:func:`fenicsfoam.scene.vary_scene`, every foam region's ``table`` replaced) before the nominal run, so a scene
that cannot take the per-seed tables (e.g. graded foam fields, which read the default table only) is refused
(:class:`UncertaintyError`) before any work. A vector probe (``"KIND:GROUP"``, e.g. a reaction force) gets
the standard deviation of each of its components, a list of 3 like its value.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fenicsfoam.material import tabulated_regions
from foambase.errors import InputError
from foambase.files import write_json_atomic, write_text_atomic

__all__ = ["METHOD", "UncertaintyError", "UncertaintyResult", "run_with_uncertainty", "seed_tables"]

Value = float | list[float]

logger = logging.getLogger(__name__)



class UncertaintyError(InputError):
    """A request for the prediction uncertainty that cannot be met, found before any run (samples, scene)."""


METHOD = ("per-seed tables: the scene run once per seed of the foam table's samples, probes_std = sample "
          "standard deviation (ddof = 1) over the seeds")


def seed_tables(samples_csv: str | os.PathLike, out_dir: str | os.PathLike) -> dict[int, Path]:
    """Write one aggregated foam table per seed of a samples CSV (``out_dir/foam_table_seed<k>.csv``).

    Each table has the mean table's format (:func:`homogenization.tables.aggregate` of that seed's rows alone),
    so ``foam_material(..., table=path)`` reads it. Every seed must cover every (density, γ) of the samples.
    """
    from homogenization.tables import AGGREGATED, aggregate, to_csv

    try:
        with open(samples_csv, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            rows = list(reader)
    except (UnicodeDecodeError, csv.Error) as exc:
        raise UncertaintyError(f"{samples_csv}: not a CSV file of foam samples ({exc})") from exc
    if not header:
        raise UncertaintyError(f"{samples_csv}: empty file, no header; expected the columns of a foam samples CSV "
                               f"(density, gamma, seed, {', '.join(AGGREGATED)})")
    missing = [c for c in ("density", "gamma", "seed", *AGGREGATED) if c not in header]
    if missing:
        raise UncertaintyError(f"{samples_csv}: no column {missing[0]!r}"
                               + (f" (nor {', '.join(map(repr, missing[1:4]))}…)" if len(missing) > 1 else "")
                               + "; a foam samples CSV (homogenization.tables, one row per seed) has density, gamma, "
                               "seed and the homogenized constants")
    if not rows:
        raise UncertaintyError(f"{samples_csv}: no samples")
    for i, r in enumerate(rows, start=2):
        for c in ("density", "gamma", "seed", *AGGREGATED):
            try:
                if not math.isfinite(float(r[c])):
                    raise ValueError
            except (TypeError, ValueError):
                raise UncertaintyError(f"{samples_csv}: line {i}, column {c!r}: {r[c]!r:.40} is not a finite "
                                       "number") from None
    nodes = {(float(r["density"]), float(r["gamma"])) for r in rows}
    by_seed: dict[int, list[dict]] = {}
    for r in rows:
        by_seed.setdefault(int(float(r["seed"])), []).append(r)
    paths = {}
    for seed, members in sorted(by_seed.items()):
        missing = nodes - {(float(r["density"]), float(r["gamma"])) for r in members}
        if missing:
            raise UncertaintyError(f"{samples_csv}: seed {seed} has no sample at (density, gamma) = "
                                   f"{sorted(missing)[0]}; every seed must cover every table node")
        paths[seed] = to_csv(aggregate(members), Path(out_dir) / f"foam_table_seed{seed}.csv")
    return paths


def _flatten(probes: dict[str, Value], names) -> list[float]:
    """The probes' values as one row of numbers (a vector probe as its components)."""
    row: list[float] = []
    for name in names:
        value = probes[name]
        row += [float(v) for v in value] if isinstance(value, list | tuple) else [float(value)]
    return row


def _unflatten(row, names, sizes: dict[str, int]) -> dict[str, Value]:
    """The inverse of :func:`_flatten`: ``{name: float}``, or a list for a vector probe."""
    out: dict[str, Value] = {}
    i = 0
    for name in names:
        n = sizes[name]
        out[name] = float(row[i]) if n == 1 else [float(v) for v in row[i:i + n]]
        i += n
    return out


def _minus(a: Value, b: Value) -> Value:
    return [x - y for x, y in zip(a, b)] if isinstance(a, list | tuple) else a - b


def _sizes(names) -> dict[str, int]:
    from fenicsfoam.scene.kinds import probe_size
    return {name: probe_size(name) for name in names}


def _default_samples(scene) -> Path:
    """The samples CSV of the one shipped table every foam region of ``scene`` uses."""
    from homogenization.tables import DEFAULT_TABLE, table_paths

    names = {r.parameters.get("table", DEFAULT_TABLE) for r in tabulated_regions(scene.regions)}
    if len(names) != 1 or next(iter(names)).endswith(".csv"):
        raise UncertaintyError(f"the scene's foam regions use the tables {sorted(names)}: pass the samples CSV their "
                         "mean table was aggregated from (samples_csv, --samples)")
    return table_paths(names.pop())["samples"]


@dataclass
class UncertaintyResult:
    """The nominal :class:`~fenicsfoam.scene.SceneResult` and the per-step standard deviation of its probes."""

    nominal: Any                                           #: SceneResult of the mean table
    #: per step of ``nominal.steps``: σ of each probe (a list of 3 for a vector probe)
    probes_std: list[dict[str, Value]] = field(default_factory=list)
    samples: list[dict[str, Any]] = field(default_factory=list)  #: per seed: probes per step done, error if any
    method: str = METHOD

    def summary(self) -> dict[str, Any]:
        """``summary.json``: the nominal summary, ``probes_std`` in every step, and an ``uncertainty`` record."""
        out = self.nominal.summary()
        for step, std in zip(out["steps"], self.probes_std):
            step["probes_std"] = std
        out["uncertainty"] = {"method": self.method, "samples": self.samples}
        return out

    def probe_std(self, name: str, relative_to: str | None = None) -> dict[str, Value]:
        """``{step label: σ}`` of a probe over the seeds, of its change from step ``relative_to`` if given.

        The change's σ is that of the per-seed changes (the values at two steps of one seed are correlated, so it
        is not a combination of the two steps' ``probes_std``). A vector probe's σ is per component (a list).
        """
        if relative_to is None:
            return {s.label: std[name] for s, std in zip(self.nominal.steps, self.probes_std)}
        size = _sizes([name])[name]
        per_seed = [{label: _minus(p[name], s["steps"][relative_to][name]) for label, p in s["steps"].items()}
                    for s in self.samples if relative_to in s["steps"]]
        out = {}
        for step in self.nominal.steps:
            values = np.array([v[step.label] for v in per_seed if step.label in v], dtype=float).reshape(-1, size)
            std = values.std(axis=0, ddof=1) if len(values) > 1 else np.full(
                size, 0.0 if self.method != METHOD else math.nan)
            out[step.label] = float(std[0]) if size == 1 else [float(v) for v in std]
        return out

    def table(self) -> str:
        """Probes per step as value ± standard deviation (mm, degrees, N, cm³; vectors per component)."""
        from fenicsfoam.scene.kinds import probe_unit
        scale = {"m": (1e3, "mm"), "deg": (1.0, "deg"), "N": (1.0, "N"), "m3": (1e6, "cm3")}
        lines = [f"scene {self.nominal.scene.name}: probes ± standard deviation over {len(self.samples)} foam seeds"]
        for step, std in zip(self.nominal.steps, self.probes_std):
            values = []
            for name, v in step.probes.items():
                k, unit = scale[probe_unit(name)]
                if isinstance(v, list | tuple):
                    values.append(f"{name} = (" + ", ".join(f"{a * k:.4g} ± {b * k:.2g}" for a, b in zip(v, std[name]))
                                  + f") {unit}")
                else:
                    values.append(f"{name} = {v * k:.4g} ± {std[name] * k:.2g} {unit}")
            lines.append(f"{step.label:>10s}: " + ", ".join(values))
        return "\n".join(lines)


def run_with_uncertainty(source, out_dir: str | os.PathLike | None = None, *,
                         samples_csv: str | os.PathLike | None = None, comm=None, **options) -> UncertaintyResult:
    """Run a scene with the mean foam table and once per seed; ``probes_std`` per step (see the module docstring).

    Parameters
    ----------
    source
        A scene file, a dict as ``tomllib`` reads one, or a parsed :class:`~fenicsfoam.scene.Scene`.
    out_dir
        Outputs of the nominal run (as :func:`~fenicsfoam.scene.run_scene`); ``summary.json`` then also holds
        ``probes_std`` per step and the per-seed values (written atomically on rank 0). ``None`` writes nothing.
    samples_csv
        Per-seed samples (default: the samples of the shipped table the scene's foam regions name, ``table``,
        by default ``foam_table_samples.csv``). The nominal run always uses the scene's table, so pass the
        samples that table was aggregated from.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).
    options
        For the nominal run (:func:`~fenicsfoam.scene.run_scene`'s ``solver``, ``force``, ``echo``).

    Raises
    ------
    SceneError
        Invalid scene; ``ConvergenceError`` if the nominal run fails (a seed's failure is recorded instead).
    UncertaintyError
        Before any run: samples that give no per-seed tables, a scene whose foam regions cannot read them (graded
        fields; a table node outside a seed's table), foam regions of several tables without ``samples_csv``.

    """
    from mpi4py import MPI

    from fenicsfoam.scene import Scene, load_scene, run_scene
    from fenicsfoam.solver import ConvergenceError

    comm = MPI.COMM_WORLD if comm is None else comm
    scene = source if isinstance(source, Scene) else load_scene(source)
    sizes = _sizes(scene.probes)
    width = sum(sizes.values())
    foams = bool(tabulated_regions(scene.regions))
    tmp = comm.bcast(tempfile.mkdtemp(prefix="fenicsfoam-seeds-") if comm.rank == 0 and foams else None, root=0)
    try:
        seeds = _seed_scenes(scene, samples_csv, tmp, comm) if foams else {}  # every variation, before any work
        nominal = run_scene(scene, out_dir, comm=comm, **options)
        labels = [s.label for s in nominal.steps]
        result = UncertaintyResult(nominal)
        if not foams:
            result.method = "no foam region: no table scatter to propagate"
            result.probes_std = [_unflatten(np.zeros(width), scene.probes, sizes) for _ in nominal.steps]
        values: dict[str, list[list[float]]] = {label: [] for label in labels}
        for seed, seed_scene in seeds.items():
            seed_out = Path(tmp) / f"seed{seed}"
            sample: dict[str, Any] = {"seed": seed}
            try:
                run = run_scene(seed_scene, seed_out, comm=comm)
                sample["steps"] = {s.label: s.probes for s in run.steps}
            except ConvergenceError as exc:  # the steps done before the failure still count
                logger.warning("scene %s with foam seed %d did not converge: %s", scene.name, seed, exc)
                done = (json.loads((seed_out / "summary.json").read_text())["steps"] if comm.rank == 0
                        else None)
                sample["steps"] = {s["label"]: s["probes"] for s in comm.bcast(done, root=0)}
                sample["error"] = str(exc)
            result.samples.append(sample)
            for label, probes in sample["steps"].items():
                if label in values:
                    values[label].append(_flatten(probes, scene.probes))
    finally:
        comm.Barrier()
        if comm.rank == 0 and tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    if foams:
        for label in labels:
            rows = np.array(values[label], dtype=float).reshape(-1, width)
            std = rows.std(axis=0, ddof=1) if len(rows) > 1 else np.full(width, math.nan)
            result.probes_std.append(_unflatten(std, scene.probes, sizes))
    if out_dir is not None and comm.rank == 0:
        from fenicsfoam.scene.outputs import probes_csv
        write_text_atomic(Path(out_dir) / "probes.csv", probes_csv(nominal, result.probes_std))
        write_json_atomic(Path(out_dir) / "summary.json", result.summary())
    comm.Barrier()
    return result


def _seed_scenes(scene, samples_csv, tmp: str, comm) -> dict[int, Any]:
    """The scene once per seed of the samples: every foam region reads that seed's table (in ``tmp``), no outputs.

    Every variation is checked (:func:`fenicsfoam.scene.vary_scene`) before any run: :class:`UncertaintyError`
    for samples that cannot give per-seed tables or a scene whose foam regions cannot take them.
    """
    from fenicsfoam.scene import SceneError, vary_scene

    if scene.graded:
        raise UncertaintyError(f"scene {scene.name!r}: graded foam fields ([[blends]], or a density or gamma per tag "
                               "or by a function) read the default foam table only, so the per-seed tables of "
                               "--uncertainty cannot replace it; run it without --uncertainty, or give the foam "
                               "regions numbers")
    tables = None
    if comm.rank == 0:
        try:
            tables = seed_tables(_default_samples(scene) if samples_csv is None else samples_csv, tmp)
        except (OSError, ValueError) as exc:  # raised on every rank below
            tables = exc
    tables = comm.bcast(tables, root=0)
    if isinstance(tables, OSError):
        raise UncertaintyError(f"the per-seed tables cannot be made: {tables}") from tables
    if isinstance(tables, Exception):
        raise tables
    quiet = {**scene.raw, "outputs": {"xdmf": False, "png": False}}
    seeds = {}
    for seed, table in tables.items():
        try:
            varied = vary_scene(scene, {"table": str(table)})
        except SceneError as exc:
            raise UncertaintyError(f"the foam table of seed {seed} does not fit scene {scene.name!r}: {exc}") from exc
        seeds[seed] = dataclasses.replace(varied, raw={**quiet, "regions": varied.raw["regions"]}, xdmf=False, png=())
    return seeds
