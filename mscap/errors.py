"""Error types raised by mscap for user-facing problems.

Library code raises these (never ``sys.exit`` or ``assert``) with a message that names
the file, the field and the offending value, so that the command line can print one clean
line instead of a traceback.
"""

from __future__ import annotations

__all__ = ["MscapError", "SceneError", "GeometryError", "MeshError"]


class MscapError(Exception):
    """Base class of every error mscap raises on purpose."""


class SceneError(MscapError):
    """A scene file is malformed or holds a value outside its valid range.

    Parameters
    ----------
    path
        The scene file.
    key
        Dotted key of the offending entry, e.g. ``layers[2].thickness_mm``.
    message
        What is wrong with it, including the value.
    """

    def __init__(self, path: str, key: str, message: str):
        self.path = str(path)
        self.key = key
        self.detail = message
        where = f"{self.path}: {key}: " if key else f"{self.path}: "
        super().__init__(where + message)


class GeometryError(MscapError):
    """A capacitor layout is geometrically invalid (overlap, outside the sheet, ...).

    ``capacitor`` is the index of the first capacitor involved, or ``None`` when the
    problem is the sheet itself.
    """

    def __init__(self, message: str, capacitor: int | None = None):
        self.capacitor = capacitor
        super().__init__(message)


class MeshError(MscapError):
    """Meshing failed or produced an invalid mesh."""
