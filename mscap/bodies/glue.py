"""Glued poses: the sheet's bottom follows a deformed object (paper §4.2, "Poses").

An object is a triangulated surface K whose vertices carry parameter-plane coordinates
``uv`` (mm); a pose gives the same triangles in another position, K_i. The sheet sits in
the parameter plane through a placement, q(X) = R(θ) X + origin, and its bottom point X
is glued to P_i(q(X)), the C1 Clough–Tocher interpolant of K_i's vertex positions over
K's own uv triangles.

The interpolant is :class:`mscap.bodies.cloughtocher.CloughTocher` (scipy's Clough–Tocher
scheme on K's own triangles); the named deformations of generated objects are in
:mod:`mscap.bodies.registry` (the table; the bodies are in :mod:`mscap.bodies.basic`,
:mod:`mscap.bodies.pneumatic` and :mod:`mscap.bodies.hand`).

Frames. ``positions`` are in the sheet frame: the object frame moved by the inverse
placement, so that the flat parameter plane (u, v, 0) is the sheet's rest plane z = 0
and q(X) lies over X. The load fraction t morphs the flat sheet (t = 0, positions are
exactly (x, y, 0)) into the pose (t = 1):

- generator poses: the generator's deformation parameter is scaled by t (curvature t/R);
- file poses: the vertex positions blend linearly, (1 − t) (u, v, 0) + t A(K_i), where A
  is the rigid motion that best fits K_i to the flat (u, v, 0) surface (``align = true``,
  the default) or the identity (``align = false``). At t = 1 the glued bottom is K_i's
  interpolant moved by A and the inverse placement; :meth:`GluePose.object_frame` maps
  positions back onto K_i as given in the file.

Scene keys are documented in ``docs/glue.md``; the ``[objects]`` and glue ``[[poses]]``
tables are read by :mod:`mscap.scene.glue`.
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass, field
from typing import Any

import numpy as np

from mscap.bodies.basic import cylinder, dome
from mscap.bodies.cloughtocher import CloughTocher, _cross
from mscap.bodies.kinematics import ParameterError
from mscap.bodies.registry import GENERATORS, register_generator
from mscap.errors import GeometryError
from mscap.geometry.polygons import point_segment_distance, points_in_polygon

__all__ = [
    "GENERATORS", "register_generator", "ParameterError", "cylinder", "dome",
    "Surface", "CloughTocher", "GlueObject", "Placement", "GluePose", "check_covers",
]


# --------------------------------------------------------------------------- surfaces

@dataclass(frozen=True, eq=False)
class Surface:
    """A triangle surface with parameter coordinates (all mm; arrays read-only)."""

    points: np.ndarray      # (n, 3)
    triangles: np.ndarray   # (m, 3) int
    uv: np.ndarray          # (n, 2)

    def __post_init__(self):
        for name, dtype, width in (("points", float, 3), ("triangles", np.int64, 3),
                                   ("uv", float, 2)):
            array = np.array(getattr(self, name), dtype=dtype)
            if array.ndim != 2 or array.shape[1] != width:
                raise ValueError(f"Surface.{name}: expected shape (*, {width}), got {array.shape}")
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        if len(self.uv) != len(self.points):
            raise ValueError(f"Surface: {len(self.uv)} uv for {len(self.points)} points")


# --------------------------------------------------------------------------- objects

@dataclass(frozen=True, eq=False)
class GlueObject:
    """An object the sheet can be glued to: ``[objects.NAME]`` in a scene.

    ``generator`` names the entry of :data:`GENERATORS` that deforms it (``None`` for an
    object read from a file, ``source``). The interpolant over ``rest.uv`` is built on
    construction, which raises ``ValueError`` for an unusable triangulation.
    """

    name: str
    rest: Surface
    generator: str | None = None
    source: str | None = None
    interpolant: CloughTocher = field(default=None, repr=False)

    def __post_init__(self):
        if self.interpolant is None:
            object.__setattr__(self, "interpolant",
                               CloughTocher(self.rest.uv, self.rest.triangles))

    @property
    def flat_points(self) -> np.ndarray:
        """``(n, 3)`` vertex positions of the flat sheet, (u, v, 0)."""
        return np.column_stack([self.rest.uv, np.zeros(len(self.rest.uv))])


def _grid(width: float, height: float, corner: tuple[float, float], edge: float) -> Surface:
    """A flat rectangle [u0, u0 + width] × [v0, v0 + height], each cell cut along the
    diagonal that alternates like a checkerboard (no preferred direction)."""
    nx, ny = max(1, math.ceil(width / edge - 1e-9)), max(1, math.ceil(height / edge - 1e-9))
    u = corner[0] + np.linspace(0.0, width, nx + 1)
    v = corner[1] + np.linspace(0.0, height, ny + 1)
    uv = np.stack(np.meshgrid(u, v, indexing="ij"), axis=-1).reshape(-1, 2)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"))
    a, b = i * (ny + 1) + j, (i + 1) * (ny + 1) + j          # (i, j), (i + 1, j)
    c, d = b + 1, a + 1                                       # (i + 1, j + 1), (i, j + 1)
    even = ((i + j) % 2 == 0)[:, None]
    first = np.where(even, np.column_stack([a, b, c]), np.column_stack([a, b, d]))
    second = np.where(even, np.column_stack([a, c, d]), np.column_stack([b, c, d]))
    return Surface(np.column_stack([uv, np.zeros(len(uv))]), np.concatenate([first, second]), uv)



# --------------------------------------------------------------------------- poses

@dataclass(frozen=True)
class Placement:
    """Where the sheet lies in the parameter plane: q(X) = R(θ) X + origin (mm, degrees)."""

    origin_mm: tuple[float, float] = (0.0, 0.0)
    rotation_deg: float = 0.0

    @property
    def rotation(self) -> np.ndarray:
        """The 2 × 2 rotation R(θ)."""
        c, s = math.cos(math.radians(self.rotation_deg)), math.sin(math.radians(self.rotation_deg))
        return np.array([[c, -s], [s, c]])

    def to_parameter(self, xy: np.ndarray) -> np.ndarray:
        """q(X) for ``(n, 2)`` sheet points."""
        return xy @ self.rotation.T + np.asarray(self.origin_mm)

    def to_sheet(self, q: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_parameter`."""
        return (q - np.asarray(self.origin_mm)) @ self.rotation

    def sheet_frame(self, points: np.ndarray) -> np.ndarray:
        """Object-frame ``(n, 3)`` points in the sheet frame: (R(θ)ᵀ (p_xy − origin), p_z)."""
        return np.column_stack([self.to_sheet(points[:, :2]), points[:, 2]])


