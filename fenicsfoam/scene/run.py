"""Running a scene: build it, step through its load schedule, evaluate its probes after every step, write its outputs.

Before any work the output directory (:class:`~fenicsfoam.scene.outputs.RunFolder`) and the scene's PETSc
options (:func:`foambase.petsc_options.check_options`: a value PETSc refuses, an option it does not read) are
checked; options that PETSc reads only when the solver is set up (e.g. ``mat_mumps_*``) are checked after the first
step. A failed step (:class:`fenicsfoam.solver.ConvergenceError`) is never silent: the steps done and the failure
(its load factor and the strong-ellipticity check at the last converged state) are written first, then the error is
raised; an interruption (Ctrl-C, SIGTERM) is written into ``summary.json`` the same way, also when the solver is
inside a long compiled call (:data:`foambase.signals.FORCE_S`).

Once the mesh is built and before anything is assembled, the run is sized (:mod:`fenicsfoam.sizing`): cells, dofs,
the linear solver (``auto``: MUMPS LU up to :data:`~fenicsfoam.sizing.ITERATIVE_ABOVE_DOFS` dofs, Krylov + GAMG
above; a scene or command line that sets ``ksp_type`` or ``pc_type`` keeps its own), and the estimated memory and
time; a run that would not fit in the available memory is refused (:class:`~fenicsfoam.sizing.TooLargeError`)
unless ``force``. The estimate and the progress of every step (Newton iterations and residuals) go to ``run.log``
in the output directory and, on a terminal, to a status line on stderr (rank 0).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from typing import Any

from mpi4py import MPI
from petsc4py import PETSc

from fenicsfoam import sizing
from fenicsfoam.io import PVD_FILE, SOLUTION_FILE, NodeLayout, SolutionWriter
from fenicsfoam.scene.build import build_model
from fenicsfoam.scene.outputs import (
    LOG_FILE,
    FieldSeries,
    Progress,
    RunFolder,
    SceneResult,
    StepResult,
    XdmfSeries,
    picture_orientation,
    picture_step,
    series_file,
)
from fenicsfoam.scene.schema import PETSC_PREFIX, Scene, load_scene
from fenicsfoam.scene.table import SceneError
from fenicsfoam.solver import ConvergenceError, ElasticityProblem
from foambase.errors import InputError
from foambase.petsc_options import check_options
from foambase.signals import FORCE_S, discard_last_resort, register_last_resort

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


def _sizer(scene: Scene, comm, solver: str, force: bool, announce):
    """The ``before_problem`` hook of :func:`build_model`: size the run, announce it, refuse it or choose its solver.

    Returns the hook and a one-element list that receives the :class:`~fenicsfoam.sizing.SizeEstimate`.
    """
    from fenicsfoam.constitutive import as_model

    made = []

    def size(mesh) -> dict[str, Any]:
        cells, dofs = sizing.size_of(mesh, scene.degree)
        db = PETSc.Options()
        own = {key: str(scene.petsc[key]) for key in ("ksp_type", "pc_type") if key in scene.petsc}
        own.update({key: db.getString(PETSC_PREFIX + key) for key in ("ksp_type", "pc_type")
                    if db.hasName(PETSC_PREFIX + key)})
        increments = sum(step.increments for step in scene.steps)

        def estimate_for(kind: str) -> sizing.SizeEstimate:
            return sizing.estimate(cells, dofs, kind, comm.size, increments)

        if comm.rank == 0:
            if own:  # the scene's or the command line's own linear solver
                kind = "direct" if own.get("pc_type", "lu") in ("lu", "cholesky") else "iterative"
            else:
                kind = sizing.choose_solver(solver, dofs, solver != "auto" or estimate_for("direct").fits)
            estimate = estimate_for(kind)
        estimate = comm.bcast(estimate if comm.rank == 0 else None, root=0)
        kind = estimate.solver
        made.append(estimate)
        text = f"scene {scene.name}: {estimate}" + (" (the scene's own solver options)" if own else "")
        announce(text)
        if not estimate.fits and not force:
            raise sizing.TooLargeError(f"{text}: this run would not fit in the memory available; make the mesh "
                                       f"coarser ([geometry] h){', use degree = 1' if scene.degree == 2 else ''}, "
                                       "run on a machine with more memory, or force it (--force; "
                                       "run_scene(force=True))")
        if own or kind == "direct":
            return {}
        return sizing.solver_options(kind, as_model(scene.model).symmetric_tangent)

    return size, made


def _value(value: Any) -> float | list[float]:
    """A probe's value for JSON: a float, or a list of floats for a vector."""
    if isinstance(value, list | tuple) or getattr(value, "ndim", 0):
        return [float(v) for v in value]
    return float(value)


