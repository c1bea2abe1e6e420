"""Shared kinematics of the surface generators: the roll onto a cylinder, rotations,
the C1 step, and the parameter checks (:class:`ParameterError`).

Every generator body (:mod:`mscap.bodies.basic`, :mod:`mscap.bodies.pneumatic`,
:mod:`mscap.bodies.hand`) builds on these; none of them imports the registry.
"""

from __future__ import annotations

import math

import numpy as np
from mscap.errors import ParameterError

__all__ = ["ParameterError", "center_of", "check_wrap", "check_range", "roll", "rotation_minus_identity",
           "smoothstep"]


def center_of(uv: np.ndarray, center_mm: tuple[float, float] | None) -> np.ndarray:
    """``center_mm``, or the centre of the bounding box of ``uv``."""
    if center_mm is None:
        return 0.5 * (uv.min(axis=0) + uv.max(axis=0))
    return np.asarray(center_mm, dtype=float)


def check_wrap(s: np.ndarray, radius_mm: float, surface: str) -> None:
    """``radius_mm`` > 0 and the arc lengths ``s`` from the contact line wrap at most
    once around."""
    if not radius_mm > 0:
        raise ParameterError("radius_mm", f"must be > 0, got {radius_mm!r}")
    reach = float(np.abs(s).max())
    if reach > math.pi * radius_mm:
        raise ParameterError("radius_mm", f"radius_mm = {radius_mm!r} wraps the object "
                             f"({reach:g} mm either side of the axis) more than once around "
                             f"the {surface}; need radius_mm >= {reach / math.pi:.4g}")


def check_range(key: str, value: float, low: float, high: float, why: str = "") -> None:
    """``low <= value <= high``, else a :class:`ParameterError` naming ``key`` (``why``
    is appended to the range)."""
    if not low <= value <= high:
        raise ParameterError(key, f"must lie in [{low:g}, {high:g}]{why}, got {value!r}")


def roll(uv: np.ndarray, s: np.ndarray, kappa: float) -> np.ndarray:
    """Roll the flat object with curvature ``kappa`` about an axis along v, below the
    contact line (u at arc length ``s`` = 0); ``(u, v, 0)`` exactly when ``kappa`` = 0."""
    # sin(κs)/κ − s and (1 − cos κs)/κ written with sinc: exact and finite as κ → 0.
    x = uv[:, 0] + s * (np.sinc(kappa * s / math.pi) - 1.0)
    z = -0.5 * kappa * s**2 * np.sinc(kappa * s / (2 * math.pi)) ** 2
    return np.column_stack([x, uv[:, 1], z])


def rotation_minus_identity(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the unit ``axis``, minus the identity: exactly
    zero at angle 0 (Rodrigues: sin a [k]× + (1 − cos a) [k]×²)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return math.sin(angle) * k + 2.0 * math.sin(0.5 * angle) ** 2 * (k @ k)


def smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The C1 cubic step 3x² − 2x³ on [0, 1] (0 below, 1 above) and its derivative."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)
