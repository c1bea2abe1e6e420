"""The glove generator (paper §6, Fig. 16): the flat back of a hand whose four fingers
bend at their knuckles, blended by linear blend skinning along and across the fingers.

A closed-form deformation, not a simulation of a hand: a smooth, plausible surface whose
strains the sheet can sense. Like every generator it maps the object's ``(n, 2)``
parameter points (mm) to ``(n, 3)`` positions at load fraction ``t`` and returns
``(u, v, 0)`` exactly at ``t = 0``; :mod:`mscap.bodies.registry` names it ``hand``.
Conventions, ranges and measured costs: docs/scenes.md, "Biaxial, pneumatic and glove".
"""

from __future__ import annotations

import math

import numpy as np

from mscap.bodies.kinematics import ParameterError, center_of, check_range, rotation_minus_identity, smoothstep

__all__ = ["hand", "FINGERS"]


#: The fingers of :func:`hand`, from −u to +u (a right hand seen from its back).
FINGERS = ("index", "middle", "ring", "little")

#: Angles beyond which linear blend skinning stops resembling a bend, and the least area
#: ratio we accept (as for :func:`mscap.bodies.basic.wrist`).
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
    axis_u = center_of(uv, center_mm)[0]
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
        check_range(f"{finger}_deg", angle, -_HAND_MAX_DEG, _HAND_MAX_DEG,
                     " degrees (linear blend skinning collapses beyond)")
    check_range("spread_deg", spread_deg, -_HAND_MAX_SPREAD_DEG, _HAND_MAX_SPREAD_DEG, " degrees")
    return tuple(float(a) for a in flexions)


def _finger_weights(u: np.ndarray, centres: np.ndarray, pitch_mm: float, web_mm: float):
    """Partition of unity across the fingers, ``(4, n)``, and its derivative in u."""
    # Step k rises from 0 to 1 across the boundary between fingers k and k + 1.
    steps, slopes = zip(*(smoothstep((u - (c + 0.5 * pitch_mm)) / web_mm + 0.5)
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
    along, d_along = smoothstep((uv[:, 1] - knuckle_mm) / blend_mm + 0.5)
    across, d_across = _finger_weights(uv[:, 0], centres, pitch_mm, web_mm)
    positions = flat.copy()
    d_u = np.tile([1.0, 0.0, 0.0], (n, 1))
    d_v = np.tile([0.0, 1.0, 0.0], (n, 1))
    blended = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for i, (centre, flexion) in enumerate(zip(centres, flexions)):
        spread = spread_deg * (1.5 - i) / 1.5
        flex = rotation_minus_identity(np.array([1.0, 0.0, 0.0]), -t * math.radians(flexion))
        fan = rotation_minus_identity(np.array([0.0, 0.0, 1.0]), t * math.radians(spread))
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
