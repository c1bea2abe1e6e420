"""Boundary data of each pose on a mesh: Dirichlet masks and values, the ball, guesses.

The sheet lies in ``z ∈ [0, thickness]`` with its edges on its in-plane bounding box
(``x_min`` … ``y_max``, every level of the edge). At load fraction ``t``:

* stretch: the grip edges of axis ``a`` sit at ``c_a + λ_a(t) (X_a − c_a)`` with
  ``λ_a(t) = 1 + t (λ_a − 1)`` and ``c`` the box centre; a clamp also holds the other two
  components, a roller only the normal one. Roller poses then fix the fewest extra
  components that remove the remaining rigid motions (see :func:`_roller_anchors`);
* poke: the held edges are clamped; the ball centre is ``d̂`` above first contact at
  ``t = 0`` and ``depth`` below it at ``t = 1``;
* glue: every bottom node follows the glued pose's surface at ``t``.
"""

from __future__ import annotations

import numpy as np

from mscap.fem.elastic.contact import Ball
from mscap.fem.elastic.newton import Loading
from mscap.fem.elastic.problem import ElasticError, ElasticProblem, node_values
from mscap.scene.poses import PokePose, StretchPose

__all__ = ["loading_for", "edge_nodes", "top_surface"]


def _box(problem: ElasticProblem) -> tuple[np.ndarray, np.ndarray]:
    points = problem.mesh.mesh2d.points
    return points.min(axis=0), points.max(axis=0)


def edge_nodes(problem: ElasticProblem, edge: str) -> np.ndarray:
    """Nodes (every level) on a bounding-box edge such as ``"x_min"``."""
    lo, hi = _box(problem)
    axis = "xy".index(edge[0])
    value = lo[axis] if edge.endswith("min") else hi[axis]
    tol = 1e-9 * max(1.0, float(np.max(hi - lo)))
    nodes = np.flatnonzero(np.abs(problem.rest[:, axis] - value) <= tol)
    if not len(nodes):
        raise ElasticError(f"no mesh nodes on the sheet edge {edge} ({'xy'[axis]} = {value:g} mm)")
    return nodes


