"""Moving fields between two meshes of the same sheet: point location and interpolation.

The elastic problem may live on a coarser mesh than the electrostatic one
(``[elastic] edge_length_mm``, ``elements_through_thickness``). The electrostatic
vertices then move by the elastic displacement evaluated at their rest positions: a
fixed sparse matrix ``T`` (rows: points, columns: elastic nodes) of the elastic shape
functions, so ``u_fine = T u_elastic`` and, for adjoints, ``∂/∂u_elastic = Tᵀ ∂/∂u_fine``.
It is exact where the two discretisations agree: P1 fields restricted to a shared level
are the 2D P1 fields of that level.

Point location is vectorised: the k nearest triangle centroids (``scipy.spatial.cKDTree``)
are candidates, the one with the largest smallest barycentric coordinate wins, and k
doubles for the few points not yet inside a candidate.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mscap.fem import elements as fem
from mscap.errors import MeshError
from mscap.mesh.triangulate import TriMesh

__all__ = ["locate", "p1_matrix", "interpolation_matrix"]

#: A point counts as inside a triangle or tet when every barycentric coordinate is above
#: ``-TOLERANCE`` (points on shared edges and on the sheet boundary sit at round-off).
TOLERANCE = 1e-9


def _barycentric_2d(mesh: TriMesh, triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(..., 3)`` of ``points`` ``(..., 2)`` in ``triangles`` ``(...)``."""
    a, b, c = (mesh.points[mesh.triangles[triangles, i]] for i in range(3))
    e1, e2, r = b - a, c - a, points - a
    det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
    l1 = (r[..., 0] * e2[..., 1] - r[..., 1] * e2[..., 0]) / det
    l2 = (e1[..., 0] * r[..., 1] - e1[..., 1] * r[..., 0]) / det
    return np.stack([1.0 - l1 - l2, l1, l2], axis=-1)


def locate(mesh: TriMesh, points: np.ndarray, candidates: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The triangle of ``mesh`` containing each of ``points`` ``(n, 2)`` and the point's
    barycentric coordinates there ``(n, 3)`` (clipped at 0 and renormalised).

    Raises
    ------
    MeshError
        When a point lies outside the triangulation.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=float)
    centroids = mesh.points[mesh.triangles].mean(axis=1)
    tree = cKDTree(centroids)
    triangle = np.zeros(len(points), dtype=np.int64)
    score = np.full(len(points), -np.inf)
    todo = np.arange(len(points))
    k = min(candidates, len(centroids))
    while len(todo):
        _, near = tree.query(points[todo], k=k)
        near = near.reshape(len(todo), -1)
        best = _barycentric_2d(mesh, near, points[todo][:, None, :]).min(axis=2)
        pick = np.argmax(best, axis=1)
        triangle[todo] = near[np.arange(len(todo)), pick]
        score[todo] = best[np.arange(len(todo)), pick]
        if k == len(centroids):
            break
        todo = todo[score[todo] < -TOLERANCE]
        k = min(4 * k, len(centroids))
    outside = np.flatnonzero(score < -TOLERANCE)
    if len(outside):
        p = points[outside[0]]
        raise MeshError(f"{len(outside)} points lie outside the triangulation, e.g. "
                        f"({p[0]:.6g}, {p[1]:.6g}) mm")
    bary = np.clip(_barycentric_2d(mesh, triangle, points), 0.0, None)
    return triangle, bary / bary.sum(axis=1, keepdims=True)


def p1_matrix(mesh: TriMesh, points: np.ndarray) -> sp.csr_matrix:
    """``(n_points, n_vertices)`` P1 interpolation on the triangulation ``mesh`` at
    ``points`` ``(n, 2)``: ``T @ values`` interpolates vertex values (raises
    :class:`MeshError` for points outside, as :func:`locate`)."""
    triangle, bary = locate(mesh, points)
    rows = np.repeat(np.arange(len(points)), 3)
    return sp.csr_matrix((bary.ravel(), (rows, mesh.triangles[triangle].ravel())),
                         shape=(len(points), len(mesh.points)))


def interpolation_matrix(problem, points: np.ndarray) -> sp.csr_matrix:
    """``(n_points, n_nodes)`` values of the elastic problem's shape functions at rest
    positions ``points`` ``(n, 3)``: ``T @ field`` interpolates any nodal field.

    ``problem.mesh`` must come from :func:`mscap.mesh.layered.extrude` (tets numbered slab by
    slab, three per triangle)."""
    mesh = problem.mesh
    points = np.asarray(points, dtype=float)
    n_tri = len(mesh.mesh2d.triangles)
    triangle, _ = locate(mesh.mesh2d, points[:, :2])
    z = mesh.level_z_mm
    slab = np.clip(np.searchsorted(z, points[:, 2], side="right") - 1, 0, len(z) - 2)
    candidates = (slab * 3 * n_tri + 3 * triangle)[:, None] + np.arange(3)[None, :]  # (n, 3)
    inv, _ = fem.jacobians(mesh.points, mesh.tets[candidates.ravel()])
    origin = mesh.points[mesh.tets[candidates.ravel(), 0]]
    local = np.einsum("mij,mj->mi", inv, np.repeat(points, 3, axis=0) - origin).reshape(-1, 3, 3)
    lam = np.concatenate([1.0 - local.sum(axis=2, keepdims=True), local], axis=2)  # (n, 3, 4)
    pick = np.argmax(lam.min(axis=2), axis=1)
    rows = np.arange(len(points))
    if lam[rows, pick].min(axis=1).min(initial=0.0) < -TOLERANCE:
        bad = int(np.argmin(lam[rows, pick].min(axis=1)))
        raise MeshError(f"point {points[bad]} mm is in no tet of the elastic mesh")
    tet = candidates[rows, pick]
    lam = np.clip(lam[rows, pick], 0.0, None)
    lam /= lam.sum(axis=1, keepdims=True)
    if problem.order == 1:
        weights = lam
    else:  # P2: λa(2λa − 1) at the vertices, 4 λa λb at the edge nodes
        a, b = fem.TET_EDGES[:, 0], fem.TET_EDGES[:, 1]
        weights = np.concatenate([lam * (2 * lam - 1), 4 * lam[:, a] * lam[:, b]], axis=1)
    nodes = problem.nodes[tet]
    matrix = sp.csr_matrix((weights.ravel(), (np.repeat(rows, nodes.shape[1]), nodes.ravel())),
                           shape=(len(points), problem.n_nodes))
    matrix.sum_duplicates()
    return matrix
