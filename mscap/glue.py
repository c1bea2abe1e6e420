"""Glued poses: the sheet's bottom follows a deformed object (paper §4.2, "Poses").

An object is a triangulated surface K whose vertices carry parameter-plane coordinates
``uv`` (mm); a pose gives the same triangles in another position, K_i. The sheet sits in
the parameter plane through a placement, q(X) = R(θ) X + origin, and its bottom point X
is glued to P_i(q(X)), the C1 Clough–Tocher interpolant of K_i's vertex positions over
K's own uv triangles.

The interpolant is scipy's (``scipy.interpolate.CloughTocher2DInterpolator``),
re-implemented vectorised on a given triangulation, because scipy only builds it on the
Delaunay triangulation of the points (a ``Delaunay`` object is the only triangulation it
accepts); that would ignore K's connectivity and fill in K's concave parts and holes. The
Bézier control points, the affine-invariant cross-boundary directions (centroid of the
neighbour) and the boundary rule are scipy's; the vertex gradients minimise the same
curvature functional (Nielson 1983, Renka & Cline 1984), solved exactly by one sparse
factorisation instead of scipy's Gauss–Seidel to ``tol = 1e-6``. On a Delaunay K both
agree to round-off (``tests/test_glue.py``).

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

Scene keys are documented in ``docs/glue.md`` and :func:`read_objects`,
:func:`read_glue_pose`.
"""

from __future__ import annotations

import inspect
import logging
import math
from dataclasses import KW_ONLY, dataclass, field
from pathlib import Path
from typing import Any, Callable

import meshio
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ._toml import Table
from .errors import GeometryError
from .geometry import point_segment_distance, points_in_polygon

__all__ = [
    "GENERATORS", "register_generator", "ParameterError", "cylinder", "dome",
    "Surface", "CloughTocher", "GlueObject", "Placement", "GluePose",
    "read_objects", "read_glue_pose", "check_covers",
]

logger = logging.getLogger(__name__)

#: Keys a glue pose reads itself; generator parameters may not use them.
_POSE_KEYS = ("name", "kind", "object", "origin_mm", "rotation_deg", "surface", "align")


# --------------------------------------------------------------------------- generators

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


def _parameter_kind(parameter: inspect.Parameter) -> str:
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
    for parameter in _generator_parameters(function):
        _parameter_kind(parameter)
        if parameter.name in _POSE_KEYS:
            raise ValueError(f"generator {name!r}: parameter name {parameter.name!r} is a "
                             "glue-pose key")
    GENERATORS[name] = function


def _generator_parameters(function) -> list[inspect.Parameter]:
    return [p for p in inspect.signature(function).parameters.values()
            if p.kind is inspect.Parameter.KEYWORD_ONLY]


register_generator("cylinder", cylinder)
register_generator("dome", dome)


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


