"""What every scene command does first: PETSc with the command line's options, the
scene, the scene's ``[petsc]`` table; and the progress printer."""

from __future__ import annotations

import sys
from typing import Callable


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
