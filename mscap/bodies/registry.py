"""The table of surface generators for glued poses: named functions that deform a flat object.

A generator ``f(uv, t, *, parameters) -> (n, 3)`` maps an object's ``(n, 2)`` parameter
coordinates (mm) to vertex positions at load fraction ``t``, with ``f(uv, 0)`` the flat
sheet ``(u, v, 0)``; its keyword-only parameters are the glue pose's scene keys.
:data:`GENERATORS` holds them by name: ``cylinder``, ``dome``, ``wrist``, ``cantilever``
(:mod:`mscap.bodies.basic`), ``pneumatic`` (:mod:`mscap.bodies.pneumatic`), ``hand``
(:mod:`mscap.bodies.hand`), and whatever :func:`register_generator` adds. The body
modules know nothing of this table: it imports them and registers them below.
:mod:`mscap.bodies.glue` reads and checks their parameters.
"""

from __future__ import annotations

import inspect
from typing import Callable

import numpy as np

from mscap.bodies.basic import cantilever, cylinder, dome, wrist
from mscap.bodies.hand import hand
from mscap.bodies.pneumatic import pneumatic

__all__ = ["GENERATORS", "register_generator", "generator_parameters", "parameter_kind"]

#: Keys a glue pose reads itself; generator parameters may not use them.
_POSE_KEYS = ("name", "kind", "object", "origin_mm", "rotation_deg", "surface", "align")


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
        no default); it raises :class:`mscap.bodies.kinematics.ParameterError` for
        out-of-range values.
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
register_generator("wrist", wrist)
register_generator("cantilever", cantilever)
register_generator("pneumatic", pneumatic)
register_generator("hand", hand)