def top_surface(problem: ElasticProblem) -> tuple[np.ndarray, np.ndarray]:
    """Top-surface nodes and their lumped areas (mm²).

    P1: a third of each adjacent triangle. P2: each triangle is split at its edge
    midpoints into four, and each sub-triangle gives a third of its area to its corners."""
    mesh = problem.mesh
    n2 = len(mesh.mesh2d.points)
    top = (len(mesh.level_z_mm) - 1) * n2
    tri = mesh.mesh2d.triangles + top
    area = 0.5 * np.abs(np.cross(*(mesh.points[tri[:, 1:], :2] - mesh.points[tri[:, :1], :2]).transpose(1, 0, 2)))
    if problem.order == 1:
        corners, weights = tri, np.repeat(area / 3, 3)
    else:
        keys = problem.edge_vertices[:, 0] * len(mesh.points) + problem.edge_vertices[:, 1]
        order = np.argsort(keys)

        def mid(a, b):
            k = np.minimum(a, b) * len(mesh.points) + np.maximum(a, b)
            return problem.n_vertices + order[np.searchsorted(keys[order], k)]
        a, b, c = tri.T
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        sub = np.concatenate([np.stack(s, axis=1) for s in
                              ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
        corners, weights = sub, np.repeat(np.tile(area / 4, 4) / 3, 3)
    areas = np.bincount(corners.ravel(), weights=weights, minlength=problem.n_nodes)
    nodes = np.unique(corners)
    return nodes, areas[nodes]


def loading_for(problem: ElasticProblem, pose) -> Loading:
    """The :class:`~mscap.fem.elastic.newton.Loading` of ``pose`` (stretch, poke or glue)."""
    if isinstance(pose, StretchPose):
        return _stretch(problem, pose)
    if isinstance(pose, PokePose):
        return _poke(problem, pose)
    if pose.kind == "glue":
        return _glue(problem, pose)
    raise ElasticError(f"pose {pose.name!r}: kind {pose.kind!r} needs no elastic solve")


def _stretch(problem: ElasticProblem, pose: StretchPose) -> Loading:
    lo, hi = _box(problem)
    center = 0.5 * (lo + hi)
    fixed = np.zeros((problem.n_nodes, 3), dtype=bool)
    for axis in pose.gripped_axes:
        for side in ("min", "max"):
            nodes = edge_nodes(problem, f"{'xy'[axis]}_{side}")
            if pose.grips == "clamp":
                fixed[nodes] = True
            else:
                fixed[nodes, axis] = True
    if pose.mode == "plane_strain":
        held = 1 - pose.axis
        for side in ("min", "max"):
            fixed[edge_nodes(problem, f"{'xy'[held]}_{side}"), held] = True
    if pose.grips == "roller":
        for node, components in _roller_anchors(problem, pose):
            fixed[node, components] = True
    stretch = np.array(pose.stretch)
    rest = problem.rest

    def targets(t: float) -> np.ndarray:
        x = rest.copy()
        ratio = 1.0 + t * (stretch - 1.0)
        x[:, :2] = center + ratio * (rest[:, :2] - center)
        return x

    return Loading(pose.name, fixed, targets, load_steps=pose.load_steps)


def _roller_anchors(problem: ElasticProblem, pose: StretchPose):
    """Extra components that remove the rigid motions rollers leave free.

    Uniaxial: rollers on the two edges normal to axis a fix u_a there, leaving the other
    in-plane translation, the z translation and the rotation about axis a; fix both at one
    bottom corner of a gripped edge and z at the other bottom corner of that edge.
    Biaxial and plane strain: only the z translation is left; fix z at one corner."""
    lo, hi = _box(problem)
    bottom = np.flatnonzero(problem.rest[:, 2] == problem.rest[:, 2].min())
    a = pose.axis
    other = 1 - a
    edge = bottom[np.abs(problem.rest[bottom, a] - lo[a]) <= 1e-9 * max(1.0, float(np.max(hi - lo)))]
    first = edge[np.argmin(problem.rest[edge, other])]
    last = edge[np.argmax(problem.rest[edge, other])]
    if pose.mode == "uniaxial":
        return [(first, [other, 2]), (last, [2])]
    return [(first, [2])]


def _poke(problem: ElasticProblem, pose: PokePose) -> Loading:
    fixed = np.zeros((problem.n_nodes, 3), dtype=bool)
    for edge in pose.held_edges:
        fixed[edge_nodes(problem, edge)] = True
    nodes, areas = top_surface(problem)
    lo, hi = _box(problem)
    cx, cy = pose.center_mm
    if not (lo[0] < cx < hi[0] and lo[1] < cy < hi[1]):
        raise ElasticError(f"pose {pose.name!r}: ball centre ({cx:g}, {cy:g}) mm lies outside the sheet")
    z_top = float(problem.mesh.level_z_mm[-1])
    dhat = pose.barrier_distance_mm
    kappa = pose.barrier_stiffness_MPa_per_mm or 0.01 * float(problem.mu.min()) / dhat
    rest = problem.rest

    def ball(t: float) -> Ball:
        z = z_top + pose.radius_mm + dhat - t * (pose.depth_mm + dhat)
        return Ball(np.array([cx, cy, z]), pose.radius_mm, nodes, areas, dhat, kappa)

    n2 = len(problem.mesh.mesh2d.points)
    vertex_2d = np.arange(problem.n_vertices) % n2

    def column_push(x: np.ndarray, b: Ball) -> np.ndarray:
        # Shift whole columns down: a vertical shift constant along each column is a
        # shear with det F = 1, so no element inverts.
        x = x.copy()
        for _ in range(4):
            shift = b.push_out(x, 0.5 * dhat)
            if not shift.any():
                break
            need = np.zeros(problem.n_nodes)
            need[b.nodes] = shift
            column = np.zeros(n2)
            if problem.order == 2:
                ends = problem.edge_vertices[need[problem.n_vertices:] > 0]
                np.maximum.at(column, vertex_2d[ends.ravel()],
                              np.repeat(2 * need[problem.n_vertices:][need[problem.n_vertices:] > 0], 2))
            np.maximum.at(column, vertex_2d, need[:problem.n_vertices])
            x[:, 2] -= node_values(problem, column[vertex_2d])
        return x

    return Loading(pose.name, fixed, lambda t: rest, ball=ball, load_steps=pose.load_steps,
                   column_push=column_push)


def _glue(problem: ElasticProblem, pose) -> Loading:
    rest = problem.rest
    z0 = float(rest[:, 2].min())
    bottom = np.flatnonzero(rest[:, 2] == z0)
    fixed = np.zeros((problem.n_nodes, 3), dtype=bool)
    fixed[bottom] = True
    xy = rest[:, :2]

    def targets(t: float) -> np.ndarray:
        x = rest.copy()
        x[bottom] = pose.positions(xy[bottom], t)
        return x

    def guess(x: np.ndarray, t: float) -> np.ndarray:
        # Each node at height h above the bottom goes to P(q) + h n(q): the sheet follows
        # the surface with straight normals (Kirchhoff–Love), exact for a thin sheet.
        position, jac = pose.positions_and_jacobian(xy, t)
        normal = np.cross(jac[:, :, 0], jac[:, :, 1])
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        return position + (rest[:, 2] - z0)[:, None] * normal

    return Loading(pose.name, fixed, targets, load_steps=1, guess=guess)
