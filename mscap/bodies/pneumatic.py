"""The pneumatic-actuator generator (paper §6, Fig. 12): the sheet rolled onto a silicone
cylinder, which then bulges (most on the thin wall over its offset cavity) and is dented
from one side by a ball.

A closed-form deformation, not a simulation of the actuator: a smooth, plausible surface
whose strains the sheet can sense. Like every generator it maps the object's ``(n, 2)``
parameter points (mm) to ``(n, 3)`` positions at load fraction ``t`` and returns
``(u, v, 0)`` exactly at ``t = 0``; :mod:`mscap.bodies.registry` names it ``pneumatic``.
Conventions, ranges and measured costs: docs/scenes.md, "Biaxial, pneumatic and glove".
"""

from __future__ import annotations

import math

import numpy as np

from mscap.bodies.kinematics import ParameterError, center_of, check_range, check_wrap, roll

__all__ = ["pneumatic"]


def _cos2_window(x: np.ndarray) -> np.ndarray:
    """cos²(π x / 2) on |x| < 1, 0 outside: a C1 bump of height 1 and half-width 1."""
    return np.where(np.abs(x) < 1.0, np.cos(0.5 * math.pi * np.minimum(np.abs(x), 1.0)) ** 2, 0.0)


def pneumatic(uv: np.ndarray, t: float, *, radius_mm: float, length_mm: float,
              inflation_mm: float = 0.0, wall_ratio: float = 0.25, thin_side_deg: float = 0.0,
              indent_mm: float = 0.0, obstacle_deg: float = 90.0,
              obstacle_radius_mm: float = 20.0, obstacle_offset_mm: float = 0.0,
              center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """A sheet wrapped around a pneumatic actuator: a cylinder that inflates and is dented.

    An analytic deformation, not a simulation of the actuator. The flat object is first
    rolled isometrically onto a cylinder of radius R along v, as
    :func:`mscap.bodies.basic.cylinder` does (the line u = ``center_mm[0]`` on top at
    z = 0, curvature t/R, the axis at z = −R at t = 1); a point sits at the angle
    φ = (u − u_c)/R from the top, towards +u. Then every point moves along the roll's
    outward normal by t·(bulge − dent), so the hoop stretch grows like t²:

    - bulge = ``inflation_mm`` · (ρ + (1 − ρ) cos²((φ − φ_thin)/2)) · cos²(π (v − v_c)/L)
      for |v − v_c| < L/2 (0 beyond): the radial growth of the inflated actuator, largest
      (``inflation_mm``) on the thin wall over the offset cavity, at φ_thin =
      ``thin_side_deg``, ρ = ``wall_ratio`` times that on the thick wall opposite, and
      smooth along the axis, vanishing at the capped ends v_c ± L/2 (L = ``length_mm``,
      v_c = ``center_mm[1]``);
    - dent = ``indent_mm`` · cos²(π r / 2) for r < 1 (0 beyond), r the distance on the
      rest cylinder from the ball's contact point (angle ``obstacle_deg``, axial position
      v_c + ``obstacle_offset_mm``) in units of ``obstacle_radius_mm``: a ball pressing
      the surface in from one side. ``obstacle_deg`` = 90° is the +u side (a ball on the
      right pushes the actuator to the left), −90° the −u side.

    The actuator's axis stays straight: the bending an offset cavity causes, and its
    deflection by the ball, are left out. At t = 0 the result is (u, v, 0) exactly, and
    at ``inflation_mm`` = ``indent_mm`` = 0 exactly the roll of
    :func:`mscap.bodies.basic.cylinder`.

    A radial graph over the cylinder never folds while R + bulge − dent > 0, and its
    area grows by at least (R + bulge − dent)/R. Refused: the roll wrapping more than
    once around; ``length_mm`` ≤ 0; ``inflation_mm`` outside [0, R/2] or an axial bulge
    slope π ``inflation_mm`` / L above 1; ``wall_ratio`` outside [0, 1]; ``indent_mm``
    outside [0, R/2] or a dent slope π ``indent_mm`` / (2 ``obstacle_radius_mm``) above
    1; ``obstacle_radius_mm`` outside (0, πR/2] (the dent would reach round the back);
    angles outside [−180, 180]. Keep the sheet's strain under 30-40 %: the hoop stretch
    on the thin wall is about 1 + ``inflation_mm`` / R.
    """
    center = center_of(uv, center_mm)
    s = uv[:, 0] - center[0]                            # arc length from the top line
    check_wrap(s, radius_mm, "actuator")
    _check_pneumatic(radius_mm, length_mm, inflation_mm, wall_ratio, thin_side_deg,
                     indent_mm, obstacle_deg, obstacle_radius_mm)
    phi = s / radius_mm
    v = uv[:, 1] - center[1]
    wall = wall_ratio + (1.0 - wall_ratio) * np.cos(0.5 * (phi - math.radians(thin_side_deg))) ** 2
    bulge = inflation_mm * wall * _cos2_window(2.0 * v / length_mm)
    around = np.angle(np.exp(1j * (phi - math.radians(obstacle_deg))))   # wrapped to (−π, π]
    r = np.hypot(radius_mm * around, v - obstacle_offset_mm) / obstacle_radius_mm
    dent = indent_mm * _cos2_window(r)
    kappa = t / radius_mm
    normal = np.column_stack([np.sin(kappa * s), np.zeros_like(s), np.cos(kappa * s)])
    return roll(uv, s, kappa) + (t * (bulge - dent))[:, None] * normal


def _check_pneumatic(radius_mm, length_mm, inflation_mm, wall_ratio, thin_side_deg,
                     indent_mm, obstacle_deg, obstacle_radius_mm) -> None:
    if not length_mm > 0:
        raise ParameterError("length_mm", f"must be > 0, got {length_mm!r}")
    check_range("inflation_mm", inflation_mm, 0.0, 0.5 * radius_mm, " (0 to radius_mm / 2)")
    if math.pi * inflation_mm / length_mm > 1.0:
        slope = math.pi * inflation_mm / length_mm
        raise ParameterError("inflation_mm", f"inflation_mm = {inflation_mm!r} over length_mm = "
                             f"{length_mm!r} makes the bulge steeper than 45° along the axis "
                             f"(slope pi inflation / length = {slope:.3g} > 1)")
    check_range("wall_ratio", wall_ratio, 0.0, 1.0)
    check_range("indent_mm", indent_mm, 0.0, 0.5 * radius_mm, " (0 to radius_mm / 2)")
    check_range("obstacle_radius_mm", obstacle_radius_mm, 1e-9, 0.5 * math.pi * radius_mm,
                 " (above 0, at most a quarter of the circumference)")
    slope = 0.5 * math.pi * indent_mm / obstacle_radius_mm
    if slope > 1.0:
        raise ParameterError("indent_mm", f"indent_mm = {indent_mm!r} over obstacle_radius_mm = "
                             f"{obstacle_radius_mm!r} makes the dent steeper than 45° (slope "
                             f"pi indent / (2 obstacle_radius) = {slope:.3g} > 1)")
    for key, angle in (("thin_side_deg", thin_side_deg), ("obstacle_deg", obstacle_deg)):
        check_range(key, angle, -180.0, 180.0, " degrees")
