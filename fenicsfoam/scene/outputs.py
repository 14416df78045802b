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
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fenicsfoam.scene.kinds import probe_size, probe_unit
from fenicsfoam.scene.schema import LABEL_PATTERN, Scene
from foambase.errors import InputError, WriteError
from foambase.files import TEMPORARY, check_output_dir, keep_unclosable, write_json_atomic, write_text_atomic
from foambase.mpi import on_rank0
from foambase.signals import discard_temporary, register_temporary

__all__ = ["FIXED_OUTPUTS", "STATUSES", "RunFolder", "SceneResult", "StepResult", "XdmfSeries", "output_path",
           "picture_orientation", "picture_step", "write_summary"]

logger = logging.getLogger(__name__)

#: The files every run may write besides its step pictures (``<label>.png``).
FIXED_OUTPUTS = ("summary.json", "probes.csv", "solution.xdmf", "solution.h5", "solution.npz",
                 "orientation.png")
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
                "failure": self.failure, "files": list(self.files)}

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


def _probes_csv(result: SceneResult) -> str:
    """One row per step; a vector probe in three columns ``KIND:GROUP_x_UNIT``, ``_y_``, ``_z_``."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    names = []
    for p in result.scene.probes:
        unit = probe_unit(p)
        names += [f"{p}_{unit}"] if probe_size(p) == 1 else [f"{p}_{c}_{unit}" for c in "xyz"]
    writer.writerow(["step", *names, "newton_iterations", "wall_s"])
    for s in result.steps:
        values = []
        for p in result.scene.probes:
            values += [repr(s.probes[p])] if probe_size(p) == 1 else [repr(v) for v in s.probes[p]]
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
    write_text_atomic(out_dir / "probes.csv", _probes_csv(result))
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
        tmp = comm.bcast(tempfile.mkdtemp(dir=out_dir, prefix=_XDMF_TEMPORARY) if comm.rank == 0 else None, root=0)
        self._tmp = Path(tmp)
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
        shutil.rmtree(self._tmp, ignore_errors=True)
        discard_temporary(self._tmp)


def picture_step(u, out_dir: Path, scene: Scene, label: str) -> None:
    """``<label>.png``: the deformed shape at the end of a step (collective; rank 0 writes)."""
    from fenicsfoam.plotting import plot_displacement
    plot_displacement(u, output_path(out_dir, f"{label}.png"), title=f"{scene.name}: {label}")


def picture_orientation(orientation, out_dir: Path, scene: Scene) -> None:
    """``orientation.png``: the l axis at the cell midpoints (collective; rank 0 writes)."""
    from fenicsfoam.plotting import plot_orientation
    plot_orientation(orientation, out_dir / "orientation.png", title=f"{scene.name}: l axis")
