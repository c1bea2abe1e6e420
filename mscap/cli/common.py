"""What every command shares: the help formatter; what every scene command does first
(PETSc with the command line's options, the scene, the scene's ``[petsc]`` table); the
``--max-memory-gb`` option of the commands that mesh; and the progress printer."""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import Callable

__all__ = ["DefaultsHelpFormatter", "load_scene_for", "add_memory_option", "add_noise_options", "add_verbose_option",
           "progress_printer", "rank_logging", "start_mpi", "MIN_FILE_SIZE_LIMIT_BYTES"]

#: The smallest file-size limit (``ulimit -f``) under which MPI is started: OpenMPI 4.1's
#: start-up writes its PMIx shared-memory segments as files and, under a limit of 1 MB,
#: dies in ``MPI_Init`` with a dozen PMIx lines (4 MB ran; measured with ``mpirun -n 2``).
#: The job scripts refuse the same before the launcher starts (slurm/common.sh).
MIN_FILE_SIZE_LIMIT_BYTES = 16 * 2**20


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Help that ends an option's text with ``(default: VALUE)`` when it has a default
    worth showing (not ``None``, not a flag's ``False``) and the text does not already
    say it; unlike ``ArgumentDefaultsHelpFormatter``, no ``(default: None)``."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        worth_showing = action.option_strings and action.nargs != 0 and action.default not in (None, argparse.SUPPRESS)
        if worth_showing and "(default" not in text:  # also catches "%(default)s"
            text += " (default: %(default)s)"
        return text


class _MemoryLimit(argparse.Action):
    """Puts ``--max-memory-gb`` into ``MSCAP_MAX_MEMORY_GB``, where the size check before
    meshing (:func:`mscap.mesh.budget.memory_limit`) reads it, in this process and in
    every process it starts."""

    def __call__(self, parser, namespace, value, option_string=None):
        if not (math.isfinite(value) and value > 0):
            parser.error(f"{option_string}: expected a positive number of GB, got {value!r}")
        from mscap.mesh.budget import MEMORY_ENV

        os.environ[MEMORY_ENV] = repr(value)
        setattr(namespace, self.dest, value)


def add_memory_option(parser: argparse.ArgumentParser) -> None:
    """``--max-memory-gb GB``: the memory a mesh may ask for (default: the machine's
    physical memory, :func:`mscap.mesh.budget.memory_limit`); one line in each command
    that meshes."""
    parser.add_argument("--max-memory-gb", type=float, action=_MemoryLimit, metavar="GB",
                        help="refuse, before meshing, a mesh whose simulation would need more than GB "
                             "(default: MSCAP_MAX_MEMORY_GB, else the memory this machine has)")


def add_noise_options(parser: argparse.ArgumentParser, relative_shift: float | None = None,
                      additive_pF: float | None = None) -> None:
    """``--relative-shift FRACTION`` and ``--additive-pF PF``, the read-out noise, named as
    the scene's ``[calibration.noise]`` keys in every command (``None``: the scene's). The
    names ``readout`` used before, ``--noise-relative`` and ``--noise-additive-pF``, still work."""
    scene = " (default: the scene's [calibration.noise], {})"
    parser.add_argument("--relative-shift", type=float, default=relative_shift, metavar="FRACTION",
                        help="per-run multiplicative shift of every capacitance, uniform in 1 +- FRACTION"
                             + (scene.format(0.15) if relative_shift is None else ""))
    parser.add_argument("--additive-pF", dest="additive_pF", type=float, default=additive_pF, metavar="PF",
                        help="per-reading additive error, uniform in +-PF" + (scene.format(2) if additive_pF is None
                                                                             else ""))
    parser.add_argument("--noise-relative", dest="relative_shift", type=float, default=argparse.SUPPRESS,
                        help=argparse.SUPPRESS)
    parser.add_argument("--noise-additive-pF", dest="additive_pF", type=float, default=argparse.SUPPRESS,
                        help=argparse.SUPPRESS)


def add_verbose_option(parser: argparse.ArgumentParser) -> None:
    """``-v``/``--verbose`` on a subcommand as well as before it (``mscap run SCENE -v``): its
    count replaces the one given before the subcommand; without it that one stands."""
    parser.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                        help="more log output (-vv: debug)")


def load_scene_for(args):
    """Initialise PETSc with ``args.petsc_args``, load ``args.scene`` and put its
    ``[petsc]`` entries into the options database (the command line wins)."""
    from mscap.fem.petsc import petsc, set_scene_options
    from mscap.scene import load_scene

    petsc(args.petsc_args)
    scene = load_scene(args.scene)
    set_scene_options(scene.petsc_options)
    return scene


def rank_logging(comm) -> None:
    """Under MPI, every rank loads the scene and logs: each line says which rank wrote it
    (``[rank 2] WARNING ...``); what the scene's loading says is said once, by rank 0 (every
    rank would say the same), and advice about the scene (``record.advice``, e.g. a biased
    element) once, by rank 0 or the first worker."""
    import logging

    rank = comm.Get_rank()
    if comm.Get_size() == 1:
        return
    for handler in logging.getLogger().handlers:
        handler.setFormatter(logging.Formatter(f"[rank {rank}] %(levelname)s %(name)s: %(message)s"))
        if rank > 0:
            handler.addFilter(lambda record: not record.name.startswith("mscap.scene"))
        if rank > 1:
            handler.addFilter(lambda record: not getattr(record, "advice", False))


def progress_printer(quiet: bool) -> Callable[[str], None] | None:
    """Progress lines to stderr, or ``None`` when ``quiet``."""
    return None if quiet else (lambda message: print(message, file=sys.stderr, flush=True))


def start_mpi():
    """``mpi4py.MPI``, started here (``MPI_Init`` on import) unless it runs already. Before
    it starts: a :class:`~mscap.errors.MscapError` naming the limit when the process may not
    write files of :data:`MIN_FILE_SIZE_LIMIT_BYTES` or the session directory (``TMPDIR``,
    else ``/tmp``) has less room, instead of MPI's start-up failing without a word of why."""
    import resource

    from mscap.errors import MscapError

    if "mpi4py.MPI" in sys.modules:  # started already (a test runner, a notebook): nothing to protect
        return sys.modules["mpi4py.MPI"]
    limit, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    if limit != resource.RLIM_INFINITY and limit < MIN_FILE_SIZE_LIMIT_BYTES:
        raise MscapError(f"the file size limit (ulimit -f) is {limit // 1024} KB: MPI's start-up needs at least "
                         f"{MIN_FILE_SIZE_LIMIT_BYTES // 1024} KB (raise it: ulimit -f unlimited)")
    session = os.environ.get("TMPDIR") or "/tmp"  # where OpenMPI puts its session directory
    try:
        room = os.statvfs(session)
    except OSError:
        room = None
    if room is not None and room.f_bavail * room.f_frsize < MIN_FILE_SIZE_LIMIT_BYTES:
        raise MscapError(f"{session} has {room.f_bavail * room.f_frsize // 1024} KB free: MPI's start-up needs at "
                         f"least {MIN_FILE_SIZE_LIMIT_BYTES // 1024} KB there (its session directory; free some "
                         f"or point TMPDIR elsewhere)")
    from mpi4py import MPI

    return MPI
