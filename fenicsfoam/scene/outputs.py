"""What a scene run produces: per-step results, ``summary.json``, ``probes.csv``, the XDMF series and the pictures.

Every file is written atomically (:mod:`foambase.files`; the XDMF series in a temporary directory moved into place
at the end), the text files and pictures by rank 0 only, so an interrupted run never leaves a half-written file.

Run folders (:class:`RunFolder`): an output directory holds one run
-------------------------------------------------------------------
* Before any work, the directory is checked: it may be new, empty, or a previous run's folder (one with a
  ``summary.json`` written by a run); a directory that holds anything else is refused (:class:`InputError`), so a
  run never mixes its files with, or removes, files it did not write.
* When the run starts (after the scene is built), the previous run's files are removed — the files its
  ``summary.json`` lists, the fixed outputs (:data:`FIXED_OUTPUTS`), the pictures of its steps, and temporary
  files that a killed run left (:data:`foambase.files.TEMPORARY`, ``.solution.*``) — and ``summary.json`` is
  written at once with ``"status": "incomplete"``. Files the run did not write (e.g. notes) are left alone.
* ``summary.json`` is rewritten after every step (the steps done, the files written so far) and at the end with
  ``"status"``: ``"complete"``; ``"failed"`` with ``error`` (a step did not converge, a solver option was not used);
  ``"interrupted"`` with ``error`` naming the signal and the step (SIGINT, SIGTERM). A run killed outright keeps
  ``"incomplete"``: a folder always says whether it holds a whole run.
* One run per folder: from the start of the run to its end the folder is locked (``flock`` on the directory, by
  rank 0). A second run into it is refused before any work if the lock is held when it starts, or when it would
  start writing (:class:`InputError`, exit status 2) — or waits for the lock with ``wait=True`` (the command
  line's ``--wait``). So a run's start-up clean-up never meets another live run's files: the temporary files it
  removes were left by a run that was killed.
* A file that cannot be written (disk full, file-size limit, quota) ends the run with ``"status": "failed"`` and
  an error naming the file and the system's error (:class:`~foambase.errors.WriteError`); the file is absent or
  its previous version, never half-written.
* Names are safe by construction: the only names that come from the scene are step labels, which the scene's
  validation restricts to a safe character set (``fenicsfoam.scene.schema.LABEL_PATTERN``), and
  :func:`output_path` refuses any name that is not a plain file name inside the folder.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import fcntl
import io
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fenicsfoam.io import PVD_FILE, write_pvd, write_vtu
from fenicsfoam.scene.kinds import probe_size, probe_unit
from fenicsfoam.scene.schema import LABEL_PATTERN, Scene
from foambase.errors import InputError, WriteError
from foambase.files import TEMPORARY, check_output_dir, keep_unclosable, write_json_atomic, write_text_atomic
from foambase.mpi import on_rank0
from foambase.signals import discard_temporary, register_temporary

__all__ = ["FIXED_OUTPUTS", "LOG_FILE", "MARGIN_DIRECTIONS", "MARGIN_MAX_CELLS", "STATUSES", "FieldSeries",
           "Progress", "RunFolder", "SceneResult", "StepResult", "XdmfSeries", "output_path", "picture_orientation",
           "picture_step", "probes_csv", "series_file", "write_summary"]

logger = logging.getLogger(__name__)

#: The run's log: the size estimate and the progress of every step (appended line by line while the run goes).
LOG_FILE = "run.log"
#: The files every run may write besides its step pictures (``<label>.png``).
FIXED_OUTPUTS = ("summary.json", "probes.csv", LOG_FILE, PVD_FILE, "solution.xdmf", "solution.h5", "solution.npz",
                 "orientation.png")
#: The ellipticity margin in the ``.vtu`` files: sampled normals and refinements (see :class:`FieldSeries`).
MARGIN_DIRECTIONS, MARGIN_REFINEMENTS = 64, 6
#: Above this many cells the ``.vtu`` files carry no ellipticity margin (its cost grows past the solve's).
MARGIN_MAX_CELLS = 200_000
#: ``summary.json``'s ``status``: how the run that wrote the folder ended (see the module docstring).
STATUSES = ("incomplete", "complete", "failed", "interrupted")
_XDMF_TEMPORARY = ".solution."


@dataclass
class StepResult:
    """One load step: probe values (SI, angles in degrees; vectors as lists of 3) and solver statistics."""

    label: str
    probes: dict[str, float | list[float]]
    newton_iterations: int
    increments: int
    cutbacks: int
    min_det_F: float
    wall_s: float
    cpu_s: float = 0.0      #: CPU time of rank 0's process during the step (wall_s also counts waiting)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the ``steps`` entries of ``summary.json``)."""
        return dict(self.__dict__)