@dataclass(frozen=True, eq=False)
class GluePose:
    """A glued pose: the sheet's bottom follows object ``object`` into this pose.

    ``generator_parameters`` (generated objects) are the keyword arguments of the
    object's generator; ``posed`` (file objects) is K_i as read and ``alignment`` the
    4 × 4 rigid motion A applied to it (identity with ``align = false``).
    """

    name: str
    kind: str = "glue"
    _: KW_ONLY
    object: GlueObject
    placement: Placement = Placement()
    generator_parameters: tuple[tuple[str, Any], ...] = ()
    posed: Surface | None = None
    alignment: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        alignment = np.array(self.alignment, dtype=float)
        alignment.setflags(write=False)
        object.__setattr__(self, "alignment", alignment)

    @property
    def object_name(self) -> str:
        """Name of the object the sheet is glued to."""
        return self.object.name

    def vertex_positions(self, t: float = 1.0) -> np.ndarray:
        """``(n, 3)`` positions of the object's vertices at load fraction ``t`` (object
        frame, after the alignment); the interpolant's data."""
        t = _fraction(t)
        if self.object.generator is not None:
            function = GENERATORS[self.object.generator]
            return function(self.object.rest.uv, t, **dict(self.generator_parameters))
        posed = self.posed.points @ self.alignment[:3, :3].T + self.alignment[:3, 3]
        return (1.0 - t) * self.object.flat_points + t * posed

    def positions(self, rest_xy: np.ndarray, t: float = 1.0) -> np.ndarray:
        """``(n, 3)`` glued positions (sheet frame, mm) of ``(n, 2)`` rest sheet points.

        Raises
        ------
        GeometryError
            When a point's parameter q(X) lies outside the object's uv triangulation.
        """
        return self._evaluate(rest_xy, t, derivative=False)

    def jacobian(self, rest_xy: np.ndarray, t: float = 1.0) -> np.ndarray:
        """``(n, 3, 2)`` exact derivative of :meth:`positions` with respect to ``rest_xy``."""
        return self._evaluate(rest_xy, t, derivative=True)[1]

    def positions_and_jacobian(self, rest_xy: np.ndarray, t: float = 1.0):
        """:meth:`positions` and :meth:`jacobian` for the price of one evaluation."""
        return self._evaluate(rest_xy, t, derivative=True)

    def object_frame(self, positions: np.ndarray) -> np.ndarray:
        """Sheet-frame ``(n, 3)`` positions back in the posed surface file's frame (undoes
        the placement and the alignment; for drawing the sheet on K_i)."""
        p = np.asarray(positions, dtype=float).reshape(-1, 3)
        q = np.column_stack([self.placement.to_parameter(p[:, :2]), p[:, 2]])
        return (q - self.alignment[:3, 3]) @ self.alignment[:3, :3]

    def _evaluate(self, rest_xy, t, derivative):
        xy = np.asarray(rest_xy, dtype=float).reshape(-1, 2)
        ct = self.object.interpolant
        q = self.placement.to_parameter(xy)
        tri, bary = ct.locate(q)
        outside = np.flatnonzero(tri < 0)
        if len(outside):
            i = outside[0]
            raise GeometryError(
                f"glue pose {self.name!r}: {len(outside)} of {len(xy)} sheet points lie "
                f"outside the parameter domain of object {self.object.name!r} (first: sheet "
                f"point {xy[i].round(6).tolist()} mm at parameter {q[i].round(6).tolist()} mm)")
        values = self.vertex_positions(t)
        result = ct.evaluate(values, ct.gradients(values), tri, bary, derivative)
        if not derivative:
            return self.placement.sheet_frame(result)
        value, dq = result                      # dP/dq, (n, 3, 2)
        r = self.placement.rotation
        jac = dq @ r                            # chain rule through q = R X + origin
        jac[:, :2] = np.einsum("ba,pbd->pad", r, jac[:, :2])   # Rᵀ on the in-plane rows
        return self.placement.sheet_frame(value), jac


