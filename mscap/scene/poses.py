"""Target poses: what each ``[[poses]]`` entry of a scene asks for, typed and checked.

A pose says *what* deforms the sheet; :mod:`mscap.fem.elastic.loading` turns it into boundary data on
a mesh. Kinds:

``free``
    The rest pose.
``stretch``
    Grips on the sheet edges: ``mode`` uniaxial (``stretch`` λ along ``direction``),
    biaxial (``stretch = [λx, λy]``) or plane_strain (λ along ``direction``, the other
    in-plane direction held); ``grips`` clamp (the edge is fully fixed) or roller (normal
    displacement only).
``poke``
    A rigid ball of ``radius_mm`` centred above ``center_mm`` pressed ``depth_mm`` into
    the top surface (depth counted from first contact) while ``held_edges`` are clamped.
``glue``
    The bottom surface follows a posed object (:mod:`mscap.bodies.glue`).
"""

from __future__ import annotations

from dataclasses import dataclass

from mscap.scene._toml import Table
from mscap.scene.settings import MAX_LENGTH_MM, MAX_LOAD_STEPS, STRETCH_RANGE

__all__ = ["FreePose", "StretchPose", "PokePose", "read_pose", "EDGES", "STRETCH_MODES", "GRIPS"]

#: Sheet edges by the bounding-box side they lie on.
EDGES = ("x_min", "x_max", "y_min", "y_max")
STRETCH_MODES = ("uniaxial", "biaxial", "plane_strain")
GRIPS = ("clamp", "roller")


@dataclass(frozen=True)
class FreePose:
    """The rest pose."""

    name: str
    kind: str = "free"


@dataclass(frozen=True)
class StretchPose:
    """Stretch by grips on the sheet edges.

    Attributes
    ----------
    mode
        ``uniaxial``, ``biaxial`` or ``plane_strain``.
    stretch
        ``(λx, λy)`` final stretch ratios; the unstretched direction has 1 (uniaxial:
        free to contract; plane strain: held).
    grips
        ``clamp`` or ``roller``.
    axis
        The stretched in-plane axis (0 = x, 1 = y) of a uniaxial or plane-strain pose.
    load_steps
        Initial number of load steps (cut automatically when Newton stalls).
    """

    name: str
    mode: str
    stretch: tuple[float, float]
    grips: str
    axis: int = 0
    load_steps: int = 1
    kind: str = "stretch"

    @property
    def gripped_axes(self) -> tuple[int, ...]:
        """In-plane axes (0 = x, 1 = y) whose two edges carry grips."""
        return (0, 1) if self.mode == "biaxial" else (self.axis,)


@dataclass(frozen=True)
class PokePose:
    """A rigid ball pressed into the top surface.

    Attributes
    ----------
    center_mm
        ``(x, y)`` of the ball centre.
    radius_mm, depth_mm
        Ball radius and indentation depth below first contact.
    held_edges
        Clamped sheet edges (names from :data:`EDGES`).
    barrier_distance_mm
        d̂: the barrier acts on nodes closer than this (the final gap lies in (0, d̂)).
        The default 0.1 mm is IPC's rule of thumb, 1e-3 of the scene's diagonal; 0.01 mm
        moved the poking scene's capacitances by 0.03 % and needed 37 instead of 26
        Newton iterations.
    barrier_stiffness_MPa_per_mm
        κ; ``None`` picks ``0.01 μ / d̂`` with μ the softest shear modulus.
    load_steps
        Initial number of load steps.
    """

    name: str
    center_mm: tuple[float, float]
    radius_mm: float
    depth_mm: float
    held_edges: tuple[str, ...]
    barrier_distance_mm: float = 0.1
    barrier_stiffness_MPa_per_mm: float | None = None
    load_steps: int = 4
    kind: str = "poke"


def read_pose(t: Table, objects: dict | None = None):
    """A typed pose from one ``[[poses]]`` table (its ``kind`` already checked)."""
    kind = t.get("kind", str)
    name = t.get("name", str)
    if kind == "glue":
        from mscap.scene.glue import read_glue_pose

        return read_glue_pose(t, objects or {})
    if kind == "free":
        t.finish()
        return FreePose(name)
    if kind == "stretch":
        pose = _read_stretch(t, name)
    else:
        pose = _read_poke(t, name)
    t.finish()
    return pose


def _choice(t: Table, key: str, choices, default=...) -> str:
    value = t.get(key, str, default)
    if value not in choices:
        raise t.error(key, f"unknown value {value!r}; expected one of {', '.join(choices)}")
    return value


def _ratio(t: Table, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise t.error(key, f"stretch ratios must be numbers > 0, got {value!r}")
    lo, hi = STRETCH_RANGE
    if not lo <= value <= hi:
        raise t.error(key, f"stretch ratios must lie in [{lo:g}, {hi:g}], got {value!r} (below {lo:g} a sheet "
                      f"between grips buckles out of plane instead of shortening; an elastomer tears before "
                      f"{hi:g} times its length)")
    return float(value)


def _read_stretch(t: Table, name: str) -> StretchPose:
    mode = _choice(t, "mode", STRETCH_MODES)
    grips = _choice(t, "grips", GRIPS, "clamp")
    raw = t.data.get("stretch")
    if mode == "biaxial":
        values = t.get("stretch", list)
        if len(values) != 2:
            raise t.error("stretch", f"biaxial stretch needs [λx, λy], got {values!r}")
        stretch = (_ratio(t, "stretch", values[0]), _ratio(t, "stretch", values[1]))
        axis = 0
        if "direction" in t.data:
            raise t.error("direction", "a biaxial stretch has no direction (it stretches x and y)")
    else:
        ratio = _ratio(t, "stretch", t.get("stretch", float) if not isinstance(raw, list) else raw)
        axis = "xy".index(_choice(t, "direction", ("x", "y"), "x"))
        stretch = (ratio, 1.0) if axis == 0 else (1.0, ratio)
    steps = t.get("load_steps", int, max(1, int(round(4 * max(abs(s - 1) for s in stretch)))), minimum=1,
                  maximum=MAX_LOAD_STEPS, why="each is a Newton solve")
    return StretchPose(name, mode, stretch, grips, axis, steps)


def _read_poke(t: Table, name: str) -> PokePose:
    center = t.points("", [t.get("center_mm", list)], key=t.key("center_mm"))[0]
    radius = t.get("radius_mm", float, positive=True)
    depth = t.get("depth_mm", float, positive=True)
    edges = t.get("held_edges", list, ["x_min", "x_max"])
    for edge in edges:
        if edge not in EDGES:
            raise t.error("held_edges", f"unknown edge {edge!r}; expected some of {', '.join(EDGES)}")
    if not edges:
        raise t.error("held_edges", "hold at least one edge (a free sheet would just move away)")
    dhat = t.get("barrier_distance_mm", float, PokePose.barrier_distance_mm, positive=True, maximum=MAX_LENGTH_MM)
    kappa = t.get("barrier_stiffness_MPa_per_mm", float, 0.0, minimum=0.0) or None
    steps = t.get("load_steps", int, min(MAX_LOAD_STEPS, max(2, int(round(depth / 3.0)))), minimum=1,
                  maximum=MAX_LOAD_STEPS, why="each is a Newton solve")
    return PokePose(name, center, radius, depth, tuple(dict.fromkeys(edges)), dhat, kappa, steps)
