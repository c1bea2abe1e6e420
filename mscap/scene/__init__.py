"""The scene: what the sheet is and what it must sense.

``settings`` holds the frozen dataclasses (:class:`Scene` and its tables) and the allowed
values of each choice; ``loader`` reads a TOML file into a :class:`Scene` with every check
in one place; ``poses`` and ``calibration`` read the ``[[poses]]`` and ``[calibration]``
tables. Nothing here imports FEM code.

    from mscap.scene import load_scene
    scene = load_scene("jobs/quick.toml")        # every check, one line per error
    scene.poses, scene.layout.k, scene.mesh.edge_length_mm
"""

from mscap._lazy import lazy_names
from mscap.scene.loader import load_scene  # noqa: F401 (in __all__)
from mscap.scene.settings import Scene  # noqa: F401 (in __all__)

__all__, __getattr__ = lazy_names(__name__, {
    "select_poses": "loader",
    "sheet_for": "sizing",
}, eager=("Scene", "load_scene"))