@dataclass
class SceneResult:
    """The outcome of :func:`~fenicsfoam.scene.run_scene`: ``summary()`` is ``summary.json``, ``table()`` is text."""

    scene: Scene
    steps: list[StepResult] = field(default_factory=list)
    n_cells: int = 0
    n_dofs: int = 0
    n_ranks: int = 1
    wall_s: float = 0.0
    materials: dict[str, dict] = field(default_factory=dict)
    error: str | None = None
    #: when a step failed: its label, the load factor reached and the strong-ellipticity check there
    failure: dict[str, Any] | None = None
    out_dir: Path | None = None
    #: how the run ended (:data:`STATUSES`)
    status: str = "incomplete"
    #: the files written into ``out_dir`` (names)
    files: list[str] = field(default_factory=list)
    #: the size and the memory and time estimate made before assembly (:class:`fenicsfoam.sizing.SizeEstimate`)
    estimate: dict[str, Any] | None = None
    #: the displacement (a ``dolfinx.fem.Function``) at the end of the last step done; its ``function_space.mesh``
    #: is the mesh (not pickled with the result)
    displacement: Any = field(default=None, repr=False, compare=False)

    def probe(self, name: str, relative_to: str | None = None) -> dict[str, float | list[float]]:
        """``{step label: value}`` of a probe, minus its value at step ``relative_to`` if given (vectors: lists)."""
        values = {s.label: s.probes[name] for s in self.steps}
        if relative_to is None:
            return values
        base = values[relative_to]
        if isinstance(base, list):
            return {label: [a - b for a, b in zip(v, base)] for label, v in values.items()}
        return {label: v - base for label, v in values.items()}

    def summary(self) -> dict[str, Any]:
        """The ``summary.json`` content: scene as read, steps with probes, sizes, timings, materials, errors."""
        return {"status": self.status, "scene": dict(self.scene.raw), "steps": [s.to_dict() for s in self.steps],
                "wall_s": self.wall_s, "n_cells": self.n_cells, "n_dofs": self.n_dofs, "n_ranks": self.n_ranks,
                "probe_units": {p: probe_unit(p) for p in self.scene.probes}, "materials": self.materials,
                "model": self.scene.model, "degree": self.scene.degree, "error": self.error,
                "failure": self.failure, "files": list(self.files), "estimate": self.estimate}

    def table(self) -> str:
        """Probes per step, Newton iterations and wall time.

        Lengths in mm, volumes in cm³, forces in N, angles in degrees; vectors as x, y, z columns.
        """
        scale = {"m": 1e3, "deg": 1.0, "N": 1.0, "m3": 1e6}
        unit = {"m": "mm", "deg": "deg", "N": "N", "m3": "cm3"}
        columns = []  # (heading, probe, component or None, scale)
        for n in self.scene.probes:
            u = probe_unit(n)
            if probe_size(n) == 1:
                columns.append((f"{n} ({unit[u]})", n, None, scale[u]))
            else:
                columns += [(f"{n} {c} ({unit[u]})", n, i, scale[u]) for i, c in enumerate("xyz")]
        width = max([22, *(len(c[0]) for c in columns)])
        head = f"{'step':>10s} " + " ".join(f"{c[0]:>{width}s}" for c in columns)
        lines = [f"scene {self.scene.name}: {self.n_cells} cells, {self.n_dofs} dofs, {self.n_ranks} rank(s), "
                 f"{self.wall_s:.1f} s", head + f" {'Newton':>7s} {'wall (s)':>9s}"]
        for s in self.steps:
            values = " ".join(f"{(s.probes[n] if i is None else s.probes[n][i]) * k:{width}.4f}"
                              for _, n, i, k in columns)
            lines.append(f"{s.label:>10s} {values} {s.newton_iterations:7d} {s.wall_s:9.2f}")
        if self.error:
            lines.append(f"{self.status.upper()}: {self.error}")
        return "\n".join(lines)


