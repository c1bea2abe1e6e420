"""The ``mscap`` command: argparse subcommands, one small module each."""

from __future__ import annotations

import argparse
import functools
import logging
import os
import sys

# One thread per process unless the user says otherwise: MPI ranks are mscap's
# parallelism, and idle OpenMP/BLAS threads spin against them (on 2 cores a threaded
# MUMPS factorisation of the poking scene ran 15 % slower with 10x the system time).
# Set before numpy loads OpenBLAS.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from mscap import __version__
from mscap.cli import (calibrate, capacitance, fabricate, inspect, merge, mesh, optimize, plot, readout, run,
                       simulate)
from mscap.cli.common import DefaultsHelpFormatter
from mscap.errors import MscapError

__all__ = ["main"]

_COMMANDS = (mesh, capacitance, simulate, optimize, run, inspect, merge, plot, calibrate, readout, fabricate)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mscap", description="Design capacitive stretch sensors.", formatter_class=DefaultsHelpFormatter,
        epilog="PETSc options (-ksp_type, -log_view, ...) given after the subcommand's "
               "arguments go to PETSc; those nothing read are named in a warning at the end.")
    parser.add_argument("--version", action="version", version=f"mscap {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=functools.partial(argparse.ArgumentParser,
                                                               formatter_class=DefaultsHelpFormatter))
    for command in _COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status."""
    args, petsc_args = build_parser().parse_known_args(argv)
    unknown = [a for a in petsc_args if a.startswith("--")]
    if unknown:
        build_parser().error(f"unrecognized arguments: {' '.join(unknown)}")
    args.petsc_args = petsc_args
    logging.basicConfig(level=logging.DEBUG if args.verbose > 1 else
                        logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        status = args.run(args) or 0
    except MscapError as exc:
        print(f"mscap: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mscap: interrupted", file=sys.stderr)
        return 130
    _warn_unused_petsc_options(petsc_args)
    return status


def _warn_unused_petsc_options(petsc_args: list[str]) -> None:
    """Name the PETSc options nothing read: PETSc ignores a misspelt ``-ksp_tpye`` in
    silence, and commands such as ``mesh`` do not start PETSc at all."""
    if "petsc4py.PETSc" in sys.modules:
        from mscap.fem.petsc import unused_options

        unused = unused_options()
    else:
        unused = [a for a in petsc_args if a.startswith("-") and a[1:2].isalpha()]
    if unused:
        print(f"mscap: warning: PETSc options never used (misspelt, or for a solver this command "
              f"does not run): {' '.join(unused)}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
