"""What every command shares: the help formatter; what every scene command does first
(PETSc with the command line's options, the scene, the scene's ``[petsc]`` table); and
the progress printer."""

from __future__ import annotations

import argparse
import sys
from typing import Callable

__all__ = ["DefaultsHelpFormatter", "load_scene_for", "progress_printer"]


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


def load_scene_for(args):
    """Initialise PETSc with ``args.petsc_args``, load ``args.scene`` and put its
    ``[petsc]`` entries into the options database (the command line wins)."""
    from mscap.fem.petsc import petsc, set_scene_options
    from mscap.scene import load_scene

    petsc(args.petsc_args)
    scene = load_scene(args.scene)
    set_scene_options(scene.petsc_options)
    return scene


def progress_printer(quiet: bool) -> Callable[[str], None] | None:
    """Progress lines to stderr, or ``None`` when ``quiet``."""
    return None if quiet else (lambda message: print(message, file=sys.stderr, flush=True))
