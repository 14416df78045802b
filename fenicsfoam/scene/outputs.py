"""What a scene run produces: per-step results, ``summary.json``, ``probes.csv``, the XDMF series and the pictures.

Every file is written atomically (:mod:`foambase.files`; the XDMF series in a temporary directory moved into place
at the end), the text files and pictures by rank 0 only, so an interrupted run never leaves a half-written file.
"""

from __future__ import annotations

import contextlib
import csv
import io
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fenicsfoam.scene.kinds import PROBE_UNITS
from fenicsfoam.scene.schema import Scene
from foambase.files import write_json_atomic, write_text_atomic

__all__ = ["SceneResult", "StepResult", "XdmfSeries", "picture_orientation", "picture_step", "write_summary"]


@dataclass
class StepResult:
    """One load step: probe values (SI, angles in degrees) and solver statistics."""

    label: str
    probes: dict[str, float]
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

    def probe(self, name: str, relative_to: str | None = None) -> dict[str, float]:
        """``{step label: value}`` of a probe, minus its value at step ``relative_to`` if given."""
        values = {s.label: s.probes[name] for s in self.steps}
        base = 0.0 if relative_to is None else values[relative_to]
        return {label: v - base for label, v in values.items()}

    def summary(self) -> dict[str, Any]:
        """The ``summary.json`` content: scene as read, steps with probes, sizes, timings, materials, errors."""
        return {"scene": dict(self.scene.raw), "steps": [s.to_dict() for s in self.steps], "wall_s": self.wall_s,
                "n_cells": self.n_cells, "n_dofs": self.n_dofs, "n_ranks": self.n_ranks,
                "probe_units": {p: PROBE_UNITS[p] for p in self.scene.probes}, "materials": self.materials,
                "model": self.scene.model, "degree": self.scene.degree, "error": self.error,
                "failure": self.failure}

    def table(self) -> str:
        """Probes per step (lengths in mm, angles in degrees), Newton iterations and wall time."""
        scale = {"m": 1e3, "deg": 1.0}
        unit = {"m": "mm", "deg": "deg"}
        names = list(self.scene.probes)
        head = f"{'step':>10s} " + " ".join(f"{n + ' (' + unit[PROBE_UNITS[n]] + ')':>22s}" for n in names)
        lines = [f"scene {self.scene.name}: {self.n_cells} cells, {self.n_dofs} dofs, {self.n_ranks} rank(s), "
                 f"{self.wall_s:.1f} s", head + f" {'Newton':>7s} {'wall (s)':>9s}"]
        for s in self.steps:
            values = " ".join(f"{s.probes[n] * scale[PROBE_UNITS[n]]:22.4f}" for n in names)
            lines.append(f"{s.label:>10s} {values} {s.newton_iterations:7d} {s.wall_s:9.2f}")
        if self.error:
            lines.append(f"FAILED: {self.error}")
        return "\n".join(lines)


def _probes_csv(result: SceneResult) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["step", *(f"{p}_{PROBE_UNITS[p]}" for p in result.scene.probes), "newton_iterations", "wall_s"])
    for s in result.steps:
        writer.writerow([s.label, *(repr(s.probes[p]) for p in result.scene.probes), s.newton_iterations,
                         repr(s.wall_s)])
    return buffer.getvalue()


def write_summary(result: SceneResult, out_dir: Path) -> None:
    """``summary.json`` and ``probes.csv`` in ``out_dir`` (call on one rank)."""
    write_json_atomic(out_dir / "summary.json", result.summary())
    write_text_atomic(out_dir / "probes.csv", _probes_csv(result))


class XdmfSeries:
    """``solution.xdmf`` (+ ``.h5``): the mesh once, the displacement per step (time = step index).

    Written in a temporary directory inside the output directory (the XDMF refers to its HDF5 file by name)
    and moved into place by :meth:`commit` (rank 0, ``os.replace``, the HDF5 file first).
    """

    def __init__(self, comm, out_dir: Path, mesh):
        from dolfinx.io import XDMFFile
        self._comm, self._out = comm, out_dir
        tmp = comm.bcast(tempfile.mkdtemp(dir=out_dir, prefix=".solution.") if comm.rank == 0 else None, root=0)
        self._tmp = Path(tmp)
        self._file = XDMFFile(comm, str(self._tmp / "solution.xdmf"), "w")
        self._file.write_mesh(mesh)

    def write(self, u, t: float) -> None:
        """Append the displacement ``u`` at time ``t`` (collective)."""
        self._file.write_function(u, t)

    def commit(self) -> None:
        """Close the files and move them into the output directory (collective)."""
        self._file.close()
        self._comm.Barrier()
        if self._comm.rank == 0:
            (self._tmp / "solution.h5").replace(self._out / "solution.h5")
            (self._tmp / "solution.xdmf").replace(self._out / "solution.xdmf")
            shutil.rmtree(self._tmp, ignore_errors=True)
        self._comm.Barrier()

    def abort(self) -> None:
        """Close the files and remove the temporary directory (collective)."""
        with contextlib.suppress(Exception):
            self._file.close()
        if self._comm.rank == 0:
            shutil.rmtree(self._tmp, ignore_errors=True)


def picture_step(u, out_dir: Path, scene: Scene, label: str) -> None:
    """``<label>.png``: the deformed shape at the end of a step (collective; rank 0 writes)."""
    from fenicsfoam.plotting import plot_displacement
    plot_displacement(u, out_dir / f"{label}.png", title=f"{scene.name}: {label}")


def picture_orientation(orientation, out_dir: Path, scene: Scene) -> None:
    """``orientation.png``: the l axis at the cell midpoints (collective; rank 0 writes)."""
    from fenicsfoam.plotting import plot_orientation
    plot_orientation(orientation, out_dir / "orientation.png", title=f"{scene.name}: l axis")
