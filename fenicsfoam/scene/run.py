"""Running a scene: build it, step through its load schedule, evaluate its probes after every step, write its outputs.

Before any work the output directory (:class:`~fenicsfoam.scene.outputs.RunFolder`) and the scene's PETSc
options (:func:`foambase.petsc_options.check_options`: a value PETSc refuses, an option it does not read) are
checked; options that PETSc reads only when the solver is set up (e.g. ``mat_mumps_*``) are checked after the first
step. A failed step (:class:`fenicsfoam.solver.ConvergenceError`) is never silent: the steps done and the failure
(its load factor and the strong-ellipticity check at the last converged state) are written first, then the error is
raised; an interruption (Ctrl-C, SIGTERM) is written into ``summary.json`` the same way. A progress bar over the
steps shows on rank 0 when stderr is a terminal.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from typing import Any

from mpi4py import MPI
from tqdm import tqdm

from fenicsfoam.io import SOLUTION_FILE, SolutionWriter
from fenicsfoam.scene.build import build_model
from fenicsfoam.scene.outputs import (
    RunFolder,
    SceneResult,
    StepResult,
    XdmfSeries,
    picture_orientation,
    picture_step,
)
from fenicsfoam.scene.schema import PETSC_PREFIX, Scene, load_scene
from fenicsfoam.scene.table import SceneError
from fenicsfoam.solver import ConvergenceError, ElasticityProblem
from foambase.errors import InputError
from foambase.petsc_options import check_options

__all__ = ["run_scene"]

logger = logging.getLogger(__name__)


def check_solver_options(scene: Scene) -> None:
    """The scene's ``[fem.petsc]`` options, before any work: :class:`SceneError` naming a refused or unread option."""
    try:
        check_options(scene.petsc, PETSC_PREFIX, ElasticityProblem.default_options(), where="fem.petsc",
                      own=("mat_type",))
    except InputError as exc:
        raise SceneError(str(exc)) from exc


def _check_deferred_options(problem: ElasticityProblem) -> None:
    """After a solve: the scene's options that PETSc has still not read (e.g. ``mat_mumps_*`` of another solver)."""
    unused = problem.unused_options()
    if unused:
        raise SceneError(f"fem.petsc.{unused[0]}: PETSc did not use this option during the first step (misspelt, "
                         f"or not an option of this solver); unused: {', '.join(unused)}")


def _interruption(exc: BaseException, step: str | None, done: int, total: int) -> str:
    what = f"interrupted by {exc.signal_name}" if hasattr(exc, "signal_name") else "interrupted (KeyboardInterrupt)"
    where = f" during step {step!r}" if step is not None else ""
    return f"{what}{where} ({done} of {total} steps done)"


def _value(value: Any) -> float | list[float]:
    """A probe's value for JSON: a float, or a list of floats for a vector."""
    if isinstance(value, list | tuple) or getattr(value, "ndim", 0):
        return [float(v) for v in value]
    return float(value)


