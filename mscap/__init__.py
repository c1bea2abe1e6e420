"""mscap: computational design of capacitive stretch sensors.

The stages, each a module returning a frozen dataclass:
``scene`` (Scene) → ``layout`` (Layout) → ``mesh2d`` (TriMesh) → ``layered``
(LayeredMesh) → later: elastic, electrostatic, objective, optimize, multistart.
"""

from mscap.errors import GeometryError, MeshError, MscapError, SceneError

__version__ = "0.1.0"

__all__ = ["__version__", "MscapError", "SceneError", "GeometryError", "MeshError"]
