"""Design control: hierarchical linear blend skinning of the sheet plane (paper §5).

Control points are mesh vertices spread evenly (by arc length) along the capacitor
outlines; each carries a 2D translation ``q_j``. Every 2D vertex moves by a blend of them,

    X2d(q) = X2d0 + W q,        W: (n, c),   q: (c, 2),

and every 3D vertex follows the 2D vertex it sits above, in-plane. Column ``j`` of ``W``
solves a boundary-value problem on the sheet with handles: it is 1 at control ``j``, 0 at
the other controls and 0 on the sheet's outer boundary. The outer boundary acts as one
more, fixed handle with weight ``w_∂ = 1 − Σ_j W_ij``; what holds exactly is

    W[control_vertex] = I,   W[outer boundary] = 0,   Σ_j W_ij + w_∂,i = 1,

so a control moves by exactly its own ``q_j`` and the sheet's edge never moves.

``method="bbw"``: bounded biharmonic weights (Jacobson et al. 2011, libigl's ``igl.bbw``):
each column minimises the Laplacian energy ``∫ (Δw)²`` subject to ``0 ≤ w ≤ 1`` and the
handle values; the ``c + 1`` columns (with ``w_∂``) are then divided by their row sum, so
``W ≥ 0`` and the partition of unity above holds to round-off. By default (``coarse``)
bbw is solved on a skinning mesh graded to the control spacing and interpolated linearly
(:func:`skinning_weights`), which keeps all of the above.
``method="harmonic"``: ``Δw = 0`` with the cotangent Laplacian (scipy, no libigl). Columns
sum with ``w_∂`` to 1 by linearity and lie in [0, 1] where the mesh is Delaunay (all cotangent
weights ≥ 0, discrete maximum principle); point handles make harmonic weights spiky (a
point has zero capacity in 2D), which is why bbw is the default.

Refinement (the "hierarchy"): :meth:`Deformer.refined` keeps the control vertices and adds
one between each pair of neighbours on the outline, on the current geometry, with fresh
weights; the optimiser restarts from ``q = 0`` there.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from mscap.errors import MeshError
from mscap.geometry.layout import Layout
from mscap.geometry.polygons import segment_projection
from mscap.fem.transfer import p1_matrix
from mscap.mesh.triangulate import TriMesh
from mscap.scene.settings import SKINNING_METHODS

__all__ = ["Deformer", "build_deformer", "skinning_weights", "outer_boundary_vertices",
           "outline_chains", "cotangent_stiffness", "METHODS"]

log = logging.getLogger(__name__)

METHODS = SKINNING_METHODS


@dataclass(frozen=True)
class Deformer:
    """Linear blend skinning of a 2D mesh by control-point translations (mm).

    Attributes
    ----------
    mesh2d
        The rest triangulation; ``rest2d = mesh2d.points``.
    weights
        ``(n, c)`` skinning weights ``W``.
    control_vertex
        ``(c,)`` mesh vertex of each control point, outline by outline, along each outline.
    control_outline
        ``(c,)`` outline (capacitor) index of each control point.
    outline_vertices
        Per outline, the mesh vertices on it in the polygon's order (counter-clockwise
        for a :class:`~mscap.geometry.layout.Layout`), from its first vertex.
    method, coarse
        How the weights were made (:func:`skinning_weights`).
    """

    mesh2d: TriMesh
    weights: np.ndarray
    control_vertex: np.ndarray
    control_outline: np.ndarray
    outline_vertices: tuple[np.ndarray, ...]
    method: str = "bbw"
    coarse: bool = True

    def __post_init__(self):
        for array in (self.weights, self.control_vertex, self.control_outline, *self.outline_vertices):
            array.setflags(write=False)

    @property
    def rest2d(self) -> np.ndarray:
        """``(n, 2)`` rest positions ``X2d0``."""
        return self.mesh2d.points

    @property
    def controls(self) -> np.ndarray:
        """``(c, 2)`` rest positions of the control points."""
        return self.mesh2d.points[self.control_vertex]

    @property
    def n_controls(self) -> int:
        return len(self.control_vertex)

    @property
    def boundary_weight(self) -> np.ndarray:
        """``(n,)`` weight ``w_∂ = 1 − Σ_j W_ij`` of the fixed outer-boundary handle."""
        return 1.0 - self.weights.sum(axis=1)

    def zeros(self) -> np.ndarray:
        """``(c, 2)`` zero translations (the rest geometry)."""
        return np.zeros((self.n_controls, 2))

    def _q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.size != 2 * self.n_controls:
            raise ValueError(f"q has {q.size} entries; expected {self.n_controls} controls × 2")
        return q.reshape(self.n_controls, 2)

    def displacement2d(self, q) -> np.ndarray:
        """``(n, 2)`` in-plane displacement ``W q`` (mm)."""
        return self.weights @ self._q(q)

    def points2d(self, q) -> np.ndarray:
        """``(n, 2)`` deformed 2D positions ``X2d0 + W q`` (mm)."""
        return self.rest2d + self.displacement2d(q)

    def points3d(self, mesh, q) -> np.ndarray:
        """``(N, 3)`` positions of a :class:`~mscap.mesh.layered.LayeredMesh` extruded from this
        2D mesh: vertex ``level * n + v`` moves in-plane by the displacement of ``v``."""
        n = len(self.rest2d)
        if len(mesh.mesh2d.points) != n:
            raise ValueError(f"layered mesh has {len(mesh.mesh2d.points)} 2D vertices; the deformer {n}")
        points = np.array(mesh.points, dtype=float)
        points[:, :2] += np.tile(self.displacement2d(q), (len(points) // n, 1))
        return points

    def vjp(self, gradient) -> np.ndarray:
        """``(c, 2)`` gradient with respect to ``q`` of a function of the positions.

        ``gradient`` is ``∂J/∂X2d`` ``(n, 2)``, or ``∂J/∂X3d`` ``(N, 3)`` of a layered mesh,
        whose levels' x, y components are summed first (every level moves with its 2D
        vertex; z does not depend on ``q``). Returns ``Wᵀ g``.
        """
        g = np.asarray(gradient, dtype=float)
        n = len(self.rest2d)
        if g.ndim == 2 and g.shape[1] == 3 and len(g) % n == 0:
            g = g.reshape(-1, n, 3)[:, :, :2].sum(axis=0)
        if g.shape != (n, 2):
            raise ValueError(f"gradient has shape {g.shape}; expected ({n}, 2) or (L*{n}, 3)")
        return self.weights.T @ g

    def outlines(self, q) -> tuple[np.ndarray, ...]:
        """Deformed capacitor outlines, one ``(m_i, 2)`` polygon per outline through all its
        mesh vertices. The map is affine on each triangle, so this polyline is the exact
        image of the rest outline."""
        points = self.points2d(q)
        return tuple(points[chain] for chain in self.outline_vertices)

    def layout(self, q) -> Layout:
        """The deformed outlines as a :class:`~mscap.geometry.layout.Layout`."""
        return Layout(self.outlines(q))

    def refined(self, q=None) -> "Deformer":
        """About twice the control points on the same outlines, on the geometry at ``q``.

        The old control vertices stay; one outline vertex nearest the arc-length midpoint is
        added between each pair of neighbouring controls (none where they are adjacent on
        the mesh). The new deformer's rest is ``points2d(q)``, so its ``q`` starts at 0.
        """
        points = self.rest2d if q is None else self.points2d(q)
        mesh = TriMesh(points, self.mesh2d.triangles, self.mesh2d.capacitor_of_triangle)
        vertices, outline_of = [], []
        for i, chain in enumerate(self.outline_vertices):
            arc, perimeter = _arc_length(points[chain])
            on = np.flatnonzero(np.isin(chain, self.control_vertex[self.control_outline == i]))
            span = (np.roll(on, -1) - on) % len(chain)  # chain steps to the next control
            gap = (arc[np.roll(on, -1)] - arc[on]) % perimeter
            span[span == 0], gap[gap == 0] = len(chain), perimeter  # a single control
            allowed = (np.arange(len(chain))[None, :] - on[:, None]) % len(chain)
            allowed = (allowed > 0) & (allowed < span[:, None])  # strictly between the two controls
            added = _nearest_on_chain(arc, perimeter, arc[on] + 0.5 * gap, allowed)
            keep = np.unique(np.concatenate([on, added]))
            vertices.append(chain[keep])
            outline_of.append(np.full(len(keep), i))
        control_vertex = np.concatenate(vertices)
        weights = skinning_weights(mesh, control_vertex, self.outline_vertices, self.method, self.coarse)
        return Deformer(mesh, weights, control_vertex, np.concatenate(outline_of), self.outline_vertices,
                        self.method, self.coarse)


def build_deformer(mesh2d: TriMesh, outlines, *, spacing_mm: float | None = None,
                   count: int | Sequence[int] | None = None, method: str = "bbw",
                   coarse: bool = True) -> Deformer:
    """Skinning deformer with control points evenly along each outline.

    Parameters
    ----------
    mesh2d
        A triangulation with every outline embedded (:func:`mscap.mesh.triangulate.triangulate`).
    outlines
        The capacitor polygons (a :class:`~mscap.geometry.layout.Layout` or its ``outlines``).
    spacing_mm, count
        Exactly one: the arc length between controls (``max(3, round(perimeter /
        spacing_mm))`` per outline) or the number per outline (one int or one per outline).
        Samples start at each polygon's first vertex; each takes the outline vertex nearest
        in arc length (duplicates on a coarse mesh are dropped, with a warning).
    method, coarse
        ``"bbw"`` (needs libigl) or ``"harmonic"``; see :func:`skinning_weights`.
    """
    outlines = tuple(np.asarray(o, dtype=float) for o in getattr(outlines, "outlines", outlines))
    if (spacing_mm is None) == (count is None):
        raise ValueError("give exactly one of spacing_mm and count")
    chains = outline_chains(mesh2d, outlines)
    vertices, outline_of = [], []
    for i, chain in enumerate(chains):
        arc, perimeter = _arc_length(mesh2d.points[chain])
        if spacing_mm is not None:
            wanted = max(3, int(round(perimeter / spacing_mm)))
        else:
            wanted = int(count if np.isscalar(count) else count[i])
        keep = np.unique(_nearest_on_chain(arc, perimeter, perimeter * np.arange(wanted) / wanted))
        if len(keep) < wanted:
            log.warning("outline %d: %d control points asked, %d distinct mesh vertices found",
                        i, wanted, len(keep))
        vertices.append(chain[keep])
        outline_of.append(np.full(len(keep), i))
    control_vertex = np.concatenate(vertices)
    weights = skinning_weights(mesh2d, control_vertex, chains, method, coarse)
    log.info("deformer: %d control points on %d outlines (%s)", len(control_vertex), len(chains), method)
    return Deformer(mesh2d, weights, control_vertex, np.concatenate(outline_of), chains, method, coarse)


def _arc_length(polyline: np.ndarray) -> tuple[np.ndarray, float]:
    """Arc length at each vertex of a closed polyline from its first vertex, and the perimeter."""
    lengths = np.linalg.norm(np.roll(polyline, -1, axis=0) - polyline, axis=1)
    return np.concatenate([[0.0], np.cumsum(lengths[:-1])]), float(lengths.sum())


def _nearest_on_chain(arc: np.ndarray, perimeter: float, target: np.ndarray,
                      allowed: np.ndarray | None = None) -> np.ndarray:
    """Per target arc length, the chain position nearest along the closed curve among the
    ``allowed`` ones (``(targets, m)`` mask; targets with none allowed are dropped)."""
    distance = np.abs((arc[None, :] - target[:, None] + 0.5 * perimeter) % perimeter - 0.5 * perimeter)
    if allowed is None:
        return np.argmin(distance, axis=1)
    return np.argmin(np.where(allowed, distance, np.inf), axis=1)[allowed.any(axis=1)]


def outer_boundary_vertices(mesh: TriMesh) -> np.ndarray:
    """Sorted vertices on edges that belong to one triangle only (the sheet's edge)."""
    pairs = np.sort(mesh.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, counts = np.unique(pairs, axis=0, return_counts=True)
    return np.unique(edges[counts == 1])


def outline_chains(mesh: TriMesh, outlines: Sequence[np.ndarray], rel_tol: float = 1e-9) -> tuple[np.ndarray, ...]:
    """The mesh vertices on each polygon, in the polygon's order from its first vertex
    (a vertex of the mesh when the polygon is embedded, as :func:`triangulate` does).

    Raises
    ------
    MeshError
        When an outline is not embedded: consecutive vertices on it are no mesh edge.
    """
    points = mesh.points
    tol = rel_tol * float(np.ptp(points, axis=0).max())
    edges = mesh.edges()
    edge_key = edges[:, 0] * len(points) + edges[:, 1]
    chains = []
    for i, polygon in enumerate(outlines):
        box = (points >= polygon.min(axis=0) - tol) & (points <= polygon.max(axis=0) + tol)
        near = np.flatnonzero(box.all(axis=1))
        b = np.roll(polygon, -1, axis=0)
        distance, t, _ = segment_projection(points[near, None, :], polygon[None], b[None])
        segment = np.argmin(distance, axis=1)
        hit = distance[np.arange(len(near)), segment] <= tol
        segment = segment[hit]
        lengths = np.linalg.norm(b - polygon, axis=1)
        arc = np.concatenate([[0.0], np.cumsum(lengths[:-1])])[segment] + t[hit, segment] * lengths[segment]
        arc[arc >= lengths.sum() - tol] = 0.0  # the first vertex, reached from the last segment
        chain = near[hit][np.argsort(arc)]
        key = np.sort(np.c_[chain, np.roll(chain, -1)], axis=1) @ np.array([len(points), 1])
        if len(chain) < 3 or not np.isin(key, edge_key).all():
            raise MeshError(f"outline {i} is not embedded in the 2D mesh: {len(chain)} vertices lie on it "
                            "and consecutive ones are not all joined by mesh edges")
        chains.append(chain)
    return tuple(chains)


def cotangent_stiffness(points: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """``(n, n)`` P1 stiffness ``K_ij = ∫ ∇φ_i·∇φ_j``: ``−½(cot α_ij + cot β_ij)`` off the
    diagonal (the angles opposite edge ij), row sums zero. Symmetric positive semidefinite."""
    n = len(points)
    rows, cols, vals = [], [], []
    for k in range(3):  # corner k, opposite edge (i, j)
        i, j = triangles[:, (k + 1) % 3], triangles[:, (k + 2) % 3]
        u, v = points[i] - points[triangles[:, k]], points[j] - points[triangles[:, k]]
        cot = np.einsum("ij,ij->i", u, v) / np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        rows += [i, j, i, j]
        cols += [j, i, i, j]
        vals += [-0.5 * cot, -0.5 * cot, 0.5 * cot, 0.5 * cot]
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def skinning_weights(mesh: TriMesh, control_vertex: np.ndarray, chains: Sequence[np.ndarray] = (),
                     method: str = "bbw", coarse: bool = True) -> np.ndarray:
    """``(n, c)`` weights: 1 at control ``j``, 0 at the other controls and on the outer boundary.

    With ``method="bbw"`` and ``coarse``, the weights are solved on a skinning mesh of the
    same sheet (:func:`_skinning_mesh`, needs the outline ``chains``) and interpolated
    linearly onto ``mesh``: libigl's active-set solver costs about a second per control on a
    10k-vertex mesh, and the weights need only resolve the control spacing. Linear
    interpolation keeps ``0 ≤ W``, the partition of unity and the handle values, and makes
    the deformation affine on each skinning triangle. When the skinning mesh would not be
    smaller than ``mesh``, bbw is solved on ``mesh`` itself. ``coarse`` is ignored by the
    harmonic method (one sparse solve). See the module docstring for the rest.
    """
    if method not in METHODS:
        raise ValueError(f"unknown skinning method {method!r}; expected one of {', '.join(METHODS)}")
    if (mesh.areas() <= 0).any():
        raise MeshError(f"{int((mesh.areas() <= 0).sum())} triangles are inverted or degenerate")
    control_vertex = np.asarray(control_vertex, dtype=np.int64)
    boundary = outer_boundary_vertices(mesh)
    if np.isin(control_vertex, boundary).any() or len(np.unique(control_vertex)) < len(control_vertex):
        raise MeshError("control points must be distinct and off the sheet's outer boundary")
    n, c = len(mesh.points), len(control_vertex)
    if method == "harmonic":
        stiffness = cotangent_stiffness(mesh.points, mesh.triangles).tocsc()
        free = np.setdiff1d(np.arange(n), np.concatenate([control_vertex, boundary]))
        weights = np.zeros((n, c))
        weights[free] = -spla.splu(stiffness[free][:, free]).solve(stiffness[free][:, control_vertex].toarray())
    elif coarse:
        if not len(chains):
            raise ValueError("coarse bbw needs the outline chains (see outline_chains)")
        skin, skin_control = _skinning_mesh(mesh, control_vertex, chains)
        if len(skin.points) >= len(mesh.points):
            weights = _bbw(mesh, control_vertex)
        else:
            # P1 on the skinning mesh (same sheet polygon, so every vertex lies in it).
            weights = p1_matrix(skin, mesh.points) @ _bbw(skin, skin_control)
    else:
        weights = _bbw(mesh, control_vertex)
    weights[boundary] = 0.0  # exact handle values, free of solver and interpolation round-off
    weights[control_vertex] = np.eye(c)
    return weights


def _bbw(mesh: TriMesh, control_vertex: np.ndarray) -> np.ndarray:
    """Bounded biharmonic weights of the controls plus the outer-boundary handle
    (libigl solves each column alone), divided by their row sums; returns the controls' columns."""
    import igl  # imported here: only bbw and its skinning mesh need it

    c = len(control_vertex)
    handles = np.concatenate([control_vertex, outer_boundary_vertices(mesh)])
    values = np.zeros((len(handles), c + 1))
    values[np.arange(c), np.arange(c)] = 1.0
    values[c:, c] = 1.0
    full = igl.bbw(np.ascontiguousarray(mesh.points, dtype=float),
                   np.ascontiguousarray(mesh.triangles, dtype=np.int64), handles, values)
    full = np.clip(full, 0.0, 1.0)
    return full[:, :c] / full.sum(axis=1, keepdims=True)


def _corners(polyline: np.ndarray, rel_tol: float = 1e-9) -> np.ndarray:
    """Boolean per vertex of a closed polyline: does it turn there?"""
    before = polyline - np.roll(polyline, 1, axis=0)
    after = np.roll(polyline, -1, axis=0) - polyline
    cross = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0]
    return np.abs(cross) > rel_tol * np.linalg.norm(before, axis=1) * np.linalg.norm(after, axis=1)


def _skinning_mesh(mesh: TriMesh, control_vertex: np.ndarray, chains: Sequence[np.ndarray],
                   edges_per_spacing: float = 4.0) -> tuple[TriMesh, np.ndarray]:
    """A triangulation of the same sheet whose outlines are the chains' corners plus the
    control points, with edges of a quarter of the median control spacing along them
    (graded to 4× that over 8× that distance), and the index of each control in it.

    Every vertex of ``mesh`` on an outline lies on an edge of this mesh's outline, and
    every vertex on the sheet's edge on its edge, so interpolated weights stay exact there.
    """
    import igl
    from scipy.spatial import cKDTree

    from mscap.mesh.triangulate import triangulate
    from mscap.scene.settings import MeshSettings

    points = mesh.points
    loop = igl.boundary_loop(np.ascontiguousarray(mesh.triangles, dtype=np.int64))
    if len(loop) != len(outer_boundary_vertices(mesh)):
        raise MeshError("the sheet has holes; build the deformer with coarse=False")
    polygons, gaps = [], []
    for chain in chains:
        is_control = np.isin(chain, control_vertex)
        polygons.append(points[chain[_corners(points[chain]) | is_control]])
        arc, perimeter = _arc_length(points[chain])
        gaps.append((np.diff(arc[is_control], append=arc[is_control][0] + perimeter)))
    # no finer than the mesh's own outline edges: past that the mesh itself is the better choice
    edge = np.median(np.concatenate([np.linalg.norm(points[np.roll(c, -1)] - points[c], axis=1) for c in chains]))
    h = max(float(np.median(np.concatenate(gaps))) / edges_per_spacing, float(edge))
    sheet = points[loop[_corners(points[loop])]]
    skin = triangulate(sheet, Layout(tuple(polygons)), MeshSettings(4 * h, h, 8 * h), auxiliary=True)
    distance, skin_control = cKDTree(skin.points).query(points[control_vertex])
    if distance.max() > 1e-9 * float(np.ptp(points, axis=0).max()):
        raise MeshError("a control point is not a vertex of the skinning mesh")
    log.info("skinning mesh: %d vertices for %d control points", len(skin.points), len(control_vertex))
    return skin, skin_control