def run_scene(source: str | os.PathLike | Mapping[str, Any] | Scene, out_dir: str | os.PathLike | None = None, *,
              comm=None, solver: str = "auto", force: bool = False, echo=None, wait: bool = False) -> SceneResult:
    """Build a scene, run its load schedule, evaluate its probes after every step and write its outputs.

    Parameters
    ----------
    source
        A TOML file, a dict as ``tomllib`` reads one, or a parsed :class:`Scene`.
    out_dir
        Where to write ``summary.json``, ``probes.csv``, ``run.log``, the field files (``solution.pvd`` with one
        ``solution_NNN_<label>.vtu`` per step, ``solution.npz``, ``solution.xdmf`` + ``.h5``; the rules:
        :mod:`fenicsfoam.io`, :class:`~fenicsfoam.scene.outputs.FieldSeries`) and the PNG pictures (``<step>.png``,
        and ``orientation.png`` for anisotropic scenes); ``None`` writes nothing. A new or empty directory, or a
        previous run's folder, whose files are replaced (the rules: :mod:`fenicsfoam.scene.outputs`). Every file
        but the log is written atomically, the text and pictures on rank 0 only.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).
    solver
        The linear solver: ``auto`` (by size), ``direct`` or ``iterative`` (:mod:`fenicsfoam.sizing`).
    force
        Run even when the estimated memory exceeds the available memory.
    echo
        Called on rank 0 with the size estimate before assembly and, after a failure or an interruption, with the
        table of the steps done (the command line passes ``print``); None: the log only.
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
        ``out_dir`` cannot hold the run (nothing is built); :class:`~fenicsfoam.sizing.TooLargeError`: the run would
        not fit in memory (the mesh is built, nothing assembled, ``out_dir`` untouched).
    fenicsfoam.solver.ConvergenceError
        A load step failed; the outputs of the steps done (and ``error`` in the summary) are written first.
    KeyboardInterrupt
        Interrupted: the summary says so (``"status": "interrupted"``) and the steps done are kept.

    """
    comm = MPI.COMM_WORLD if comm is None else comm
    start = time.perf_counter()
    scene = source if isinstance(source, Scene) else load_scene(source)
    sizing.choose_solver(solver, 0)  # a bad name fails before any work
    folder = None if out_dir is None else RunFolder(out_dir, comm, wait=wait)
    if folder is not None:
        folder.check()
    check_solver_options(scene)
    announced: list[str] = []

    def announce(text: str) -> None:
        announced.append(text)
        logger.info("%s", text)
        if echo is not None and comm.rank == 0:
            echo(text)

    sizer, estimates = _sizer(scene, comm, solver, force, announce)
    model = build_model(scene, comm, before_problem=sizer)
    problem = model.problem
    result = SceneResult(scene, n_cells=model.tagged.n_cells, n_ranks=comm.size,
                         n_dofs=problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
                         materials=model.materials, out_dir=None if folder is None else folder.path,
                         estimate=estimates[0].to_dict() if estimates else None)
    if folder is not None:
        folder.start(result)
        folder.progress(result, LOG_FILE)
    out = None if folder is None else folder.path
    progress = Progress(comm, None if out is None else out / LOG_FILE)
    for text in announced:
        progress.line(text)
    problem.progress = progress.status
    current: list[str | None] = [None]

    def last_resort(signal_name: str) -> None:  # the watcher thread, the main thread stuck in compiled code
        if folder is not None:
            result.wall_s = time.perf_counter() - start
            folder.finish(result, "interrupted",
                          f"interrupted by {signal_name}"
                          + (f" during step {current[0]!r}" if current[0] is not None else "")
                          + f" ({len(result.steps)} of {len(model.steps)} steps done; the solver was inside a "
                            f"compiled call and was stopped {FORCE_S:g} s after the signal)")
        progress.close()
        if echo is not None and comm.rank == 0:
            echo(result.table())

    register_last_resort(last_resort)
    writing = out is not None and scene.xdmf
    layout = NodeLayout(problem.V) if writing else None
    series = solution = fields = None
    pictures = scene.png if out is not None else ()
    failure = None
    try:  # the writers too: one that cannot write (disk full) fails the run like any other error
        series = XdmfSeries(comm, out, problem.V.mesh) if writing else None
        solution = SolutionWriter(problem.V, out, layout) if writing else None
        fields = FieldSeries(model, scene, out, layout) if writing else None
        for index, step in enumerate(model.steps):
            current[0] = step.label
            progress.status(f"step {index + 1}/{len(model.steps)} {step.label}: started")
            try:
                stats = problem.solve_step(step)
            except ConvergenceError as exc:
                failure = exc
                result.error = str(exc)
                result.failure = {"step": exc.step, "load_factor": exc.load_factor, "reason": exc.reason,
                                  "ellipticity": None if exc.ellipticity is None else exc.ellipticity.to_dict()}
                progress.line(f"step {index + 1}/{len(model.steps)} {step.label}: FAILED: {exc}")
                break
            if index == 0:
                _check_deferred_options(problem)
            result.steps.append(StepResult(step.label, {n: _value(p(problem.u)) for n, p in model.probes.items()},
                                           stats.newton_iterations, stats.increments, stats.cutbacks,
                                           stats.min_det_F, stats.wall_s, stats.cpu_s))
            current[0] = None
            logger.info("scene %s, step %s: %s", scene.name, step.label, result.steps[-1].probes)
            progress.line(f"step {index + 1}/{len(model.steps)} {step.label}: done, {stats.newton_iterations} Newton "
                          f"iterations in {stats.increments} increment(s), {stats.cutbacks} cut-back(s), "
                          f"{stats.wall_s:.1f} s")
            if series is not None:
                series.write(problem.u, float(index))
                solution.add(step.label, problem.u)
                folder.progress(result, series_file(index, step.label), PVD_FILE)
                fields.write(index, step.label)
            if folder is not None:
                folder.progress(result, *([f"{step.label}.png"] if step.label in pictures else []))
            if step.label in pictures:
                picture_step(problem.u, out, scene, step.label)
        if series is not None:
            series.commit()
            if folder is not None:
                folder.progress(result, "solution.xdmf", "solution.h5", SOLUTION_FILE)
            solution.commit()
        if pictures and model.orientation is not None:
            folder.progress(result, "orientation.png")
            picture_orientation(model.orientation, out, scene)
    except BaseException as exc:
        discard_last_resort(last_resort)
        interrupted = isinstance(exc, KeyboardInterrupt)
        progress.close()
        if series is not None:
            series.abort(collective=not interrupted)
        if folder is not None:
            result.wall_s = time.perf_counter() - start
            folder.finish(result, "interrupted" if interrupted else "failed",
                          _interruption(exc, current[0], len(result.steps), len(model.steps)) if interrupted
                          else f"{type(exc).__name__}: {exc}" if not isinstance(exc, SceneError) else str(exc))
        if echo is not None and comm.rank == 0:
            echo(result.table())
        raise
    discard_last_resort(last_resort)
    progress.close()
    result.wall_s = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    result.displacement = problem.u
    if folder is not None:
        folder.finish(result, "failed" if failure is not None else "complete")
    if failure is not None:
        if echo is not None and comm.rank == 0:
            echo(result.table())
        raise failure
    return result
