"""The ``fenicsfoam`` command line: ``fenicsfoam COMMAND [-v] [options]``.

Commands: ``info`` (versions of the numerical stack), ``run`` (a TOML scene; ``--uncertainty``: every probe ± its
standard deviation over the foam table's seeds), ``calibrate`` (the foams' ``E_solid`` from one measurement,
:mod:`fenicsfoam.calibrate`), ``control`` (inverse servo control of the Tripod, :mod:`fenicsfoam.control`),
``homogenize`` (FFT homogenization
of a foam or a phase image; the ``homogenize`` program is the same command), ``table`` (the foam-table sweep).
Exit status: 0 ok, 1 other failure, 2 bad input (detected before any work), 3 a solver did not converge.
``-v`` logs INFO (and FFCx's compiler lines), ``-vv`` DEBUG, on rank 0.

A command is a :class:`foambase.cli.Command` registered in :data:`COMMANDS` as ``"module:ATTRIBUTE"``: a new one
is one line there (its module is imported when the parser is built, after the entry point has kept OpenBLAS
single-threaded, so command modules import numpy only inside their functions or after that).
"""

from __future__ import annotations

import argparse
import logging
import sys

from foambase import cli

__all__ = ["COMMANDS", "INFO", "RUN", "main"]

logger = logging.getLogger(__name__)

#: The sub-commands, in the order ``fenicsfoam --help`` lists them.
COMMANDS: tuple[str, ...] = (
    "fenicsfoam.cli:INFO",
    "fenicsfoam.cli:RUN",
    "fenicsfoam.calibrate:CALIBRATE",
    "fenicsfoam.control:CONTROL",
    "homogenization.cli:HOMOGENIZE",
    "homogenization.cli:TABLE",
)


def _info(_: argparse.Namespace) -> int:
    """Print the versions of the numerical stack this installation uses."""
    import dolfinx
    import numpy
    import ufl
    from mpi4py import MPI
    from petsc4py import PETSc

    import fenicsfoam

    rows = [
        ("fenicsfoam", fenicsfoam.__version__),
        ("dolfinx", dolfinx.__version__),
        ("ufl", ufl.__version__),
        ("petsc", ".".join(map(str, PETSc.Sys.getVersion()))),
        ("mpi", MPI.Get_library_version().splitlines()[0]),
        ("numpy", numpy.__version__),
    ]
    for name, version in rows:
        print(f"{name:12s} {version}")
    return 0


def _run_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", type=cli.nonempty_path, help="the scene file (TOML)")
    parser.add_argument("--out", type=cli.nonempty_path, required=True,
                        help="output directory: new, empty, or a previous run's folder (its files are replaced)")
    parser.add_argument("--wait", action="store_true",
                        help="if another run is writing into --out, wait for it to end (default: refuse)")
    parser.add_argument("--uncertainty", action="store_true",
                        help="also run once per seed of the foam table: every probe as value ± standard deviation "
                             "(summary.json: probes_std per step)")
    parser.add_argument("--solver", choices=("auto", "direct", "iterative"), default="auto",
                        help="linear solver of the Newton iterations: direct (MUMPS LU), iterative (Krylov + GAMG "
                             "with the rigid-body near-null space), or auto: direct up to 1000000 dofs while its "
                             "estimated memory fits, iterative otherwise")
    parser.add_argument("--force", action="store_true",
                        help="run even when the estimated memory (printed before assembly) exceeds the memory "
                             "available (otherwise refused, exit status 2)")
    parser.add_argument("--samples", type=cli.nonempty_path, default=None, metavar="CSV",
                        help="per-seed samples for --uncertainty (default: the shipped foam_table_samples.csv)")


def _run_check(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.samples is not None and not args.uncertainty:
        parser.error("--samples is used only with --uncertainty")
    if args.samples is not None and not args.samples.exists():
        parser.error(f"--samples: file {str(args.samples)!r} does not exist")
    if args.samples is not None:
        from foambase.errors import InputError
        from foambase.files import check_input_file
        try:
            check_input_file(args.samples, "--samples")
        except InputError as exc:
            parser.error(str(exc))


def _run(args: argparse.Namespace) -> int:
    """Run a scene file; PETSc options after ``--`` go to the options database (they override the scene's).

    The output directory is checked before the scene is read (``--out`` named in the error); command-line PETSc
    options that nothing has read by the end of the run are reported in a warning (as PETSc's ``-options_left``).
    The size estimate is printed before assembly, and the table of the steps done after a failure or an
    interruption too.
    """
    from mpi4py import MPI

    from fenicsfoam.scene import run_scene
    from fenicsfoam.scene.outputs import RunFolder
    from foambase.petsc_options import command_line_options

    comm = MPI.COMM_WORLD
    RunFolder(args.out, comm, what="--out", wait=args.wait).check()
    with command_line_options(args.passthrough):
        if args.uncertainty:
            from fenicsfoam.uncertainty import run_with_uncertainty

            result = run_with_uncertainty(args.scene, args.out, samples_csv=args.samples, comm=comm,
                                          solver=args.solver, force=args.force,
                                          echo=lambda text: print(text, flush=True))
        else:
            result = run_scene(args.scene, args.out, comm=comm, solver=args.solver, force=args.force,
                               echo=lambda text: print(text, flush=True), wait=args.wait)
    if comm.rank == 0:
        print(result.table())
        print(f"outputs in {args.out}")
    return 0


INFO = cli.Command("info", "versions of the numerical stack", lambda parser: None, _info)
RUN = cli.Command(
    "run", "run a TOML scene: summary.json, probes.csv, solution.xdmf, PNGs", _run_arguments, _run,
    description="Run a TOML scene (every key: the docs' scenes page). PETSc options after '--' apply to the "
                "scene's solver, prefix 'scene_' (e.g. -- -scene_snes_rtol 1e-8). With --uncertainty, every "
                "probe is reported as value ± standard deviation over the foam table's seeds. Works under mpirun.",
    check=_run_check, passthrough=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``fenicsfoam`` console script; returns the exit status."""
    return cli.main("fenicsfoam", "Stochastic foams → homogenized tables → soft-robot scenes (FEniCSx).",
                    COMMANDS, argv)


if __name__ == "__main__":
    sys.exit(main())
