"""Running a scene: build it, step through its load schedule, evaluate its probes after every step, write its outputs.

A failed step (:class:`fenicsfoam.solver.ConvergenceError`) is never silent: the steps done and the failure (its
load factor and the strong-ellipticity check at the last converged state) are written first, then the error is
raised. A progress bar over the steps shows on rank 0 when stderr is a terminal.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mpi4py import MPI
from tqdm import tqdm

from fenicsfoam.scene.build import build_model
from fenicsfoam.scene.outputs import (
    SceneResult,
    StepResult,
    XdmfSeries,
    picture_orientation,
    picture_step,
    write_summary,
)
from fenicsfoam.scene.schema import Scene, load_scene
from fenicsfoam.solver import ConvergenceError

__all__ = ["run_scene"]

logger = logging.getLogger(__name__)


def run_scene(source: str | os.PathLike | Mapping[str, Any] | Scene, out_dir: str | os.PathLike | None = None, *,
              comm=None) -> SceneResult:
    """Build a scene, run its load schedule, evaluate its probes after every step and write its outputs.

    Parameters
    ----------
    source
        A TOML file, a dict as ``tomllib`` reads one, or a parsed :class:`Scene`.
    out_dir
        Where to write ``summary.json``, ``probes.csv``, ``solution.xdmf`` (+ ``.h5``) and the PNG pictures
        (``<step>.png``, and ``orientation.png`` for anisotropic scenes); ``None`` writes nothing. Every file
        is written atomically, the text and pictures on rank 0 only.
    comm
        MPI communicator (default ``MPI.COMM_WORLD``).

    Returns
    -------
    SceneResult
        Steps with probe values (SI, angles in degrees) and Newton statistics, sizes and timings;
        ``result.table()`` prints them.

    Raises
    ------
    SceneError
        Invalid scene (nothing is built).
    fenicsfoam.solver.ConvergenceError
        A load step failed; the outputs of the steps done (and ``error`` in the summary) are written first.

    """
    comm = MPI.COMM_WORLD if comm is None else comm
    start = time.perf_counter()
    scene = source if isinstance(source, Scene) else load_scene(source)
    model = build_model(scene, comm)
    problem = model.problem
    result = SceneResult(scene, n_cells=model.tagged.n_cells, n_ranks=comm.size,
                         n_dofs=problem.V.dofmap.index_map.size_global * problem.V.dofmap.index_map_bs,
                         materials=model.materials)
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        if comm.rank == 0:
            out.mkdir(parents=True, exist_ok=True)
        comm.Barrier()
    series = XdmfSeries(comm, out, problem.V.mesh) if out is not None and scene.xdmf else None
    pictures = scene.png if out is not None else ()
    failure = None
    try:
        bar = tqdm(model.steps, desc=f"scene {scene.name}", unit="step", disable=None if comm.rank == 0 else True)
        for index, step in enumerate(bar):
            bar.set_postfix(step=step.label, refresh=False)
            try:
                stats = problem.solve_step(step)
            except ConvergenceError as exc:
                failure = exc
                result.error = str(exc)
                result.failure = {"step": exc.step, "load_factor": exc.load_factor, "reason": exc.reason,
                                  "ellipticity": None if exc.ellipticity is None else exc.ellipticity.to_dict()}
                break
            result.steps.append(StepResult(step.label, {n: float(p(problem.u)) for n, p in model.probes.items()},
                                           stats.newton_iterations, stats.increments, stats.cutbacks,
                                           stats.min_det_F, stats.wall_s))
            logger.info("scene %s, step %s: %s", scene.name, step.label, result.steps[-1].probes)
            if series is not None:
                series.write(problem.u, float(index))
            if step.label in pictures:
                picture_step(problem.u, out, scene, step.label)
        bar.close()
    except BaseException:
        if series is not None:
            series.abort()
        raise
    if series is not None:
        series.commit()
    if pictures and model.orientation is not None:
        picture_orientation(model.orientation, out, scene)
    result.wall_s = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    result.out_dir = out
    if out is not None and comm.rank == 0:
        write_summary(result, out)
    if failure is not None:
        raise failure
    return result
