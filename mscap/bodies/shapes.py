"""Generators for the pneumatic-actuator and glove scenes (paper §6, Figs. 12 and 16).

Two analytic stand-ins for bodies the paper simulates or scans, registered as glue-pose
generators (:func:`mscap.bodies.registry.register_generator`) when :mod:`mscap.bodies.registry` is
imported:

- ``pneumatic``: the sheet rolled onto a silicone cylinder, which then bulges (most on
  the thin wall over its offset cavity) and is dented from one side by a ball;
- ``hand``: the flat back of a hand whose four fingers bend at their knuckles, blended by
  linear blend skinning along and across the fingers.

Both are closed-form deformations, not simulations of the actuator or of a hand: they
give smooth, plausible surfaces whose strains the sheet can sense. Like every generator
they map the object's ``(n, 2)`` parameter points (mm) to ``(n, 3)`` positions at load
fraction ``t`` and return ``(u, v, 0)`` exactly at ``t = 0``. Conventions, ranges and
measured costs: docs/scenes.md, "Biaxial, pneumatic and glove".
"""

from __future__ import annotations

import math

import numpy as np

from mscap.bodies.registry import (ParameterError, _center, _check_wrap, _roll, _smoothstep, _turn,
                         register_generator)

__all__ = ["pneumatic", "hand", "FINGERS"]


def _check_range(key: str, value: float, low: float, high: float, why: str = "") -> None:
    if not low <= value <= high:
        raise ParameterError(key, f"must lie in [{low:g}, {high:g}]{why}, got {value!r}")


def _cos2_window(x: np.ndarray) -> np.ndarray:
    """cos²(π x / 2) on |x| < 1, 0 outside: a C1 bump of height 1 and half-width 1."""
    return np.where(np.abs(x) < 1.0, np.cos(0.5 * math.pi * np.minimum(np.abs(x), 1.0)) ** 2, 0.0)


# --------------------------------------------------------------------------- pneumatic