def run_scene(source: str | os.PathLike | Mapping[str, Any] | Scene, out_dir: str | os.PathLike | None = None, *,
              comm=None, wait: bool = False) -> SceneResult:
    """Build a scene, run its load schedule, evaluate its probes after every step and write its outputs.

    Parameters
    ----------
    source
        A TOML file, a dict as ``tomllib`` reads one, or a parsed :class:`Scene`.
    out_dir
        Where to write ``summary.json``, ``probes.csv``, ``solution.xdmf`` (+ ``.h5``), ``solution.npz``
        (:func:`fenicsfoam.io.read_solution`) and the PNG pictures (``<step>.png``, and ``orientation.png`` for
        anisotropic scenes); ``None`` writes nothing. A new or empty directory, or a previous run's folder, whose
        files are replaced (the rules: :mod:`fenicsfoam.scene.outputs`). Every file is written atomically, the text
        and pictures on rank 0 only.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).
    wait
        If another run is writing into ``out_dir`` (it holds the folder's lock), wait for it to end instead of
        refusing (:class:`InputError`).

    Returns
    -------
    SceneResult
        Steps with probe values (SI, angles in degrees) and Newton statistics, sizes and timings;
        ``result.table()`` prints them.

    Raises
    ------
    SceneError
        Invalid scene, including a PETSc option that PETSc refuses or does not read (nothing is built; an option
        read only at set-up is found after the first step, and the run stops there).
    InputError
        ``out_dir`` cannot hold the run (nothing is built).
    fenicsfoam.solver.ConvergenceError
        A load step failed; the outputs of the steps done (and ``error`` in the summary) are written first.
    KeyboardInterrupt
        Interrupted: the summary says so (``"status": "interrupted"``) and the steps done are kept.

    """
    comm = MPI.COMM_WORLD if comm is None else comm
    start = time.perf_counter()
    scene = source if isinstance(source, Scene) else load_scene(source)
    folder = None if out_dir is None else RunFolder(out_dir, comm, wait=wait)
    if folder is not None:
        folder.check()
    check_solver_options(scene)
    model = build_model(scene, comm)
    problem = model.problem
    result = SceneResult(scene, n_cells=model.tagged.n_cells, n_ranks=comm.size,
                         n_dofs=problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
                         materials=model.materials, out_dir=None if folder is None else folder.path)
    if folder is not None:
        folder.start(result)
    out = None if folder is None else folder.path
    series = solution = None
    pictures = scene.png if out is not None else ()
    failure, current = None, None
    try:
        series = XdmfSeries(comm, out, problem.V.mesh) if out is not None and scene.xdmf else None
        solution = SolutionWriter(problem.V, out) if series is not None else None
        bar = tqdm(model.steps, desc=f"scene {scene.name}", unit="step", disable=None if comm.rank == 0 else True)
        for index, step in enumerate(bar):
            current = step.label
            bar.set_postfix(step=step.label, refresh=False)
            try:
                stats = problem.solve_step(step)
            except ConvergenceError as exc:
                failure = exc
                result.error = str(exc)
                result.failure = {"step": exc.step, "load_factor": exc.load_factor, "reason": exc.reason,
                                  "ellipticity": None if exc.ellipticity is None else exc.ellipticity.to_dict()}
                break
            if index == 0:
                _check_deferred_options(problem)
            result.steps.append(StepResult(step.label, {n: _value(p(problem.u)) for n, p in model.probes.items()},
                                           stats.newton_iterations, stats.increments, stats.cutbacks,
                                           stats.min_det_F, stats.wall_s))
            current = None
            logger.info("scene %s, step %s: %s", scene.name, step.label, result.steps[-1].probes)
            if series is not None:
                series.write(problem.u, float(index))
                solution.add(step.label, problem.u)
            if folder is not None:
                folder.progress(result, *([f"{step.label}.png"] if step.label in pictures else []))
            if step.label in pictures:
                picture_step(problem.u, out, scene, step.label)
        bar.close()
        if series is not None:
            series.commit()
            if folder is not None:
                folder.progress(result, "solution.xdmf", "solution.h5", SOLUTION_FILE)
            solution.commit()
        if pictures and model.orientation is not None:
            folder.progress(result, "orientation.png")
            picture_orientation(model.orientation, out, scene)
    except BaseException as exc:
        interrupted = isinstance(exc, KeyboardInterrupt)
        if series is not None:
            series.abort(collective=not interrupted)
        if folder is not None:
            result.wall_s = time.perf_counter() - start
            folder.finish(result, "interrupted" if interrupted else "failed",
                          _interruption(exc, current, len(result.steps), len(model.steps)) if interrupted
                          else f"{type(exc).__name__}: {exc}" if not isinstance(exc, SceneError) else str(exc))
        raise
    result.wall_s = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    result.displacement = problem.u
    if folder is not None:
        folder.finish(result, "failed" if failure is not None else "complete")
    if failure is not None:
        raise failure
    return result
