"""Moving fields between two meshes of the same sheet: point location and interpolation.

The elastic problem may live on a coarser mesh than the electrostatic one
(``[elastic] edge_length_mm``, ``elements_through_thickness``). The electrostatic
vertices then move by the elastic displacement evaluated at their rest positions: a
fixed sparse matrix ``T`` (rows: points, columns: elastic nodes) of the elastic shape
functions, so ``u_fine = T u_elastic`` and, for adjoints, ``∂/∂u_elastic = Tᵀ ∂/∂u_fine``.
It is exact where the two discretisations agree: P1 fields restricted to a shared level
are the 2D P1 fields of that level.

Points are located in the 2D triangulation by :class:`mscap.geometry.locate.TriangleLocator`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mscap.errors import MeshError
from mscap.fem import elements as fem
from mscap.geometry.locate import TOLERANCE, TriangleLocator
from mscap.mesh.triangulate import TriMesh

__all__ = ["locate", "p1_matrix", "interpolation_matrix"]

#: Points located per block by :func:`interpolation_matrix`.
POINT_BLOCK = 65536


def locate(mesh: TriMesh, points: np.ndarray, candidates: int = 8,
           locator: TriangleLocator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The triangle of ``mesh`` containing each of ``points`` ``(n, 2)`` and the point's
    barycentric coordinates there ``(n, 3)`` (clipped at 0 and renormalised); ``locator``:
    ``mesh``'s :class:`TriangleLocator`, when the caller locates several batches.

    Raises
    ------
    MeshError
        When a point lies outside the triangulation.
    """
    points = np.asarray(points, dtype=float)
    locator = locator or TriangleLocator(mesh.points, mesh.triangles)
    triangle, bary = locator.locate(points, candidates)
    outside = np.flatnonzero(triangle < 0)
    if len(outside):
        p = points[outside[0]]
        raise MeshError(f"{len(outside)} points lie outside the triangulation, e.g. "
                        f"({p[0]:.6g}, {p[1]:.6g}) mm")
    bary = np.clip(bary, 0.0, None)
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
    points = np.asarray(points, dtype=float)
    # POINT_BLOCK points at a time: the candidate tets' Jacobians and coordinates take
    # about 1.2 kB per point (300 MB for the glove's finer-mesh check all at once).
    locator = TriangleLocator(problem.mesh.mesh2d.points, problem.mesh.mesh2d.triangles)  # built once
    parts = [_shape_values(problem, locator, points[start:start + POINT_BLOCK])
             for start in range(0, len(points), POINT_BLOCK)]
    tet = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=int)
    weights = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, problem.nodes.shape[1]))
    rows = np.arange(len(points))
    nodes = problem.nodes[tet]
    matrix = sp.csr_matrix((weights.ravel(), (np.repeat(rows, nodes.shape[1]), nodes.ravel())),
                           shape=(len(points), problem.n_nodes))
    matrix.sum_duplicates()
    return matrix


def _shape_values(problem, locator: TriangleLocator, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The elastic tet containing each of ``points`` ``(n, 3)`` and its shape functions'
    values there ``(n, nb)`` (see :func:`interpolation_matrix`)."""
    mesh = problem.mesh
    n_tri = len(mesh.mesh2d.triangles)
    triangle, _ = locate(mesh.mesh2d, points[:, :2], locator=locator)
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
    return tet, weights