def _fraction(t: float) -> float:
    t = float(t)
    if not 0.0 <= t <= 1.0:
        raise ValueError(f"load fraction must lie in [0, 1], got {t!r}")
    return t


def _rigid_fit(source: np.ndarray, target: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """4 × 4 proper rigid motion A minimising Σ w |A(source) − target|² (Kabsch)."""
    w = weight / weight.sum()
    s0, t0 = w @ source, w @ target
    u, _, vt = np.linalg.svd(((source - s0) * w[:, None]).T @ (target - t0))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T)) or 1.0])
    rotation = vt.T @ flip @ u.T
    motion = np.eye(4)
    motion[:3, :3], motion[:3, 3] = rotation, t0 - rotation @ s0
    return motion


def _vertex_areas(surface: Surface) -> np.ndarray:
    """Lumped parameter-plane area per vertex (a third of each incident triangle)."""
    p = surface.uv[surface.triangles]
    area = 0.5 * np.abs(_cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
    return np.bincount(surface.triangles.ravel(), np.repeat(area / 3, 3), len(surface.uv))



def check_covers(pose: GluePose, sheet_outline_mm: np.ndarray) -> None:
    """Check that the placed sheet lies inside the object's parameter domain.

    The outline is sampled at a quarter of the object's shortest edge and each sample
    located; then no edge of the object's boundary may cross the outline and no
    boundary vertex (a hole or a notch) may lie inside it.

    Raises
    ------
    GeometryError
        Naming the pose, the object and the first uncovered point (sheet mm).
    """
    ct = pose.object.interpolant
    outline = np.asarray(sheet_outline_mm, dtype=float)
    q = pose.placement.to_parameter(outline)
    a, b = q, np.roll(q, -1, axis=0)
    edge = np.linalg.norm(ct.points[ct.edges[:, 1]] - ct.points[ct.edges[:, 0]], axis=1).min()
    counts = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / (0.25 * edge))).astype(int)
    counts = np.minimum(counts, max(1, 200_000 // len(q)))
    start = np.repeat(np.arange(len(q)), counts)              # outline edge of each sample
    s = (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)) / counts[start]
    samples = a[start] + s[:, None] * (b - a)[start]

    def fail(point_q, what):
        xy = pose.placement.to_sheet(point_q[None])[0].round(6).tolist()
        raise GeometryError(f"glue pose {pose.name!r}: the parameter domain of object "
                            f"{pose.object.name!r} does not cover the sheet: {what} at sheet "
                            f"point {xy} mm (parameter {np.round(point_q, 6).tolist()} mm)")

    tri, _ = ct.locate(samples)
    if (tri < 0).any():
        fail(samples[np.argmax(tri < 0)], "the outline leaves it")
    p1, p2 = (ct.points[i] for i in ct.boundary_edges.T)
    tol = 1e-9 * ct.scale**2

    def side(u, v):  # strictly one way, strictly the other
        return ((u > tol) & (v < -tol)) | ((u < -tol) & (v > tol))

    d1 = _cross((b - a)[None], p1[:, None] - a[None])                   # (E, n)
    d2 = _cross((b - a)[None], p2[:, None] - a[None])
    d3 = _cross((p2 - p1)[:, None], a[None] - p1[:, None])
    d4 = _cross((p2 - p1)[:, None], b[None] - p1[:, None])
    cross = side(d1, d2) & side(d3, d4)
    if cross.any():
        e, j = np.unravel_index(np.argmax(cross), cross.shape)
        w = d3[e, j] / (d3[e, j] - d4[e, j])
        fail(a[j] + w * (b[j] - a[j]), "its boundary crosses the outline")
    inside = points_in_polygon(p1, q)
    if inside.any():
        near = point_segment_distance(p1[inside], np.stack([a, b], axis=1)).min(axis=1)
        strictly = np.flatnonzero(inside)[near > 1e-9 * ct.scale]
        if len(strictly):
            fail(p1[strictly[0]], "a boundary point of the object (hole or notch) lies inside")