def probes_csv(result: SceneResult, std: list[dict[str, Any]] | None = None) -> str:
    """``probes.csv``: one row per step; a vector probe in three columns ``KIND:GROUP_x_UNIT``, ``_y_``, ``_z_``.

    With ``std`` (per step, σ of every probe: ``--uncertainty``), each value column is followed by its standard
    deviation, ``..._std_UNIT``.
    """
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    names = []
    for p in result.scene.probes:
        unit = probe_unit(p)
        stems = [p] if probe_size(p) == 1 else [f"{p}_{c}" for c in "xyz"]
        for stem in stems:
            names += [f"{stem}_{unit}"] + ([f"{stem}_std_{unit}"] if std is not None else [])
    writer.writerow(["step", *names, "newton_iterations", "wall_s"])
    for k, s in enumerate(result.steps):
        values = []
        for p in result.scene.probes:
            value = [s.probes[p]] if probe_size(p) == 1 else list(s.probes[p])
            sigma = None if std is None else ([std[k][p]] if probe_size(p) == 1 else list(std[k][p]))
            for i, v in enumerate(value):
                values += [repr(v)] + ([] if sigma is None else [repr(float(sigma[i]))])
        writer.writerow([s.label, *values, s.newton_iterations, repr(s.wall_s)])
    return buffer.getvalue()


def output_path(out_dir: Path, name: str) -> Path:
    """``out_dir / name`` for a plain file name (no directory part, not hidden); anything else is refused."""
    if not name or name != os.path.basename(name) or name.startswith(".") or "\0" in name or "\\" in name:
        raise InputError(f"{name!r} is not a plain file name: outputs are written inside {out_dir} only")
    return out_dir / name


def write_summary(result: SceneResult, out_dir: Path) -> None:
    """``summary.json`` and ``probes.csv`` in ``out_dir`` (call on one rank)."""
    for name in ("probes.csv", "summary.json"):
        if name not in result.files:
            result.files.append(name)
    write_text_atomic(out_dir / "probes.csv", probes_csv(result))
    write_json_atomic(out_dir / "summary.json", result.summary())


