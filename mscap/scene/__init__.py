"""The scene: what the sheet is and what it must sense.

``settings`` holds the frozen dataclasses (:class:`Scene` and its tables) and the allowed
values of each choice; ``loader`` reads a TOML file into a :class:`Scene` with every check
in one place; ``poses`` and ``calibration`` read the ``[[poses]]`` and ``[calibration]``
tables. Nothing here imports FEM code.
"""

from mscap.scene.loader import load_scene
from mscap.scene.settings import Scene

__all__ = ["Scene", "load_scene"]
