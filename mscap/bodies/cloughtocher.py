"""The C1 Clough–Tocher interpolant on a given planar triangulation.

Each triangle is split at its centroid into three; on each part the interpolant is a
cubic in Bézier form. Together they match the vertex values and vertex gradients and
are C1 across the split lines and across every edge two triangles share. The vertex
gradients are those that minimise the curvature of the cubics along the triangulation's
edges (the global minimum-norm-network estimate of Nielson 1983 and Renka & Cline
1984).

This is scipy's scheme (``scipy.interpolate.CloughTocher2DInterpolator``), re-implemented
vectorised on a triangulation the caller gives, because scipy only builds it on the
Delaunay triangulation of the points (a ``Delaunay`` object is the only triangulation it
accepts); that would ignore a surface's own connectivity and fill in its concave parts
and holes. The Bézier control points, the affine-invariant cross-boundary directions
(centroid of the neighbour) and the boundary rule are scipy's; the curvature functional
is solved exactly by one sparse factorisation instead of scipy's Gauss–Seidel to
``tol = 1e-6``. On a Delaunay triangulation both agree to round-off
(``tests/bodies/test_glue.py``).

References
----------
G. M. Nielson, "A method for interpolating scattered data based upon a minimum norm
network", Math. Comp. 40, 253 (1983).

R. J. Renka and A. K. Cline, "A triangle-based C1 interpolation method", Rocky Mountain
J. Math. 14, 223 (1984).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from mscap.geometry.locate import TriangleLocator

__all__ = ["CloughTocher"]


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
        self._locator = None

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
        """Triangle (``-1`` outside) and barycentric coordinates of each point
        (:class:`mscap.geometry.locate.TriangleLocator`: points within 1e-9 of the domain's
        size outside a boundary edge count as on it)."""
        if self._locator is None:
            self._locator = TriangleLocator(self.points, self.triangles)
        return self._locator.locate(xy)

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