def _previous_run(path: Path) -> dict[str, Any] | None:
    """The summary of the run that wrote ``path``, or None if ``path`` is not a run folder."""
    try:
        summary = json.loads((path / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return summary if isinstance(summary, dict) and "scene" in summary and "steps" in summary else None


def _previous_files(path: Path, summary: dict[str, Any]) -> set[str]:
    """The names a previous run wrote: those it lists, the fixed outputs, its pictures, its temporaries."""
    names = {n for n in summary.get("files", []) if isinstance(n, str)} | set(FIXED_OUTPUTS)
    steps = summary.get("scene", {}).get("steps", []) if isinstance(summary.get("scene"), dict) else []
    labels = [s.get("label") for s in [*summary.get("steps", []), *steps] if isinstance(s, dict)]
    names |= {f"{label}.png" for label in labels if isinstance(label, str) and LABEL_PATTERN.fullmatch(label)}
    scheduled = [s.get("label") if isinstance(s, dict) else None for s in steps]
    names |= {series_file(i, label) for i, label in enumerate(scheduled)
              if isinstance(label, str) and LABEL_PATTERN.fullmatch(label)}
    names |= {p.name for p in path.iterdir() if p.name.startswith(_XDMF_TEMPORARY) or TEMPORARY.match(p.name)}
    return {n for n in names if n == os.path.basename(n) and n not in ("", ".", "..")}


class RunFolder:
    """The output directory of one run (the rules: the module docstring). Collective methods say so.

    Parameters
    ----------
    path
        The directory.
    comm
        The run's communicator; rank 0 does the file work.
    what
        How the directory is named in error messages (``out_dir``; the command line says ``--out``).

    """

    def __init__(self, path: str | os.PathLike, comm, what: str = "out_dir", wait: bool = False):
        self.path, self.comm, self.what, self.wait = Path(path), comm, what, wait
        self._lock: int | None = None

    def _acquire(self, wait: bool) -> int:
        """Lock the directory (``flock`` on it, rank 0): one run per folder. :class:`InputError` if another holds it."""
        fd = os.open(self.path, os.O_RDONLY | os.O_DIRECTORY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(fd)
            raise InputError(f"{self.what} {self.path}: another run is writing into this folder (it holds the "
                             "folder's lock); give another directory, or wait for that run to end (the command "
                             "line's --wait does)") from None
        return fd

    def check(self) -> Path:
        """Check before any work that the directory can hold this run (collective); :class:`InputError` if not."""
        def check():
            path = check_output_dir(self.path, self.what)
            if path.is_dir() and not self.wait:
                os.close(self._acquire(wait=False))  # refused early if a run is writing there now
            if path.is_dir() and any(path.iterdir()) and _previous_run(path) is None:
                raise InputError(f"{self.what} {path}: the directory is not empty and not a run's output folder "
                                 "(no summary.json of a run); give a new or empty directory, or a previous run's")
            return path
        on_rank0(self.comm, check, f"the output directory {self.path} cannot be used")
        return self.path

    def start(self, result: SceneResult) -> None:
        """Remove the previous run's files and write ``summary.json`` with ``"status": "incomplete"`` (collective)."""
        def start():
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock = self._acquire(self.wait)  # held until finish(): no other run cleans up or writes here
            previous = _previous_run(self.path)
            if previous is not None:
                for name in sorted(_previous_files(self.path, previous)):
                    target = self.path / name
                    if target.is_dir() and not target.is_symlink():
                        shutil.rmtree(target, ignore_errors=True)
                    else:
                        with contextlib.suppress(FileNotFoundError):
                            target.unlink()
                logger.info("run folder %s: removed the previous run's files", self.path)
            result.status, result.files = "incomplete", ["summary.json"]
            write_json_atomic(self.path / "summary.json", result.summary())
        on_rank0(self.comm, start, f"the output directory {self.path} could not be prepared")

    def progress(self, result: SceneResult, *names: str) -> list[Path]:
        """Record files about to be written and the steps done in ``summary.json`` (rank 0); their paths."""
        paths = [output_path(self.path, name) for name in names]
        result.files.extend(n for n in names if n not in result.files)
        if self.comm.rank == 0:
            write_json_atomic(self.path / "summary.json", result.summary())
        return paths

    def finish(self, result: SceneResult, status: str, error: str | None = None) -> None:
        """Write the final ``summary.json`` and ``probes.csv`` (rank 0 only: safe when other ranks have stopped)."""
        result.status = status
        if error is not None:
            result.error = error
        if self.comm.rank == 0:
            try:
                result.files = [n for n in result.files if (self.path / n).exists()]  # e.g. a picture interrupted
                write_summary(result, self.path)
            finally:
                if self._lock is not None:
                    os.close(self._lock)  # releases the folder's lock
                    self._lock = None


def _system_error(directory: Path, size: int = 1 << 20) -> str:
    """The system's error for a write of ``size`` bytes in ``directory`` (a probe, removed), or why none is seen."""
    probe = directory / f".write-probe.{os.getpid()}"
    try:
        with open(probe, "wb") as f:
            f.write(b"\0" * size)
            f.flush()
            os.fsync(f.fileno())
    except OSError as exc:
        return f"{exc.strerror} ({errno.errorcode.get(exc.errno, exc.errno)})"
    finally:
        with contextlib.suppress(OSError):
            probe.unlink()
    return "no system error reproduced by a test write (see HDF5's diagnostics above)"


class XdmfSeries:
    """``solution.xdmf`` (+ ``.h5``): the mesh once, the displacement per step (time = step index).

    Written in a temporary directory inside the output directory (the XDMF refers to its HDF5 file by name)
    and moved into place by :meth:`commit` (rank 0, ``os.replace``, the HDF5 file first).
    """

    def __init__(self, comm, out_dir: Path, mesh):
        from dolfinx.io import XDMFFile
        self._comm, self._out = comm, out_dir
        tmp = None
        if comm.rank == 0:
            tmp = tempfile.mkdtemp(dir=out_dir, prefix=_XDMF_TEMPORARY)
            register_temporary(tmp)  # at once: a signal during the broadcast below must not leave it behind
        self._tmp = Path(comm.bcast(tmp, root=0))
        register_temporary(self._tmp)  # removed on every rank if a signal arrives
        self._file = XDMFFile(comm, str(self._tmp / "solution.xdmf"), "w")
        self._guarded(lambda: self._file.write_mesh(mesh))

    def _guarded(self, write) -> None:
        """Run a write of the HDF5/XDMF file; an HDF5 failure becomes a :class:`WriteError` naming the file.

        HDF5 reports only that it failed (its own diagnostics go to stderr); the system's error is found by
        writing as many bytes again beside it (:func:`_system_error`). A file HDF5 could not write cannot be
        closed either, and its C++ destructor would then abort the process: it is kept open (leaked) instead.
        """
        try:
            write()
        except RuntimeError as exc:
            keep_unclosable(self._file)
            self._file = None
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise WriteError(f"cannot write {self._out / 'solution.h5'}: HDF5 failed ({exc}): "
                             f"{_system_error(self._tmp.parent)}; the series was not written") from exc

    def write(self, u, t: float) -> None:
        """Append the displacement ``u`` at time ``t`` (collective)."""
        self._guarded(lambda: self._file.write_function(u, t))

    def commit(self) -> None:
        """Close the files and move them into the output directory (collective)."""
        self._guarded(self._file.close)
        self._comm.Barrier()
        if self._comm.rank == 0:
            (self._tmp / "solution.h5").replace(self._out / "solution.h5")
            (self._tmp / "solution.xdmf").replace(self._out / "solution.xdmf")
            shutil.rmtree(self._tmp, ignore_errors=True)
        discard_temporary(self._tmp)
        self._comm.Barrier()

    def abort(self, collective: bool = True) -> None:
        """Remove the temporary directory, on every rank that calls this.

        ``collective``: close the files first (every rank must call); an interrupted run passes False, as the
        other ranks may have stopped (closing a parallel HDF5 file waits for them).
        """
        if collective and self._file is not None:
            with contextlib.suppress(Exception):
                self._file.close()
        for _ in range(10):  # another rank may still be writing a file into it (until it waits in MPI): retry
            shutil.rmtree(self._tmp, ignore_errors=True)
            if not self._tmp.exists():
                break
            time.sleep(0.05)
        discard_temporary(self._tmp)


def picture_step(u, out_dir: Path, scene: Scene, label: str) -> None:
    """``<label>.png``: the deformed shape at the end of a step (collective; rank 0 writes)."""
    from fenicsfoam.plotting import plot_displacement
    plot_displacement(u, output_path(out_dir, f"{label}.png"), title=f"{scene.name}: {label}",
                      obstacles=_obstacles(scene, label))


def _obstacles(scene: Scene, label: str) -> list:
    """The scene's contact obstacles where they are at the end of the step ``label`` (none without contacts)."""
    contacts = scene.loads.get("contact") or {}
    if not contacts:
        return []
    from fenicsfoam.contact import OBSTACLES, Obstacle
    factors = dict.fromkeys(contacts, 0.0)
    for step in scene.steps:
        factors.update({k: v for k, v in step.loads.items() if k in contacts})
        if step.label == label:
            break
    return [Obstacle(spec["obstacle"], **{k: spec[k] for k in OBSTACLES[spec["obstacle"]]})
            .moved([factors[name] * m for m in spec["motion"]]) for name, spec in contacts.items()]


def picture_orientation(orientation, out_dir: Path, scene: Scene) -> None:
    """``orientation.png``: the l axis at the cell midpoints (collective; rank 0 writes)."""
    from fenicsfoam.plotting import plot_orientation
    plot_orientation(orientation, out_dir / "orientation.png", title=f"{scene.name}: l axis")


def series_file(index: int, label: str) -> str:
    """The name of step ``index``'s ``.vtu`` file (``solution_NNN_<label>.vtu``)."""
    return f"solution_{index:03d}_{label}.vtu"


class FieldSeries:
    """``solution.pvd`` and one ``solution_NNN_<label>.vtu`` per step: the displacement and the cell fields.

    Point data: ``displacement`` (m). Cell data (one value per cell, the mean over the cell's quadrature points of
    the stress integral, or the cell's constant): ``region`` (cell tag), ``density`` and ``gamma`` (foam regions;
    NaN elsewhere), ``l_axis`` (anisotropic scenes), ``cauchy_stress`` (Pa, 9 components row by row: ``σ = P Fᵀ /
    det F``; the linear model's stress as it is), ``von_mises`` (Pa, of the cell's mean ``σ``),
    ``equivalent_strain`` (``sqrt(2/3 dev e : dev e)`` of the model's strain ``e``: Green–Lagrange for SVK, the
    corotated strain ``sym(Rᵀ F) - I`` for corotational, ``sym ∇u`` for linear), ``det_F`` and
    ``ellipticity_margin`` (Pa, :func:`fenicsfoam.stability.ellipticity_margin` with :data:`MARGIN_DIRECTIONS`
    sampled normals; omitted above :data:`MARGIN_MAX_CELLS` cells, where it would cost more than the solve).
    Field data: ``step_index``, ``step_label`` (its UTF-8 bytes as UInt8), ``gravity_factor``, and per external load
    ``load_factor:<name>``, per rigid motion ``angle_deg:<name>`` and ``translation_m:<name>``.

    Every file is written atomically by rank 0; ``solution.pvd`` is rewritten after each step, so it lists exactly
    the steps whose files exist. Building the series and :meth:`write` are collective.
    """

    def __init__(self, model, scene: Scene, out_dir: Path, layout):
        import basix
        import ufl
        from dolfinx import fem

        from fenicsfoam.constitutive import deformation_gradient
        from fenicsfoam.orientation import cell_values, owned_cell_tags

        problem = model.problem
        self._problem, self._layout, self._out = problem, layout, out_dir
        self._entries: list[tuple[float, str, str]] = []
        mesh = problem.V.mesh
        self._n_cells = n = mesh.topology.index_map(mesh.topology.dim).size_local
        self._cells = np.arange(n, dtype=np.int32)
        tags = owned_cell_tags(mesh, model.tagged.cell_tags)
        density, gamma = np.full(n, np.nan), np.full(n, np.nan)
        graded = getattr(model, "cell_materials", None)
        for region in scene.regions:
            if region.material != "foam":
                continue
            if graded is not None and region.name in graded.foams:
                foam = graded.foams[region.name]
                density[foam.cells], gamma[foam.cells] = foam.density, foam.gamma
            else:
                inside = np.isin(tags, region.tags)
                for key, values in (("density", density), ("gamma", gamma)):
                    value = region.parameters.get(key)
                    values[inside] = value if isinstance(value, int | float) else np.nan
        static = {"region": tags.astype(np.int32), "density": density, "gamma": gamma}
        if model.orientation is not None:
            static["l_axis"] = cell_values(model.orientation)
        self._static = {name: layout.gather_cells(values) for name, values in static.items()}

        u = problem.u
        F = deformation_gradient(u)
        J = ufl.det(F)
        sigma = problem.stress * F.T / J if problem.model.finite_strain else problem.stress
        e = problem.model.strain(u, problem.rotation)
        dev = e - ufl.tr(e) / 3 * ufl.Identity(3)
        cell = basix.cell.string_to_type(mesh.topology.cell_name())
        points, weights = basix.make_quadrature(cell, problem.quadrature_degree)
        self._weights = weights / weights.sum()
        self._expression = fem.Expression(
            ufl.as_vector([sigma[i, j] for i in range(3) for j in range(3)]
                          + [J, ufl.sqrt(2.0 / 3.0 * ufl.inner(dev, dev))]), points)
        self._margin = mesh.comm.allreduce(n) <= MARGIN_MAX_CELLS

    def write(self, index: int, label: str) -> str:
        """Write step ``index`` (the problem's current state) and the collection; returns the ``.vtu`` name."""
        from fenicsfoam.orientation import cell_values

        problem, layout = self._problem, self._layout
        values = self._expression.eval(self._cells).reshape(self._n_cells, len(self._weights), 11)
        mean = np.einsum("cpk,p->ck", values, self._weights)
        sigma = mean[:, :9].reshape(-1, 3, 3)
        deviator = sigma - np.trace(sigma, axis1=1, axis2=2)[:, None, None] * np.eye(3) / 3
        computed = {"cauchy_stress": mean[:, :9],
                    "von_mises": np.sqrt(1.5 * np.einsum("cij,cij->c", deviator, deviator)),
                    "equivalent_strain": mean[:, 10], "det_F": mean[:, 9]}
        if self._margin:
            check = problem.ellipticity_margin(directions=MARGIN_DIRECTIONS, refinements=MARGIN_REFINEMENTS)
            computed["ellipticity_margin"] = cell_values(check.margin)
        cells = {**self._static, **{name: layout.gather_cells(v) for name, v in computed.items()}}
        displacement = layout.gather_function(problem.u)
        name = series_file(index, label)
        if layout.mesh is not None:
            loads = problem.loads
            fields = {"step_index": np.array([index], dtype=np.int64),
                      "step_label": np.frombuffer(label.encode(), dtype=np.uint8),
                      "gravity_factor": np.array([loads.gravity])}
            fields.update({f"load_factor:{k}": np.array([v]) for k, v in loads.factors.items()})
            fields.update({f"angle_deg:{k}": np.array([np.degrees(v)]) for k, v in loads.angles.items()})
            fields.update({f"translation_m:{k}": np.asarray(v, dtype=float).reshape(1, 3)
                           for k, v in loads.translations.items()})
            write_vtu(output_path(self._out, name), layout.mesh, {"displacement": displacement}, cells, fields)
            self._entries.append((float(index), label, name))
            write_pvd(self._out / PVD_FILE, self._entries)
        return name


class Progress:
    """What a run is doing, on rank 0: lines in ``run.log`` and, when stderr is a terminal, a status line there.

    :meth:`line` records a line for good (the size estimate, a finished step); :meth:`status` records where the
    solve is (a Newton iteration and its residual): on a terminal it replaces the status line, in the log it is a
    line of its own. Other ranks do nothing.
    """

    def __init__(self, comm, log: Path | None, stream=None):
        stream = sys.stderr if stream is None else stream
        self._on = comm.rank == 0
        self._stream = stream if self._on and _is_terminal(stream) else None
        self._log = open(log, "a", encoding="utf-8") if self._on and log is not None else None  # noqa: SIM115
        self._start = time.monotonic()
        self._width = 0

    def _write_log(self, text: str) -> None:
        if self._log is not None and not self._log.closed:
            self._log.write(f"[{time.monotonic() - self._start:8.1f} s] {text}\n")
            self._log.flush()

    def line(self, text: str) -> None:
        """A line for good."""
        self._write_log(text)
        if self._stream is not None:
            self._stream.write("\r" + " " * self._width + "\r" + text + "\n")
            self._stream.flush()
            self._width = 0

    def status(self, text: str) -> None:
        """Where the solve is now."""
        self._write_log(text)
        if self._stream is not None:
            shown = text[:shutil.get_terminal_size((120, 20)).columns - 1]
            self._stream.write("\r" + shown + " " * max(0, self._width - len(shown)))
            self._stream.flush()
            self._width = len(shown)

    def close(self) -> None:
        """End the status line; close the log."""
        if self._stream is not None and self._width:
            self._stream.write("\n")
            self._stream.flush()
            self._width = 0
        if self._log is not None:
            self._log.close()


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