class CloughTocher:
    """scipy's C1 Clough–Tocher interpolant on a fixed planar triangulation.

    Everything that depends only on the triangulation (neighbours, cross-boundary
    directions, the factorised gradient system, a point locator) is built once; values
    are given per evaluation.

    Parameters
    ----------
    points
        ``(n, 2)`` vertex coordinates.
    triangles
        ``(m, 3)`` vertex indices; any orientation, no folds, every vertex used.

    Raises
    ------
    ValueError
        On duplicate points, unused points, zero-area triangles, edges shared by more
        than two triangles, or a triangulation that folds over.
    """

    # control points of the 3 sub-triangle cubics, as exponents of the extended
    # barycentric coordinates (b1, b2, b3, b4), in scipy's naming c_ijkl
    _EXPONENTS = np.array([[3, 0, 0, 0], [2, 1, 0, 0], [2, 0, 1, 0], [2, 0, 0, 1],
                           [1, 2, 0, 0], [1, 1, 0, 1], [1, 0, 2, 0], [1, 0, 1, 1],
                           [1, 0, 0, 2], [0, 3, 0, 0], [0, 2, 1, 0], [0, 2, 0, 1],
                           [0, 1, 2, 0], [0, 1, 1, 1], [0, 1, 0, 2], [0, 0, 3, 0],
                           [0, 0, 2, 1], [0, 0, 1, 2], [0, 0, 0, 3]])
    _MULTINOMIAL = 6.0 / np.prod([[math.factorial(e) for e in row] for row in _EXPONENTS],
                                 axis=1)

    def __init__(self, points: np.ndarray, triangles: np.ndarray):
        p = np.asarray(points, dtype=float)
        tri = np.asarray(triangles, dtype=np.int64)
        n = len(p)
        self.scale = float(np.ptp(p, axis=0).max()) or 1.0
        _check_points(p, tri)
        area2 = _cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
        flat = np.abs(area2) <= 1e-12 * self.scale**2
        if flat.any():
            i = int(np.argmax(flat))
            raise ValueError(f"{flat.sum()} triangles have zero area in the parameter plane "
                             f"(first: triangle {i}, vertices {tri[i].tolist()} at "
                             f"{np.round(p[tri[i]], 6).tolist()})")
        self.points, self.triangles = p, tri

        # half-edge 3t + k is the edge of triangle t opposite its vertex k (qhull's order)
        ends = np.sort(tri[:, [[1, 2], [2, 0], [0, 1]]], axis=2).reshape(-1, 2)
        keys, first, inverse, counts = np.unique(ends[:, 0] * n + ends[:, 1], return_index=True,
                                                 return_inverse=True, return_counts=True)
        if (counts > 2).any():
            a, b = divmod(int(keys[np.argmax(counts > 2)]), n)
            raise ValueError(f"edge ({a}, {b}) is shared by {counts.max()} triangles "
                             "(the surface must be a manifold)")
        twin = np.full(3 * len(tri), -1)
        second = np.flatnonzero((counts[inverse] == 2) & (np.arange(len(twin)) != first[inverse]))
        twin[second] = first[inverse[second]]
        twin[first[inverse[second]]] = second
        self.neighbors = np.where(twin >= 0, twin // 3, -1).reshape(-1, 3)
        self._boundary = np.flatnonzero(twin < 0)
        self.edges = np.column_stack(divmod(keys, n))

        # barycentric coordinates c0, c1 = T⁻¹ (x − p2), c2 = 1 − c0 − c1
        origin = p[tri[:, 2]]
        (a, c), (b, d) = (p[tri[:, 0]] - origin).T, (p[tri[:, 1]] - origin).T
        self._origin = origin
        self._inverse = np.stack([np.column_stack([d, -b]), np.column_stack([-c, a])],
                                 axis=1) / (a * d - b * c)[:, None, None]
        grad01 = self._inverse                              # rows: ∇c0, ∇c1
        self._bary_gradient = np.concatenate([grad01, -grad01.sum(axis=1, keepdims=True)], axis=1)
        self._check_folds(twin)
        self._g = self._cross_boundary_directions()
        self._matrix, self._rhs = self._gradient_system()
        self._lu = splu(self._matrix.tocsc())
        self._finder = None

    # ---------------------------------------------------------------- construction

    def _barycentric(self, tri: np.ndarray, xy: np.ndarray) -> np.ndarray:
        c01 = np.einsum("pij,pj->pi", self._inverse[tri], xy - self._origin[tri])
        return np.column_stack([c01, 1.0 - c01.sum(axis=1)])

    def _check_folds(self, twin: np.ndarray) -> None:
        """Across every interior edge the two triangles must lie on opposite sides."""
        inner = np.flatnonzero(twin >= 0)
        t, k = np.divmod(inner, 3)
        t2 = twin[inner] // 3
        # a fold shows as the neighbour's far vertex having a non-negative barycentric
        # coordinate for our opposite vertex (whatever the two triangles' orientations)
        far = self.triangles[t2, twin[inner] % 3]
        c = self._barycentric(t, self.points[far])[np.arange(len(t)), k]
        bad = c > -1e-12
        if bad.any():
            i = int(np.argmax(bad))
            a, b = self.triangles[t[i], [(k[i] + 1) % 3, (k[i] + 2) % 3]]
            raise ValueError(f"the parameter-plane triangulation folds over at edge "
                             f"({a}, {b}): triangles {t[i]} and {t2[i]} lie on the same side")

    def _cross_boundary_directions(self) -> np.ndarray:
        """scipy's g1, g2, g3: the derivative direction across edge k points from this
        triangle's centroid to its neighbour's (affine invariant); on the boundary, from
        the edge's midpoint to the centroid (g = −1/2, as in scipy 1.13)."""
        tri, nbr = self.triangles, self.neighbors
        centroid = self.points[tri].mean(axis=1)
        m = len(tri)
        g = np.full((m, 3), -0.5)
        for k in range(3):
            has = nbr[:, k] >= 0
            t = np.flatnonzero(has)
            c = self._barycentric(t, centroid[nbr[t, k]])
            i, j = (k + 2) % 3, (k + 1) % 3
            g[t, k] = (2 * c[:, i] + c[:, j] - 1) / (2 - 3 * c[:, i] - 3 * c[:, j])
        return g

    def _gradient_system(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """H, B with H ∇f = B f minimising Σ_edges ∫ |∂²w/∂s²|² of the edge cubics.

        Per edge E = p_j − p_i, with a = E·∇f_i and b = E·∇f_j, L³ ∫ w''² =
        4a² + 4ab + 4b² + 12 (f_i − f_j)(a + b) + const (scipy's interpnd notes).
        """
        i, j = self.edges[:, 0], self.edges[:, 1]
        e = self.points[j] - self.points[i]
        w = np.linalg.norm(e, axis=1) ** -3
        outer = w[:, None, None] * e[:, :, None] * e[:, None, :]          # (E, 2, 2)
        n = len(self.points)
        a = np.arange(2)

        def dof(vertex):  # (E, 2) unknowns (∂x, ∂y) of each edge's vertex
            return 2 * vertex[:, None] + a

        # ∂/∂∇f_i: 8 E Eᵀ ∇f_i + 4 E Eᵀ ∇f_j = −12 (f_i − f_j) E, and i <-> j, over L³
        blocks = ((i, i, 8), (j, j, 8), (i, j, 4), (j, i, 4))
        matrix = sp.coo_matrix((
            np.concatenate([factor * outer.ravel() for _, _, factor in blocks]),
            (np.concatenate([np.repeat(dof(r), 2, axis=1).ravel() for r, _, _ in blocks]),
             np.concatenate([np.tile(dof(c), 2).ravel() for _, c, _ in blocks]))),
            shape=(2 * n, 2 * n)).tocsr()
        we = 12 * w[:, None] * e                                          # (E, 2)
        terms = ((i, i, -we), (j, i, -we), (i, j, we), (j, j, we))        # (row, column)
        rhs = sp.coo_matrix((
            np.concatenate([v.ravel() for _, _, v in terms]),
            (np.concatenate([dof(r).ravel() for r, _, _ in terms]),
             np.concatenate([np.repeat(c, 2) for _, c, _ in terms]))),
            shape=(2 * n, n)).tocsr()
        return matrix, rhs

    @property
    def boundary_edges(self) -> np.ndarray:
        """``(E, 2)`` vertex indices of the edges that have one triangle."""
        t, k = np.divmod(self._boundary, 3)
        return np.column_stack([self.triangles[t, (k + 1) % 3], self.triangles[t, (k + 2) % 3]])

    # ---------------------------------------------------------------- evaluation

    def gradients(self, values: np.ndarray) -> np.ndarray:
        """``(n, 2, k)`` vertex gradients of ``(n, k)`` vertex values (exact minimiser)."""
        values = np.asarray(values, dtype=float).reshape(len(self.points), -1)
        return self._lu.solve(np.asarray(self._rhs @ values)).reshape(len(self.points), 2, -1)

    def locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangle (``-1`` outside) and barycentric coordinates of each point.

        Points within 1e-9 of the domain's size outside a boundary edge count as on it.
        """
        if self._finder is None:
            # a trapezoid map works on any valid triangulation; imported only when needed
            import matplotlib.tri as mtri
            triangulation = mtri.Triangulation(self.points[:, 0], self.points[:, 1], self.triangles)
            self._finder = mtri.TrapezoidMapTriFinder(triangulation)
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        tri = np.asarray(self._finder(xy[:, 0], xy[:, 1]), dtype=np.int64)
        miss = np.flatnonzero(tri < 0)
        if len(miss):
            tri[miss] = self._nearest_boundary_triangle(xy[miss])
        bary = np.zeros((len(xy), 3))
        found = tri >= 0
        bary[found] = self._barycentric(tri[found], xy[found])
        return tri, bary

    def _nearest_boundary_triangle(self, xy: np.ndarray) -> np.ndarray:
        t = self._boundary // 3
        a, b = (self.points[i] for i in self.boundary_edges.T)
        ab = b - a
        out = np.full(len(xy), -1)
        for start in range(0, len(xy), 1024):          # chunks bound the memory, not a loop per point
            ap = xy[start:start + 1024, None, :] - a[None]
            s = np.clip(np.einsum("peb,eb->pe", ap, ab) / np.einsum("eb,eb->e", ab, ab), 0, 1)
            d = np.linalg.norm(ap - s[..., None] * ab[None], axis=2)
            near = d.argmin(axis=1)
            close = d[np.arange(len(near)), near] <= 1e-9 * self.scale
            out[start:start + 1024] = np.where(close, t[near], -1)
        return out

    def evaluate(self, values: np.ndarray, gradients: np.ndarray, tri: np.ndarray,
                 bary: np.ndarray, derivative: bool = False):
        """Interpolant (and its ``(p, k, 2)`` derivative) at located points.

        ``values`` ``(n, k)``, ``gradients`` ``(n, 2, k)`` from :meth:`gradients`,
        ``tri``/``bary`` from :meth:`locate` (every ``tri >= 0``).
        """
        values = np.asarray(values, dtype=float).reshape(len(self.points), -1)
        control = self._control_points(values, gradients, tri)          # (p, 19, k)
        low = bary.argmin(axis=1)
        rows = np.arange(len(tri))
        b_low = bary[rows, low]
        beta = np.column_stack([bary - b_low[:, None], 3 * b_low])      # extended, one is 0
        powers = beta[:, :, None] ** np.arange(4)                       # (p, 4, 4)
        e = self._EXPONENTS
        factors = powers[:, np.arange(4), e]                             # (p, 19, 4)
        monomials = factors.prod(axis=2) * self._MULTINOMIAL
        value = np.einsum("pa,pak->pk", monomials, control)
        if not derivative:
            return value
        dbary = self._bary_gradient[tri]                                 # (p, 3, 2)
        d_low = dbary[rows, low]
        dbeta = np.concatenate([dbary - d_low[:, None], 3 * d_low[:, None]], axis=1)
        dfactors = e * powers[:, np.arange(4), np.maximum(e - 1, 0)]
        dmono = np.stack([dfactors[:, :, j] * np.delete(factors, j, axis=2).prod(axis=2)
                          for j in range(4)], axis=2) * self._MULTINOMIAL[:, None]
        return value, np.einsum("paj,pjd,pak->pkd", dmono, dbeta, control)

    def _control_points(self, f: np.ndarray, df: np.ndarray, tri: np.ndarray) -> np.ndarray:
        """scipy's ``_clough_tocher_2d_single`` control points, vectorised (p, 19, k)."""
        v = self.triangles[tri]
        p = self.points[v]                                               # (p, 3, 2)
        f1, f2, f3 = f[v[:, 0]], f[v[:, 1]], f[v[:, 2]]
        d1, d2, d3 = df[v[:, 0]], df[v[:, 1]], df[v[:, 2]]
        e12, e23, e31 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]

        def along(d, e):  # directional derivative (p, k)
            return np.einsum("pik,pi->pk", d, e)

        c3000, c0300, c0030 = f1, f2, f3
        c2100 = (along(d1, e12) + 3 * c3000) / 3
        c2010 = (-along(d1, e31) + 3 * c3000) / 3
        c1200 = (-along(d2, e12) + 3 * c0300) / 3
        c0210 = (along(d2, e23) + 3 * c0300) / 3
        c1020 = (along(d3, e31) + 3 * c0030) / 3
        c0120 = (-along(d3, e23) + 3 * c0030) / 3
        c2001 = (c2100 + c2010 + c3000) / 3
        c0201 = (c1200 + c0300 + c0210) / 3
        c0021 = (c1020 + c0120 + c0030) / 3
        g1, g2, g3 = (self._g[tri, k][:, None] for k in range(3))
        c0111 = (g1 * (-c0300 + 3 * c0210 - 3 * c0120 + c0030)
                 + (-c0300 + 2 * c0210 - c0120 + c0021 + c0201)) / 2
        c1011 = (g2 * (-c0030 + 3 * c1020 - 3 * c2010 + c3000)
                 + (-c0030 + 2 * c1020 - c2010 + c2001 + c0021)) / 2
        c1101 = (g3 * (-c3000 + 3 * c2100 - 3 * c1200 + c0300)
                 + (-c3000 + 2 * c2100 - c1200 + c2001 + c0201)) / 2
        c1002 = (c1101 + c1011 + c2001) / 3
        c0102 = (c1101 + c0111 + c0201) / 3
        c0012 = (c1011 + c0111 + c0021) / 3
        c0003 = (c1002 + c0102 + c0012) / 3
        return np.stack([c3000, c2100, c2010, c2001, c1200, c1101, c1020, c1011, c1002,
                         c0300, c0210, c0201, c0120, c0111, c0102, c0030, c0021, c0012,
                         c0003], axis=1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _check_points(p: np.ndarray, tri: np.ndarray) -> None:
    if len(tri) == 0:
        raise ValueError("no triangles")
    if tri.min() < 0 or tri.max() >= len(p):
        raise ValueError(f"triangle vertex indices must lie in [0, {len(p)})")
    used = np.zeros(len(p), dtype=bool)
    used[tri.ravel()] = True
    if not used.all():
        raise ValueError(f"{np.count_nonzero(~used)} points are in no triangle "
                         f"(first: point {int(np.argmin(used))})")
    _, first, counts = np.unique(p, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = p[first[np.argmax(counts > 1)]]
        same = np.flatnonzero(np.all(p == dup, axis=1))
        raise ValueError(f"points {same.tolist()} share the parameter coordinates "
                         f"{dup.tolist()} (a seam must be cut open)")


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


def _read_surface(t: Table, key: str, base: Path) -> tuple[Path, Any]:
    """Read the triangle surface file named by entry ``key`` of ``t`` with meshio."""
    path = base / t.get(key, str)
    try:
        mesh = meshio.read(path)
    except Exception as exc:          # meshio raises many types; name the file in all
        raise t.error(key, f"cannot read surface file {str(path)!r}: {exc}") from None
    kinds = {block.type for block in mesh.cells} - {"vertex", "line", "triangle"}
    if kinds:
        raise t.error(key, f"{str(path)!r} has {', '.join(sorted(kinds))} cells; "
                      "only triangles are supported (triangulate the surface)")
    blocks = [block.data for block in mesh.cells if block.type == "triangle"]
    if not blocks:
        raise t.error(key, f"{str(path)!r} has no triangles")
    points = np.asarray(mesh.points, dtype=float)
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    if not np.isfinite(points).all():
        raise t.error(key, f"{str(path)!r} has non-finite point coordinates")
    return path, (points, np.concatenate(blocks).astype(np.int64), mesh.point_data)


def read_objects(t: Table | None, scene_path: str) -> dict[str, GlueObject]:
    """Read the scene's ``[objects]`` table.

    Each ``[objects.NAME]`` is either generated or read from a file:

    ``generator`` (string)
        a name in :data:`GENERATORS` (``"cylinder"``, ``"dome"``, ...). The rest
        surface is the flat rectangle ``width_mm`` × ``height_mm`` (numbers > 0) with
        its lower-left corner at ``corner_mm`` (``[u, v]``, default ``[0, 0]``),
        triangulated with edges of ``edge_length_mm`` (> 0, default 1); its points are
        (u, v, 0). It must cover the sheet's placement in the parameter plane.
    ``rest`` (string)
        a triangle surface file meshio reads, relative to the scene file's directory;
        ``uv_field`` (string, optional) names the point data holding each vertex's
        parameter coordinates (mm, 2 columns, or more with zeros after the second);
        without it the parameter coordinates are the file's (x, y).

    Raises
    ------
    SceneError
        Naming the key and value: both or neither of ``generator``/``rest``, an unknown
        generator, an unreadable or non-triangle file, a missing or malformed uv field,
        and parameter-plane triangulations with duplicate or unused points, zero-area
        triangles, non-manifold edges or folds.
    """
    if t is None:
        return {}
    base = Path(scene_path).parent
    objects = {}
    for name in t.data:
        o = t.table(name)
        if o.has("generator") == o.has("rest"):
            raise o.error("generator", "give exactly one of 'generator' (a generated flat "
                          "object) or 'rest' (a surface file)")
        if o.has("generator"):
            generator = o.get("generator", str)
            if generator not in GENERATORS:
                raise o.error("generator", f"unknown generator {generator!r}; known: "
                              f"{', '.join(sorted(GENERATORS))}")
            width = o.get("width_mm", float, positive=True)
            height = o.get("height_mm", float, positive=True)
            corner = _point(o, "corner_mm", [0.0, 0.0])
            edge = o.get("edge_length_mm", float, 1.0, positive=True)
            cells = math.ceil(width / edge) * math.ceil(height / edge)
            if cells > 1_000_000:
                raise o.error("edge_length_mm", f"{edge!r} mm makes {cells} cells on a "
                              f"{width:g} x {height:g} mm object (limit 1000000)")
            rest, key, source = _grid(width, height, corner, edge), "edge_length_mm", None
        else:
            generator = None
            path, (points, triangles, point_data) = _read_surface(o, "rest", base)
            uv, key = points[:, :2], "rest"
            field_name = o.get("uv_field", str, None)
            if field_name is not None:
                uv, key = _uv_field(o, field_name, path, point_data, len(points)), "uv_field"
            rest, source = Surface(points, triangles, uv), str(path)
        o.finish()
        try:
            objects[name] = GlueObject(name, rest, generator, source)
        except ValueError as exc:
            where = f"{source!r}: " if source else ""
            raise o.error(key, f"{where}unusable parameter-plane triangulation: {exc}") from None
        logger.info("object %r: %d vertices, %d triangles, uv extent %s mm", name,
                    len(rest.uv), len(rest.triangles), np.ptp(rest.uv, axis=0).round(3).tolist())
    return objects


def _point(t: Table, key: str, default: Any = ...) -> tuple[float, float] | None:
    """Entry ``key`` as one point ``[x, y]`` (``default`` when absent)."""
    value = t.get(key, list, default)
    if value is None:
        return None
    return t.points("", [value], key=t.key(key))[0]


def _uv_field(t: Table, name: str, path: Path, point_data: dict, n: int) -> np.ndarray:
    if name not in point_data:
        known = ", ".join(sorted(point_data)) or "none"
        raise t.error("uv_field", f"{str(path)!r} has no point data {name!r} "
                      f"(it has: {known})")
    uv = np.asarray(point_data[name], dtype=float)
    if uv.ndim != 2 or uv.shape[0] != n or uv.shape[1] < 2 or np.any(uv[:, 2:] != 0):
        raise t.error("uv_field", f"point data {name!r} of {str(path)!r} must hold 2 "
                      f"coordinates per point (mm), got shape {uv.shape}")
    if not np.isfinite(uv).all():
        raise t.error("uv_field", f"point data {name!r} of {str(path)!r} is not finite")
    return uv[:, :2]


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


def read_glue_pose(t: Table, objects: dict[str, GlueObject]) -> GluePose:
    """Read one ``[[poses]]`` entry of kind ``"glue"``.

    Keys: ``object`` (a name defined under ``[objects]``); the placement ``origin_mm``
    (``[u, v]``, default ``[0, 0]``: the parameter point under the sheet's origin) and
    ``rotation_deg`` (default 0); then for a generated object its generator's parameters
    (``cylinder`` and ``dome``: ``radius_mm`` > 0, ``center_mm`` = ``[u, v]``, default
    the centre of the object), or for a file object ``surface`` (the posed surface file,
    relative to the scene file, same triangles as the rest file) and ``align`` (boolean,
    default true: fit K_i rigidly to the flat sheet before blending).

    Raises
    ------
    SceneError
        Naming the key and value: a kind other than glue, an unknown object, generator
        parameters missing or out of range, a surface given for a generated object (or
        missing for a file object), an unreadable surface, a posed surface whose points
        or triangles differ from the rest surface's, and unknown keys.
    """
    name = t.get("name", str)
    kind = t.get("kind", str)
    if kind != "glue":
        raise t.error("kind", f"expected 'glue', got {kind!r}")
    object_name = t.get("object", str)
    if object_name not in objects:
        defined = ", ".join(sorted(objects)) or "none; add an [objects.NAME] table"
        raise t.error("object", f"unknown object {object_name!r}; defined: {defined}")
    obj = objects[object_name]
    origin = _point(t, "origin_mm", [0.0, 0.0])
    placement = Placement(origin, t.get("rotation_deg", float, 0.0))
    if obj.generator is not None:
        if t.has("surface") or t.has("align"):
            key = "surface" if t.has("surface") else "align"
            raise t.error(key, f"object {object_name!r} is generated by {obj.generator!r}; "
                          "give its parameters instead of a posed surface")
        pose = GluePose(name, object=obj, placement=placement,
                        generator_parameters=_read_parameters(t, obj))
    else:
        base = Path(t.path).parent
        path, (points, triangles, _) = _read_surface(t, "surface", base)
        rest = obj.rest
        if len(points) != len(rest.points) or len(triangles) != len(rest.triangles):
            raise t.error("surface", f"{str(path)!r} has {len(points)} points and "
                          f"{len(triangles)} triangles; the rest surface {obj.source!r} has "
                          f"{len(rest.points)} and {len(rest.triangles)}")
        differ = np.flatnonzero(np.any(triangles != rest.triangles, axis=1))
        if len(differ):
            i = differ[0]
            raise t.error("surface", f"{str(path)!r} has the rest surface's counts but "
                          f"different triangles ({len(differ)} differ; first: triangle {i} "
                          f"is {triangles[i].tolist()}, in the rest surface "
                          f"{rest.triangles[i].tolist()})")
        posed = Surface(points, triangles, rest.uv)
        alignment = np.eye(4)
        if t.get("align", bool, True):
            alignment = _rigid_fit(points, obj.flat_points, _vertex_areas(rest))
        pose = GluePose(name, object=obj, placement=placement, posed=posed, alignment=alignment)
    t.finish()
    return pose


def _read_parameters(t: Table, obj: GlueObject) -> tuple[tuple[str, Any], ...]:
    """The generator's keyword parameters from the pose table, checked by one call."""
    function = GENERATORS[obj.generator]
    values = {}
    for parameter in _generator_parameters(function):
        default = ... if parameter.default is inspect.Parameter.empty else parameter.default
        if _parameter_kind(parameter) == "point":
            values[parameter.name] = _point(t, parameter.name, default)
        else:
            values[parameter.name] = t.get(parameter.name, float, default)
    uv = obj.rest.uv
    try:
        posed = np.asarray(function(uv, 1.0, **values), dtype=float)
        flat = np.asarray(function(uv, 0.0, **values), dtype=float)
    except ParameterError as exc:
        raise t.error(exc.parameter, str(exc)) from None
    scale = max(1.0, float(np.abs(uv).max()))
    if posed.shape != (len(uv), 3) or not np.isfinite(posed).all():
        raise t.error("object", f"generator {obj.generator!r} returned shape {posed.shape} "
                      f"or non-finite values for {len(uv)} vertices")
    if flat.shape != posed.shape or np.abs(flat - obj.flat_points).max() > 1e-12 * scale:
        raise t.error("object", f"generator {obj.generator!r} does not return the flat "
                      "sheet (u, v, 0) at load fraction 0")
    return tuple(values.items())


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
