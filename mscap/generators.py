"""Surface generators for glued poses: named functions that deform a flat object.

A generator ``f(uv, t, *, parameters) -> (n, 3)`` maps an object's ``(n, 2)`` parameter
coordinates (mm) to vertex positions at load fraction ``t``, with ``f(uv, 0)`` the flat
sheet ``(u, v, 0)``; its keyword-only parameters are the glue pose's scene keys.
:data:`GENERATORS` holds them by name (``cylinder``, ``dome``, and whatever
:func:`register_generator` adds); :mod:`mscap.glue` reads and checks their parameters.
"""

from __future__ import annotations

import inspect
import math
from typing import Callable

import numpy as np

__all__ = [
    "GENERATORS", "register_generator", "ParameterError", "cylinder", "dome",
    "generator_parameters", "parameter_kind",
]

#: Keys a glue pose reads itself; generator parameters may not use them.
_POSE_KEYS = ("name", "kind", "object", "origin_mm", "rotation_deg", "surface", "align")


class ParameterError(ValueError):
    """A generator parameter is out of range; ``parameter`` names the scene key."""

    def __init__(self, parameter: str, message: str):
        self.parameter = parameter
        super().__init__(message)


def _center(uv: np.ndarray, center_mm: tuple[float, float] | None) -> np.ndarray:
    """``center_mm``, or the centre of the bounding box of ``uv``."""
    if center_mm is None:
        return 0.5 * (uv.min(axis=0) + uv.max(axis=0))
    return np.asarray(center_mm, dtype=float)


def cylinder(uv: np.ndarray, t: float, *, radius_mm: float,
             center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """Roll the flat object isometrically onto a cylinder with its axis along v.

    The line u = ``center_mm[0]`` stays in place; the surface bends down (towards −z) on
    both sides, so the sheet lies on the outside of the cylinder, whose axis is at
    z = −R/t. ``t`` scales the curvature 1/R; at t = 0 the result is (u, v, 0).
    """
    if not radius_mm > 0:
        raise ParameterError("radius_mm", f"must be > 0, got {radius_mm!r}")
    axis_u = _center(uv, center_mm)[0]
    s = uv[:, 0] - axis_u                               # arc length from the contact line
    reach = float(np.abs(s).max())
    if reach > math.pi * radius_mm:
        raise ParameterError("radius_mm", f"radius_mm = {radius_mm!r} wraps the object "
                             f"({reach:g} mm either side of the axis) more than once around "
                             f"the cylinder; need radius_mm >= {reach / math.pi:.4g}")
    kappa = t / radius_mm
    # sin(κs)/κ and (1 − cos κs)/κ written with sinc: exact and finite as κ → 0.
    x = axis_u + s * np.sinc(kappa * s / math.pi)
    z = -0.5 * kappa * s**2 * np.sinc(kappa * s / (2 * math.pi)) ** 2
    return np.column_stack([x, uv[:, 1], z])


def dome(uv: np.ndarray, t: float, *, radius_mm: float,
         center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """Lift the flat object vertically onto a sphere of radius R (a spherical cap).

    Not isometric: a point at distance r from ``center_mm`` keeps (u, v) and rises to the
    sphere touching z = 0 at the centre from below, so radial lines stretch by
    1/cos(asin(r/R)). ``t`` scales the curvature 1/R.
    """
    if not radius_mm > 0:
        raise ParameterError("radius_mm", f"must be > 0, got {radius_mm!r}")
    r2 = np.sum((uv - _center(uv, center_mm)) ** 2, axis=1)
    reach = math.sqrt(float(r2.max()))
    if reach >= radius_mm:
        raise ParameterError("radius_mm", f"radius_mm = {radius_mm!r} is not larger than the "
                             f"object's largest distance from the centre ({reach:g} mm): "
                             "the cap cannot cover it")
    kappa = t / radius_mm
    z = -kappa * r2 / (1.0 + np.sqrt(1.0 - kappa**2 * r2))     # R − sqrt(R² − r²), scaled
    return np.column_stack([uv, z])


#: Named surface generators: ``f(uv, t, *, parameters) -> (n, 3)`` vertex positions.
GENERATORS: dict[str, Callable[..., np.ndarray]] = {}


def parameter_kind(parameter: inspect.Parameter) -> str:
    """``"point"`` for a parameter annotated ``tuple[float, float]``, ``"float"`` for
    ``float``; ``TypeError`` for anything else."""
    annotation = str(parameter.annotation)
    if "tuple" in annotation:
        return "point"
    if "float" in annotation:
        return "float"
    raise TypeError(f"generator parameter {parameter.name!r} must be annotated float or "
                    f"tuple[float, float], got {annotation!r}")


def register_generator(name: str, function: Callable[..., np.ndarray]) -> None:
    """Make ``function`` available as ``generator = "name"`` in scenes.

    Parameters
    ----------
    name
        The scene's name for it.
    function
        ``function(uv, t, *, p1: float, p2: tuple[float, float] | None = None, ...)``
        returns the ``(n, 3)`` vertex positions of the object at load fraction ``t``
        from its ``(n, 2)`` parameter coordinates; ``t = 0`` must give ``(u, v, 0)``.
        Its keyword-only parameters are the pose's scene keys (required when they have
        no default); it raises :class:`ParameterError` for out-of-range values.
    """
    if name in GENERATORS:
        raise ValueError(f"a generator named {name!r} is already registered")
    positional = [p for p in inspect.signature(function).parameters.values()
                  if p.kind is not inspect.Parameter.KEYWORD_ONLY]
    if len(positional) != 2:
        raise TypeError(f"generator {name!r} must take (uv, t) positionally, then keywords")
    for parameter in generator_parameters(function):
        parameter_kind(parameter)
        if parameter.name in _POSE_KEYS:
            raise ValueError(f"generator {name!r}: parameter name {parameter.name!r} is a "
                             "glue-pose key")
    GENERATORS[name] = function


def generator_parameters(function) -> list[inspect.Parameter]:
    """The keyword-only parameters of a generator: its pose's scene keys."""
    return [p for p in inspect.signature(function).parameters.values()
            if p.kind is inspect.Parameter.KEYWORD_ONLY]


register_generator("cylinder", cylinder)
register_generator("dome", dome)
