"""The ``mscap`` command: argparse subcommands, one small module each."""

from __future__ import annotations

import argparse
import functools
import logging
import os
import re
import sys

# One thread per process unless the user says otherwise: MPI ranks are mscap's
# parallelism, and idle OpenMP/BLAS threads spin against them (on 2 cores a threaded
# MUMPS factorisation of the poking scene ran 15 % slower with 10x the system time).
# Set before numpy loads OpenBLAS.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from mscap import __version__
from mscap.cli import (calibrate, capacitance, fabricate, fit, inspect, merge, mesh, optimize, plot, readout,
                       run, simulate)
from mscap.cli.common import DefaultsHelpFormatter, add_verbose_option
from mscap.errors import MscapError

__all__ = ["main", "build_parser", "parse"]

_COMMANDS = (mesh, capacitance, simulate, optimize, run, inspect, merge, plot, calibrate, fit, readout, fabricate)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mscap", description="Design capacitive stretch sensors.", formatter_class=DefaultsHelpFormatter,
        epilog="PETSc options (-ksp_type, -log_view, ...) given after the subcommand's "
               "arguments go to PETSc; those nothing read are named in a warning at the end.")
    parser.add_argument("--version", action="version", version=f"mscap {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=functools.partial(argparse.ArgumentParser,
                                                               formatter_class=DefaultsHelpFormatter))
    for command in _COMMANDS:
        command.add_parser(sub)
    for subparser in sub.choices.values():  # -v after the subcommand too, never a PETSc option
        add_verbose_option(subparser)
    return parser


#: A PETSc option: one dash, a word of two or more characters (``-ksp_type``, ``-help``).
_PETSC_OPTION = re.compile(r"-[A-Za-z][A-Za-z0-9_]+")
#: A PETSc option's value that starts with a dash: a negative number.
_NEGATIVE = re.compile(r"-\d|-\.\d")


def parse(argv: list[str] | None = None) -> tuple[argparse.Namespace, list[str]]:
    """The command line split into mscap's arguments and PETSc's options.

    After the subcommand, a one-dash word of two or more characters is a PETSc option
    (with the next word as its value unless that starts with a dash), unless it is a
    cluster of the subcommand's own one-letter flags (``-vv``). Left to argparse,
    ``-options_left`` was read as ``-o ptions_left`` (an output directory named
    "ptions_left") and ``-vec_type`` as ``-v`` with a stray argument."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    at = next((i for i, word in enumerate(argv) if word in commands), len(argv))
    flags = {option[1] for option, action in commands[argv[at]]._option_string_actions.items()
             if len(option) == 2 and action.nargs == 0} if at < len(argv) else set()
    mine, petsc, i = argv[:at + 1], [], at + 1
    while i < len(argv):
        word = argv[i]
        if word == "--":
            mine += argv[i:]
            break
        if _PETSC_OPTION.fullmatch(word) and not set(word[1:]) <= flags:
            petsc.append(word)
            if i + 1 < len(argv) and (not argv[i + 1].startswith("-") or _NEGATIVE.match(argv[i + 1])):
                i += 1
                petsc.append(argv[i])
        else:
            mine.append(word)
        i += 1
    args, rest = parser.parse_known_args(mine)
    unknown = [a for a in rest if a.startswith("-")]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    return args, petsc + rest


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status."""
    from mscap.outputs import EscapedStream

    # Everything printed passes one filter: a name read from a file cannot drive the terminal.
    streams = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = EscapedStream(sys.stdout), EscapedStream(sys.stderr)
    try:
        return _main(argv)
    finally:
        sys.stdout, sys.stderr = streams


def _main(argv: list[str] | None) -> int:
    args, petsc_args = parse(argv)
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
