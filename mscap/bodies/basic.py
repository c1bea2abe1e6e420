"""The simple generators: a cylinder, a dome, a wrist and a cantilever (joystick).

Each maps an object's ``(n, 2)`` parameter coordinates (mm) to ``(n, 3)`` positions at
load fraction ``t``, ``(u, v, 0)`` exactly at ``t = 0``; :mod:`mscap.bodies.registry`
names them for scenes. Conventions, ranges and costs: docs/glue.md and docs/scenes.md,
"Wrist and joystick".
"""

from __future__ import annotations

import math

import numpy as np

from mscap.bodies.kinematics import (ParameterError, center_of, check_wrap, roll, rotation_minus_identity,
                                     smoothstep)

__all__ = ["cylinder", "dome", "wrist", "cantilever"]


def cylinder(uv: np.ndarray, t: float, *, radius_mm: float,
             center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """Roll the flat object isometrically onto a cylinder with its axis along v.

    The line u = ``center_mm[0]`` stays in place; the surface bends down (towards −z) on
    both sides, so the sheet lies on the outside of the cylinder, whose axis is at
    z = −R/t. ``t`` scales the curvature 1/R; at t = 0 the result is (u, v, 0).
    """
    s = uv[:, 0] - center_of(uv, center_mm)[0]           # arc length from the contact line
    check_wrap(s, radius_mm, "cylinder")
    return roll(uv, s, t / radius_mm)


def dome(uv: np.ndarray, t: float, *, radius_mm: float,
         center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """Lift the flat object vertically onto a sphere of radius R (a spherical cap).

    Not isometric: a point at distance r from ``center_mm`` keeps (u, v) and rises to the
    sphere touching z = 0 at the centre from below, so radial lines stretch by
    1/cos(asin(r/R)). ``t`` scales the curvature 1/R.
    """
    if not radius_mm > 0:
        raise ParameterError("radius_mm", f"must be > 0, got {radius_mm!r}")
    r2 = np.sum((uv - center_of(uv, center_mm)) ** 2, axis=1)
    reach = math.sqrt(float(r2.max()))
    if reach >= radius_mm:
        raise ParameterError("radius_mm", f"radius_mm = {radius_mm!r} is not larger than the "
                             f"object's largest distance from the centre ({reach:g} mm): "
                             "the cap cannot cover it")
    kappa = t / radius_mm
    z = -kappa * r2 / (1.0 + np.sqrt(1.0 - kappa**2 * r2))     # R − sqrt(R² − r²), scaled
    return np.column_stack([uv, z])


#: Angles beyond which linear blend skinning stops resembling a bend (its blended
#: rotation collapses towards a projection), and the least area ratio we accept.
_WRIST_MAX_DEG = 90.0
_WRIST_MIN_AREA_RATIO = 0.25


def wrist(uv: np.ndarray, t: float, *, radius_mm: float, joint_mm: float,
          flexion_deg: float = 0.0, deviation_deg: float = 0.0, blend_mm: float = 60.0,
          center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """A sheet on the back of a wrist: the object rolled onto a tube, the tube bent at a joint.

    First the flat object is rolled isometrically onto a tube of radius R along v, as
    :func:`cylinder` does (the line u = ``center_mm[0]`` on top at z = 0, curvature t/R,
    the axis at z = −R at t = 1). Then two bones bend the tube by linear blend skinning
    about the joint, the fixed point (u_c, ``joint_mm``, −R) on the final axis: the
    forearm (v below the joint) stays put, the hand (v above) turns by

        H(t) = R_x(−t ``flexion_deg``) R_z(−t ``deviation_deg``)

    (flexion about x, then deviation about the hand's own, flexed dorsal axis; the two
    commute to first order). ``flexion_deg`` > 0 bends
    the hand towards −z, away from the sheet (palmar flexion with the sheet on the back
    of the wrist: the sheet stretches); < 0 is extension (the sheet is compressed).
    ``deviation_deg`` > 0 turns the hand towards +u (radial or ulnar deviation depending
    on the side). A point p of the tube goes to p + w(v) (H(t) − I)(p − joint), where the
    skinning weight w is the C1 cubic step from 0 to 1 over ``blend_mm`` centred at the
    joint. At t = 0 the result is (u, v, 0) exactly.

    Limits. Linear blending shrinks the tube where w ≈ 1/2 (by cos(a/2) for a bend by a;
    the "candy-wrapper" volume loss), and a bend by a over a blend b compresses the
    inside of the bend, at distance ≈ R from the joint, by about 1.5 R a / b at its
    steepest (the cubic step's slope is 1.5/b). It is a smooth stand-in for a rigged
    wrist, not anatomy. Angles beyond ±90° are refused, as are settings that compress
    the surface anywhere below a quarter of its area at t = 1 (it would fold); keep the
    compression of the sheet under 30-40 % (docs/scenes.md lists the ranges we use).
    """
    axis_u = center_of(uv, center_mm)[0]
    s = uv[:, 0] - axis_u                               # arc length from the top line
    check_wrap(s, radius_mm, "tube")
    if not blend_mm > 0:
        raise ParameterError("blend_mm", f"must be > 0, got {blend_mm!r}")
    for key, angle in (("flexion_deg", flexion_deg), ("deviation_deg", deviation_deg)):
        if not abs(angle) <= _WRIST_MAX_DEG:
            raise ParameterError(key, f"must lie in [-{_WRIST_MAX_DEG:g}, {_WRIST_MAX_DEG:g}] "
                                 f"degrees (linear blend skinning collapses beyond), got {angle!r}")
    joint = np.array([axis_u, joint_mm, -radius_mm])
    positions, ratio = _wrist_bend(uv, s, t, radius_mm, joint, flexion_deg, deviation_deg,
                                   blend_mm, need_ratio=t == 1.0)
    if ratio is not None and ratio.min() < _WRIST_MIN_AREA_RATIO:
        i = int(np.argmin(ratio))
        key = "flexion_deg" if abs(flexion_deg) >= abs(deviation_deg) else "deviation_deg"
        what = (f"compress the surface to {ratio[i]:.3g} of its area" if ratio[i] > 0 else
                f"fold the surface over (signed area ratio {ratio[i]:.3g})")
        raise ParameterError(key, f"flexion_deg = {flexion_deg!r}, deviation_deg = "
                             f"{deviation_deg!r} over blend_mm = {blend_mm!r} {what} at uv = "
                             f"{uv[i].round(3).tolist()} mm (least area ratio "
                             f"{_WRIST_MIN_AREA_RATIO:g}); reduce the angles or lengthen blend_mm")
    return positions


def _wrist_bend(uv, s, t, radius_mm, joint, flexion_deg, deviation_deg, blend_mm, need_ratio):
    """:func:`wrist`'s positions and, if ``need_ratio``, its signed area ratio per point:
    |∂p/∂u × ∂p/∂v| (the roll is isometric) with the sign of the blended normal."""
    kappa = t / radius_mm
    rolled = roll(uv, s, kappa)
    flex = rotation_minus_identity(np.array([1.0, 0.0, 0.0]), -t * math.radians(flexion_deg))
    deviate = rotation_minus_identity(np.array([0.0, 0.0, 1.0]), -t * math.radians(deviation_deg))
    turn = flex @ deviate + flex + deviate          # H − I = (A−I)(B−I) + (A−I) + (B−I)
    w, slope = smoothstep((uv[:, 1] - joint[1]) / blend_mm + 0.5)
    offset = (rolled - joint) @ turn.T              # (H − I)(p − joint)
    positions = rolled + w[:, None] * offset
    if not need_ratio:
        return positions, None
    blended = np.eye(3) + w[:, None, None] * turn                      # (n, 3, 3)
    tangent_u = np.column_stack([np.cos(kappa * s), np.zeros_like(s), -np.sin(kappa * s)])
    normal = np.column_stack([np.sin(kappa * s), np.zeros_like(s), np.cos(kappa * s)])
    d_u = np.einsum("nij,nj->ni", blended, tangent_u)
    d_v = blended[:, :, 1] + (slope / blend_mm)[:, None] * offset
    cross = np.cross(d_u, d_v)
    flipped = np.einsum("ni,nij,nj->n", cross, blended, normal) < 0
    return positions, np.where(flipped, -1.0, 1.0) * np.linalg.norm(cross, axis=1)


def cantilever(uv: np.ndarray, t: float, *, radius_mm: float, length_mm: float,
               tilt_deg: float = 0.0, direction_deg: float = 0.0,
               center_mm: tuple[float, float] | None = None) -> np.ndarray:
    """A sheet wrapped around a joystick: a stick clamped at v = 0, bent at constant curvature.

    The flat object is rolled isometrically onto a stick of radius R along v, as
    :func:`cylinder` does (the line u = ``center_mm[0]`` on top at z = 0, curvature t/R,
    the stick's axis at z = −R at t = 1). The stick's axis, the line (u_c, v, −R) at every
    t, then bends like an Euler–Bernoulli beam under a pure end moment: curvature
    κ = t ``tilt_deg`` / ``length_mm`` (rad/mm) over 0 ≤ v ≤ ``length_mm``, so that its tip
    turns by t ``tilt_deg``, in the plane of the axis and the cross-section direction
    d = (cos β, 0, sin β), β = ``direction_deg`` (0° = +x, 90° = +z: towards the top,
    where the sheet's centre line sits). The axis moves towards d, so the side of the
    stick facing d is compressed (by 1 − κR at its surface) and the opposite side
    stretched (1 + κR). Cross-sections stay rigid and perpendicular to the bent axis. The
    base v ≤ 0 is clamped (unchanged); beyond the tip (v > ``length_mm``) the stick
    continues straight along the tip's tangent, rigidly. At t = 0 the result is
    (u, v, 0) exactly. The surface is smooth for 0 < v < ``length_mm``; at v = 0 and at
    the tip the curvature switches on and off, so the stretch along v jumps there (the
    axis stays C1): keep the object inside 0 < v < ``length_mm`` (the glue interpolant
    is C1).

    Refused: |tilt_deg| > 180°, and κR ≥ 1 at t = 1 (the inside of the bend would
    fold); keep κR = |tilt| R / length under ~0.3 for a sheet that is not compressed
    by more than 30 %.
    """
    axis_u = center_of(uv, center_mm)[0]
    s_u = uv[:, 0] - axis_u                             # arc length from the top line
    check_wrap(s_u, radius_mm, "stick")
    if not length_mm > 0:
        raise ParameterError("length_mm", f"must be > 0, got {length_mm!r}")
    if not abs(tilt_deg) <= 180.0:
        raise ParameterError("tilt_deg", f"must lie in [-180, 180] degrees, got {tilt_deg!r}")
    strain = abs(math.radians(tilt_deg)) * radius_mm / length_mm
    if strain >= 1.0:
        raise ParameterError("tilt_deg", f"tilt_deg = {tilt_deg!r} over length_mm = "
                             f"{length_mm!r} bends the stick (radius_mm = {radius_mm!r}) to a "
                             f"radius below its own: curvature x radius = {strain:.3g} >= 1 "
                             "folds the inside of the bend")
    rolled = roll(uv, s_u, t / radius_mm)
    kappa = t * math.radians(tilt_deg) / length_mm
    beta = math.radians(direction_deg)
    d = np.array([math.cos(beta), 0.0, math.sin(beta)])
    axis = np.array([math.sin(beta), 0.0, -math.cos(beta)])    # e_v × d: turns e_v towards d
    v = uv[:, 1]
    s = np.clip(v, 0.0, length_mm)                                # arc length along the bend
    theta = kappa * s
    # The axis point at v moves by γ(v) − (u_c, v, −R): along e_v by sin(θ)/κ − s and
    # towards d by (1 − cos θ)/κ on the arc, then straight along the tip's tangent.
    half = np.sin(0.5 * theta)
    along = s * (np.sinc(theta / math.pi) - 1.0) - (v - s) * 2.0 * half**2
    across = 0.5 * kappa * s**2 * np.sinc(theta / (2 * math.pi)) ** 2 + (v - s) * np.sin(theta)
    # The cross-section offset r = p − axis point turns about the axis e_v × d by θ.
    r = rolled - np.array([axis_u, 0.0, -radius_mm])
    r[:, 1] = 0.0
    k_r = np.cross(axis, r)
    turned = np.sin(theta)[:, None] * k_r + (2.0 * half**2)[:, None] * np.cross(axis, k_r)
    return (rolled + along[:, None] * np.array([0.0, 1.0, 0.0]) + across[:, None] * d
            + turned)
