"""The ``fenicsfoam`` command line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


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


def _run(args: argparse.Namespace) -> int:
    """Run a scene file; PETSc options after ``--`` go to the options database (they override the scene's)."""
    from mpi4py import MPI
    from petsc4py import PETSc

    from fenicsfoam.scene import SceneError, run_scene
    from fenicsfoam.solver import ConvergenceError

    comm = MPI.COMM_WORLD
    if args.petsc:
        PETSc.Options().insertString(" ".join(args.petsc))
    try:
        result = run_scene(args.scene, args.out, comm=comm)
    except (SceneError, ConvergenceError) as exc:
        if comm.rank == 0:
            print(f"fenicsfoam run: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, SceneError) else 3
    if comm.rank == 0:
        print(result.table())
        print(f"outputs in {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``fenicsfoam`` (sub-commands are registered here)."""
    parser = argparse.ArgumentParser(prog="fenicsfoam", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="versions of the numerical stack").set_defaults(func=_info)
    run = sub.add_parser("run", help="run a TOML scene: summary.json, probes.csv, solution.xdmf, PNGs",
                         description="Run a TOML scene (README, 'Scenes and fenicsfoam run'). PETSc options "
                                     "after '--' apply to the scene's solver, prefix 'scene_' "
                                     "(e.g. -- -scene_snes_rtol 1e-8).")
    run.add_argument("scene", type=Path, help="the scene file (TOML)")
    run.add_argument("--out", type=Path, required=True, help="output directory (created if needed)")
    run.set_defaults(func=_run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``fenicsfoam`` console script."""
    argv = sys.argv[1:] if argv is None else list(argv)
    petsc = argv[argv.index("--") + 1:] if "--" in argv else []
    args = build_parser().parse_args(argv[: len(argv) - len(petsc) - (1 if "--" in argv else 0)])
    args.petsc = petsc
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
