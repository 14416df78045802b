"""The ``fenicsfoam`` command line."""

from __future__ import annotations

import argparse
import sys


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


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``fenicsfoam`` (sub-commands are registered here)."""
    parser = argparse.ArgumentParser(prog="fenicsfoam", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="versions of the numerical stack").set_defaults(func=_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``fenicsfoam`` console script."""
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
