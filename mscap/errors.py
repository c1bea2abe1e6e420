"""Every error type mscap raises, one per stage, all :class:`MscapError` (the command
line prints them as one line and exits 2) except :class:`ParameterError`, the body
generators' signal that the scene's glue reader turns into a :class:`SceneError`.

Library code raises these (never ``sys.exit`` or ``assert``) with a message that names
the file, the field and the offending value, so that the command line can print one clean
line instead of a traceback.
"""

from __future__ import annotations

__all__ = ["MscapError", "SceneError", "GeometryError", "MeshError", "LinearSolveError", "ElasticError",
           "AdjointError", "ElectrostaticError", "ReadoutError", "DesignError", "StoreError", "StoreFullError",
           "CalibrationError", "FabricationError", "ParameterError"]


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


class LinearSolveError(MscapError):
    """A PETSc linear solve failed (factorisation breakdown, divergence)."""


class ElasticError(MscapError):
    """The elastic problem is ill-posed or its solution failed (names pose, load step and
    residual)."""


class AdjointError(MscapError):
    """A gradient was asked of a simulation that cannot give it."""


class ElectrostaticError(MscapError):
    """The electrostatic problem is ill-posed (missing plates, touching conductors,
    inverted tets) or its solve failed."""


class InvertedMeshError(ElectrostaticError):
    """Dielectric tets of the electrostatic mesh are inverted or degenerate at the deformed
    positions: a limit of the mesh (a sliver across the elastic mesh's element faces), not
    of the design; the optimiser remeshes when it is what holds a step back."""


class ReadoutError(MscapError):
    """An array, a pattern set or readings that cannot give the capacitances."""


class DesignError(MscapError):
    """A design evaluation produced a non-finite value or cannot be carried out."""


class StoreError(MscapError):
    """A results file cannot be used: wrong scene, not an mscap file, unknown run."""


class StoreFullError(StoreError):
    """A results file cannot take the next write: the disk, a quota or the process's
    file-size limit refuses the room it needs. Nothing of the file was touched."""


class CalibrationError(MscapError):
    """A calibration cannot run: no ``[calibration]``, a cache of another scene, ..."""


class ParameterError(ValueError):
    """A generator parameter is out of range; ``parameter`` names the scene key."""

    def __init__(self, parameter: str, message: str):
        self.parameter = parameter
        super().__init__(message)


class FabricationError(MscapError):
    """A design cannot be routed or written under its scene's ``[fabrication]`` rules
    (a blocked capacitor, plates closer than the clearance, pads that do not fit)."""