def pneumatic(uv: np.ndarray, t: float, *, radius_mm: float, length_mm: float,
              inflation_mm: float = 0.0, wall_ratio: float = 0.25, thin_side_deg: float = 0.0,
              indent_mm: float = 0.0, obstacle_deg: float = 90.0,
              obstacle_radius_mm: float = 20.0, obstacle_offset_mm: float = 0.0,
              center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """A sheet wrapped around a pneumatic actuator: a cylinder that inflates and is dented.

    An analytic deformation, not a simulation of the actuator. The flat object is first
    rolled isometrically onto a cylinder of radius R along v, as
    :func:`mscap.bodies.registry.cylinder` does (the line u = ``center_mm[0]`` on top at
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
    :func:`mscap.bodies.registry.cylinder`.

    A radial graph over the cylinder never folds while R + bulge − dent > 0, and its
    area grows by at least (R + bulge − dent)/R. Refused: the roll wrapping more than
    once around; ``length_mm`` ≤ 0; ``inflation_mm`` outside [0, R/2] or an axial bulge
    slope π ``inflation_mm`` / L above 1; ``wall_ratio`` outside [0, 1]; ``indent_mm``
    outside [0, R/2] or a dent slope π ``indent_mm`` / (2 ``obstacle_radius_mm``) above
    1; ``obstacle_radius_mm`` outside (0, πR/2] (the dent would reach round the back);
    angles outside [−180, 180]. Keep the sheet's strain under 30-40 %: the hoop stretch
    on the thin wall is about 1 + ``inflation_mm`` / R.
    """
    center = _center(uv, center_mm)
    s = uv[:, 0] - center[0]                            # arc length from the top line
    _check_wrap(s, radius_mm, "actuator")
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
    return _roll(uv, s, kappa) + (t * (bulge - dent))[:, None] * normal


def _check_pneumatic(radius_mm, length_mm, inflation_mm, wall_ratio, thin_side_deg,
                     indent_mm, obstacle_deg, obstacle_radius_mm) -> None:
    if not length_mm > 0:
        raise ParameterError("length_mm", f"must be > 0, got {length_mm!r}")
    _check_range("inflation_mm", inflation_mm, 0.0, 0.5 * radius_mm, " (0 to radius_mm / 2)")
    if math.pi * inflation_mm / length_mm > 1.0:
        slope = math.pi * inflation_mm / length_mm
        raise ParameterError("inflation_mm", f"inflation_mm = {inflation_mm!r} over length_mm = "
                             f"{length_mm!r} makes the bulge steeper than 45° along the axis "
                             f"(slope pi inflation / length = {slope:.3g} > 1)")
    _check_range("wall_ratio", wall_ratio, 0.0, 1.0)
    _check_range("indent_mm", indent_mm, 0.0, 0.5 * radius_mm, " (0 to radius_mm / 2)")
    _check_range("obstacle_radius_mm", obstacle_radius_mm, 1e-9, 0.5 * math.pi * radius_mm,
                 " (above 0, at most a quarter of the circumference)")
    slope = 0.5 * math.pi * indent_mm / obstacle_radius_mm
    if slope > 1.0:
        raise ParameterError("indent_mm", f"indent_mm = {indent_mm!r} over obstacle_radius_mm = "
                             f"{obstacle_radius_mm!r} makes the dent steeper than 45° (slope "
                             f"pi indent / (2 obstacle_radius) = {slope:.3g} > 1)")
    for key, angle in (("thin_side_deg", thin_side_deg), ("obstacle_deg", obstacle_deg)):
        _check_range(key, angle, -180.0, 180.0, " degrees")


# --------------------------------------------------------------------------- hand

#: The fingers of :func:`hand`, from −u to +u (a right hand seen from its back).
FINGERS = ("index", "middle", "ring", "little")

#: Angles beyond which linear blend skinning stops resembling a bend, and the least area
#: ratio we accept (as for :func:`mscap.bodies.registry.wrist`).
_HAND_MAX_DEG = 90.0
_HAND_MAX_SPREAD_DEG = 30.0
_HAND_MIN_AREA_RATIO = 0.25


def hand(uv: np.ndarray, t: float, *, knuckle_mm: float, pitch_mm: float = 19.0,
         joint_depth_mm: float = 8.0, blend_mm: float = 36.0, web_mm: float = 15.0,
         index_deg: float = 0.0, middle_deg: float = 0.0, ring_deg: float = 0.0,
         little_deg: float = 0.0, spread_deg: float = 0.0,
         center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """A sheet on the back of a hand whose four fingers bend at their knuckles.

    An analytic stand-in for a rigged hand, not anatomy. The object is the flat back of
    a right hand seen from its back (+z, where the sheet's top faces), the fingers
    pointing towards +v: index, middle, ring and little finger side by side at
    u_i = u_c + (i − 1.5) ``pitch_mm`` (u_c = ``center_mm[0]``, between the middle and
    ring fingers). Each finger is a bone that turns about its knuckle (MCP joint)
    J_i = (u_i, ``knuckle_mm``, −``joint_depth_mm``), below the skin, by

        H_i(t) = R_z(t α_i) R_x(−t θ_i)

    θ_i = ``index_deg``, ... (flexion about the knuckle axis, the u direction: > 0 bends
    the finger towards −z, into the palm, and stretches the sheet over the knuckle),
    then α_i = ``spread_deg`` (1.5 − i)/1.5 about the back's normal through the
    knuckle (spread > 0 fans the fingers out: index towards −u, little towards +u).
    The back of the hand is the fixed bone. Linear blend skinning: a point p goes to

        p + Σ_i w_i(u, v) (H_i − I)(p − J_i),   w_i = a(v) c_i(u)

    with a the C1 cubic step 3s² − 2s³ from 0 to 1 over ``blend_mm`` centred on the
    knuckle line, and c_i a partition of unity across the fingers: 1 on finger i's core,
    changing by the same C1 step over ``web_mm`` centred midway between neighbouring
    fingers (the index and little finger extend to the object's edges). So the back of
    the hand (v ≤ knuckle − blend/2) stays, and a finger's core beyond knuckle + blend/2
    (|u − u_i| ≤ (pitch − web)/2) turns rigidly by H_i about J_i. The interphalangeal
    joints are not modelled (a sheet on the back of the hand ends before them).
    At t = 0 the result is (u, v, 0) exactly.

    Limits. A flexion θ stretches the back over the knuckle by about
    ``joint_depth_mm`` θ over ``blend_mm`` (×1.5 at the cubic step's steepest); fingers
    bent by different angles shear the web between them (a drop of about ℓ Δθ at a
    distance ℓ beyond the knuckle over ``web_mm``). Refused: flexions beyond ±90°,
    spreads beyond ±30°, ``pitch_mm``, ``blend_mm`` ≤ 0, ``joint_depth_mm`` < 0,
    ``web_mm`` outside (0, ``pitch_mm``], and settings that compress the surface
    anywhere below a quarter of its area at t = 1 (or fold it; the parameter named is
    the angle largest in magnitude).
    """
    angles = _check_hand(pitch_mm, joint_depth_mm, blend_mm, web_mm,
                         (index_deg, middle_deg, ring_deg, little_deg), spread_deg)
    axis_u = _center(uv, center_mm)[0]
    positions, ratio = _hand_bend(uv, t, axis_u, knuckle_mm, pitch_mm, joint_depth_mm,
                                  blend_mm, web_mm, angles, spread_deg, need_ratio=t == 1.0)
    if ratio is not None and ratio.min() < _HAND_MIN_AREA_RATIO:
        i = int(np.argmin(ratio))
        values = dict(zip([f"{f}_deg" for f in FINGERS] + ["spread_deg"],
                          list(angles) + [spread_deg]))
        key = max(values, key=lambda k: abs(values[k]))
        what = (f"compress the surface to {ratio[i]:.3g} of its area" if ratio[i] > 0 else
                f"fold the surface over (signed area ratio {ratio[i]:.3g})")
        raise ParameterError(key, f"finger angles {values} over blend_mm = {blend_mm!r}, "
                             f"web_mm = {web_mm!r} {what} at uv = {uv[i].round(3).tolist()} mm "
                             f"(least area ratio {_HAND_MIN_AREA_RATIO:g}); reduce the angles "
                             "or their differences between neighbouring fingers")
    return positions


def _check_hand(pitch_mm, joint_depth_mm, blend_mm, web_mm, flexions, spread_deg):
    for key, value in (("pitch_mm", pitch_mm), ("blend_mm", blend_mm)):
        if not value > 0:
            raise ParameterError(key, f"must be > 0, got {value!r}")
    if not joint_depth_mm >= 0:
        raise ParameterError("joint_depth_mm", f"must be >= 0, got {joint_depth_mm!r}")
    if not 0 < web_mm <= pitch_mm:
        raise ParameterError("web_mm", f"must lie in (0, pitch_mm = {pitch_mm!r}] (the fingers "
                             f"need a core that turns rigidly), got {web_mm!r}")
    for finger, angle in zip(FINGERS, flexions):
        _check_range(f"{finger}_deg", angle, -_HAND_MAX_DEG, _HAND_MAX_DEG,
                     " degrees (linear blend skinning collapses beyond)")
    _check_range("spread_deg", spread_deg, -_HAND_MAX_SPREAD_DEG, _HAND_MAX_SPREAD_DEG, " degrees")
    return tuple(float(a) for a in flexions)


def _finger_weights(u: np.ndarray, centres: np.ndarray, pitch_mm: float, web_mm: float):
    """Partition of unity across the fingers, ``(4, n)``, and its derivative in u."""
    # Step k rises from 0 to 1 across the boundary between fingers k and k + 1.
    steps, slopes = zip(*(_smoothstep((u - (c + 0.5 * pitch_mm)) / web_mm + 0.5)
                          for c in centres[:-1]))
    up = np.vstack([np.ones_like(u), *steps, np.zeros_like(u)])           # (5, n)
    d_up = np.vstack([np.zeros_like(u), *slopes, np.zeros_like(u)]) / web_mm
    return up[:-1] - up[1:], d_up[:-1] - d_up[1:]


def _hand_bend(uv, t, axis_u, knuckle_mm, pitch_mm, joint_depth_mm, blend_mm, web_mm,
               flexions, spread_deg, need_ratio):
    """:func:`hand`'s positions and, if ``need_ratio``, its signed area ratio per point:
    |∂p/∂u × ∂p/∂v| with the sign of the blended normal."""
    n = len(uv)
    flat = np.column_stack([uv, np.zeros(n)])
    centres = axis_u + (np.arange(4) - 1.5) * pitch_mm
    along, d_along = _smoothstep((uv[:, 1] - knuckle_mm) / blend_mm + 0.5)
    across, d_across = _finger_weights(uv[:, 0], centres, pitch_mm, web_mm)
    positions = flat.copy()
    d_u = np.tile([1.0, 0.0, 0.0], (n, 1))
    d_v = np.tile([0.0, 1.0, 0.0], (n, 1))
    blended = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for i, (centre, flexion) in enumerate(zip(centres, flexions)):
        spread = spread_deg * (1.5 - i) / 1.5
        flex = _turn(np.array([1.0, 0.0, 0.0]), -t * math.radians(flexion))
        fan = _turn(np.array([0.0, 0.0, 1.0]), t * math.radians(spread))
        turn = fan @ flex + fan + flex              # H − I = (A−I)(B−I) + (A−I) + (B−I)
        joint = np.array([centre, knuckle_mm, -joint_depth_mm])
        offset = (flat - joint) @ turn.T            # (H_i − I)(p − J_i)
        w = along * across[i]
        positions += w[:, None] * offset
        if need_ratio:
            d_u += (along * d_across[i])[:, None] * offset + w[:, None] * turn[:, 0]
            d_v += (d_along / blend_mm * across[i])[:, None] * offset + w[:, None] * turn[:, 1]
            blended += w[:, None, None] * turn
    if not need_ratio:
        return positions, None
    cross = np.cross(d_u, d_v)
    flipped = np.einsum("ni,ni->n", cross, blended[:, :, 2]) < 0
    return positions, np.where(flipped, -1.0, 1.0) * np.linalg.norm(cross, axis=1)


register_generator("pneumatic", pneumatic)
register_generator("hand", hand)
