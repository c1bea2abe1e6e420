"""Gradient of a pose's capacitances with respect to the rest geometry (paper §5): the
electrostatic shape derivative, one elastic adjoint solve per pose, and the rest-position
derivative of the elastic equilibrium.

The discrete model. Rest positions ``X_f`` (electrostatic vertices) and ``X_e`` (elastic
mesh vertices; P2 edge nodes are their edges' midpoints) give a pose's equilibrium ``x``:
``g_F(x, X_e) = 0`` on the free dofs, ``x_D = D(X_e)`` on the Dirichlet dofs, with ``g``
the gradient of the elastic energy ``Σ_e vol_e Σ_q w_q ψ(F_eq)`` plus, for a poke, the
ball barrier ``κ Σ_i a_i(X_e) b(d_i(x))`` (lumped areas of the rest top surface). The
electrostatic vertices are ``x_f = X_f + T (x − X_e)`` with ``T`` the transfer matrix
*held fixed* (built once at the rest meshes; it is part of the model, not re-located
when X moves), and ``J = Σ_j w_j C_j(x_f)``. The Lamé parameters of every tet are fixed
numbers (they depend on heights only, and the design moves vertices in-plane).

With ``g_f = ∂J/∂x_f`` and ``r = Tᵀ g_f`` (= ∂J/∂x), one solve ``H λ = r`` with the exact
Hessian H at ``x`` and ``λ_D = 0`` (the kept factorisation of
:func:`mscap.fem.elastic.newton.solve_pose`, whose Dirichlet rows are identity rows) gives

    dJ/dX_f = g_f,
    dJ/dX_e = −Tᵀ g_f − ∂/∂X_e [λ · g(x, X_e)] + (∂D/∂X_e)ᵀ (r − H λ)_D,

the last term the Dirichlet data's dependence on X (grips c + s ⊙ (X − c) with the box
centre c fixed, held edges x_D = X_D, glue x_D = P(X_D,xy)). On a shared mesh x_f is
``x`` itself: no direct term, ``r`` is ``g_f`` padded, and all of dJ/dX is returned as
the elastic part (``fine`` is zero); always add the two parts of the same positions.

Mixed derivative of one element at one quadrature point (``G = Dm⁻¹`` the inverse rest
Jacobian ``Dm = [X1 − X0, X2 − X0, X3 − X0]``, ``F = Φ G`` with ``Φ = xᵀ D_q`` fixed,
``L = Λ G`` with ``Λ = λᵀ D_q``; ``dG = −G dDm G``, ``d vol = vol tr(G dDm)``):

    ∂/∂Dm [vol P(F) : L] = vol [ (P : L) Gᵀ − Fᵀ dP[L] Gᵀ − Lᵀ P Gᵀ ],

(:func:`mscap.fem.elastic.neohookean.piola_differential` gives ``dP[L]``), then column k of it goes to
vertex k + 1 and minus their sum to vertex 0. P2 is the same per quadrature point.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from mscap.errors import AdjointError
from mscap.fem import electrostatic
from mscap.fem.elastic import neohookean
from mscap.fem.elastic.contact import Ball, barrier_derivatives
from mscap.fem.elastic.loading import loading_for
from mscap.fem.elastic.newton import ElasticState, Loading, NewtonSettings
from mscap.fem.elastic.problem import ElasticProblem, node_values, rest_geometry
from mscap.fem.petsc import LinearSolver
from mscap.profile import phase, timed
from mscap.fem.simulate import solve_poses
from mscap.mesh.layered import LayeredMesh
from mscap.scene.poses import PokePose, StretchPose


__all__ = ["AdjointError", "RestGradient", "pose_rest_gradient", "elastic_rest_vjp", "ball_rest_vjp",
           "dirichlet_vjp", "problem_at", "moved", "solve_moved_pose"]

log = logging.getLogger(__name__)


class RestGradient(NamedTuple):
    """``∂J/∂X`` (pF/mm) with respect to the electrostatic vertices ``fine`` ``(N_f, 3)``
    and the elastic mesh vertices ``elastic`` ``(n_vertices, 3)`` (empty without an elastic
    problem). On a shared mesh both are derivatives with respect to the same positions:
    the gradient is their sum (``fine`` is then zero for every elastic pose)."""

    fine: np.ndarray
    elastic: np.ndarray


@phase("adjoint")
def pose_rest_gradient(sim, pose_index: int, weights, pose) -> RestGradient:
    """Gradient of ``Σ_j w_j C_j`` (pF) of one pose with respect to the rest positions.

    Parameters
    ----------
    sim
        A :class:`~mscap.fem.simulate.Simulation` run with ``keep_factorisation=True``.
    pose_index
        The pose's index into ``sim.poses``.
    weights
        ``(k,)`` weights ``w_j`` (for an objective: ``∂J/∂C`` of this pose).
    pose
        The pose ``sim.poses[pose_index]`` was solved for (its Dirichlet data and loads).
    """
    started = time.perf_counter()
    result = sim.poses[pose_index]
    g_f = electrostatic.capacitance_vjp(sim.electro, result.capacitances, weights, result.vertices)
    problem = sim.elastic
    if result.state is None:
        n = 0 if problem is None else problem.n_vertices
        return RestGradient(g_f, np.zeros((n, 3)))
    state = result.state
    if state.operator is None:
        raise AdjointError(f"pose {pose.name!r}: no factorised Hessian kept; run simulate(scene, "
                           "keep_factorisation=True)")
    loading = loading_for(problem, pose)
    fixed = loading.fixed
    if sim.transfer is None:  # shared mesh: x_f = x[:N_f]
        r = np.zeros((problem.n_nodes, 3))
        r[:len(g_f)] = g_f
        fine, direct = np.zeros_like(g_f), np.zeros_like(r)
    else:
        r = sim.transfer.T @ g_f
        fine, direct = g_f, -r
    vjp_done = time.perf_counter()
    rhs = np.where(fixed, 0.0, r)
    adjoint = state.operator.solve(rhs.ravel()).reshape(-1, 3)
    adjoint[fixed] = 0.0
    solved = time.perf_counter()
    x = state.nodes
    reaction = np.where(fixed, r - _hessian_product(problem, x, adjoint, fixed.any(axis=1)), 0.0)
    nodal = direct + dirichlet_vjp(problem, pose, loading, reaction)
    elastic = _fold(problem, nodal) + elastic_rest_vjp(problem, x, adjoint)
    if loading.ball is not None:
        elastic += ball_rest_vjp(problem, loading.ball(1.0), x, adjoint)
    log.info("pose %s: rest gradient in %.2f s (capacitance vjp %.2f s, adjoint solve %.2f s)", pose.name,
             time.perf_counter() - started, vjp_done - started, solved - vjp_done)
    return RestGradient(fine, elastic)


@timed("assembly")
def elastic_rest_vjp(problem: ElasticProblem, x: np.ndarray, adjoint: np.ndarray) -> np.ndarray:
    """``−∂/∂X [λ · ∇_x E(x, X)]`` ``(n_vertices, 3)`` at node positions ``x`` for the
    adjoint ``λ = adjoint`` ``(n_nodes, 3)``: the elastic energy's mixed second derivative
    contracted with λ, with respect to the rest vertex positions (μ, λ_Lamé fixed)."""
    el, nodes = problem.element, problem.nodes
    out = np.zeros((problem.n_vertices, 3))
    for start in range(0, len(nodes), problem.block):
        part = slice(start, start + problem.block)
        G, vol = problem.rest_inv[part], problem.rest_vol[part]
        mu, lame = problem.mu[part], problem.lam[part]
        xt = np.swapaxes(x[nodes[part]], 1, 2)
        lt = np.swapaxes(adjoint[nodes[part]], 1, 2)
        gt = np.swapaxes(G, 1, 2)
        d_dm = np.zeros_like(G)
        for q, w in enumerate(el.weights):
            F = xt @ el.gradients[q] @ G
            L = lt @ el.gradients[q] @ G
            P = neohookean.first_piola(F, mu, lame)
            dP = neohookean.piola_differential(F, L, mu, lame)
            PL = np.einsum("mij,mij->m", P, L)
            d_dm += w * (PL[:, None, None] * gt - np.swapaxes(F, 1, 2) @ dP @ gt
                         - np.swapaxes(L, 1, 2) @ P @ gt)
        d_dm *= vol[:, None, None]
        # Dm's column k is X_{k+1} − X_0.
        local = np.concatenate([-d_dm.sum(axis=2)[:, None, :], np.swapaxes(d_dm, 1, 2)], axis=1)
        vertices = problem.mesh.tets[part].ravel()
        for i in range(3):
            out[:, i] -= np.bincount(vertices, weights=local[:, :, i].ravel(), minlength=len(out))
    return out


@timed("assembly")
def ball_rest_vjp(problem: ElasticProblem, ball: Ball, x: np.ndarray, adjoint: np.ndarray) -> np.ndarray:
    """``−∂/∂X [λ · ∇_x (κ Σ_i a_i(X) b(d_i(x)))]`` ``(n_vertices, 3)``: the barrier's
    rest dependence through the lumped top-surface areas ``a_i`` (as
    :func:`mscap.fem.elastic.loading.top_surface`), ``a_i = Σ_t c_ti area_t``."""
    w = x[ball.nodes] - ball.center
    rho = np.linalg.norm(w, axis=1)
    active = np.flatnonzero(rho - ball.radius < ball.dhat)
    db, _ = barrier_derivatives(rho[active] - ball.radius, ball.dhat)
    weight = np.zeros(problem.n_nodes)  # ∂(λ · g_ball)/∂a_i
    weight[ball.nodes[active]] = ball.stiffness * db * np.einsum(
        "ij,ij->i", w[active] / rho[active, None], adjoint[ball.nodes[active]])
    tri, corners, share = _top_triangles(problem)
    per_triangle = weight[corners] @ share
    p = problem.mesh.points[tri, :2]  # (T, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    sign = np.sign(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    out = np.zeros((problem.n_vertices, 3))
    for j in range(3):  # ∂|area|/∂p_j = ½ sign · (y_{j+1} − y_{j+2}, x_{j+2} − x_{j+1})
        a, b = p[:, (j + 1) % 3], p[:, (j + 2) % 3]
        d_area = 0.5 * sign[:, None] * np.stack([a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]], axis=1)
        for i in range(2):
            out[:, i] -= np.bincount(tri[:, j], weights=per_triangle * d_area[:, i], minlength=len(out))
    return out


def dirichlet_vjp(problem: ElasticProblem, pose, loading: Loading, v: np.ndarray) -> np.ndarray:
    """``(∂x_D/∂X)ᵀ v`` ``(n_nodes, 3)`` (per node, P2 edge nodes separate) for ``v``
    ``(n_nodes, 3)`` on the pose's Dirichlet entries (ignored elsewhere)."""
    v = np.where(loading.fixed, v, 0.0)
    if isinstance(pose, StretchPose):  # x = c + s ⊙ (X − c) in plane, z = Z; c fixed
        return v * np.array([*pose.stretch, 1.0])
    if isinstance(pose, PokePose):  # held: x = X
        return v
    if pose.kind == "glue":  # every bottom node: x = P(X_xy)
        out = np.zeros_like(v)
        bottom = np.flatnonzero(loading.fixed.all(axis=1))
        jac = pose.jacobian(problem.rest[bottom, :2])
        out[bottom, :2] = np.einsum("nij,ni->nj", jac, v[bottom])
        return out
    raise AdjointError(f"pose {pose.name!r}: no Dirichlet derivative for kind {pose.kind!r}")


@timed("assembly")
def _hessian_product(problem: ElasticProblem, x: np.ndarray, v: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``(H v)`` of the elastic Hessian on the nodes flagged in ``rows`` (others zero),
    from the elements touching them only. The ball adds nothing there when ``v`` vanishes
    on those nodes (its Hessian is block diagonal)."""
    out = np.zeros((problem.n_nodes, 3))
    touching = np.flatnonzero(rows[problem.nodes].any(axis=1))
    for start in range(0, len(touching), problem.block):
        part = touching[start:start + problem.block]
        nodes = problem.nodes[part]
        terms = neohookean.element_terms(problem.element, problem.rest_inv[part], problem.rest_vol[part],
                                         x[nodes], problem.mu[part], problem.lam[part])
        local = np.einsum("ikabm,mbk->mai", terms.hessian, v[nodes], optimize=True)
        for i in range(3):
            out[:, i] += np.bincount(nodes.ravel(), weights=local[:, :, i].ravel(), minlength=len(out))
    out[~rows] = 0.0
    return out


def _fold(problem: ElasticProblem, nodal: np.ndarray) -> np.ndarray:
    """Node derivatives onto the vertices (a P2 edge node is its edge's midpoint)."""
    out = nodal[:problem.n_vertices].copy()
    if problem.order == 2:
        half = 0.5 * nodal[problem.n_vertices:]
        for end in range(2):
            for i in range(3):
                out[:, i] += np.bincount(problem.edge_vertices[:, end], weights=half[:, i], minlength=len(out))
    return out


def _top_triangles(problem: ElasticProblem):
    """Top-surface triangles ``(T, 3)`` (vertices), the nodes they lump area to ``(T, c)``
    and each node's share of the triangle's area ``(c,)`` (as :func:`top_surface`)."""
    mesh = problem.mesh
    tri = mesh.mesh2d.triangles + (len(mesh.level_z_mm) - 1) * len(mesh.mesh2d.points)
    if problem.order == 1:
        return tri, tri, np.full(3, 1.0 / 3.0)
    n = problem.n_vertices
    keys = problem.edge_vertices[:, 0] * n + problem.edge_vertices[:, 1]
    order = np.argsort(keys)

    def mid(a, b):
        k = np.minimum(a, b) * n + np.maximum(a, b)
        return n + order[np.searchsorted(keys[order], k)]
    a, b, c = tri.T
    corners = np.stack([a, b, c, mid(a, b), mid(b, c), mid(c, a)], axis=1)
    # Four sub-triangles, a third of each to its corners: 1/12 to a vertex, 3/12 to a midpoint.
    return tri, corners, np.array([1, 1, 1, 3, 3, 3]) / 12.0


# --- the forward map at other rest positions (Taylor tests, line searches) -------------

def _mesh_at(mesh: LayeredMesh, points: np.ndarray) -> LayeredMesh:
    points = np.array(points, dtype=float)
    if points.shape != mesh.points.shape:
        raise AdjointError(f"expected {mesh.points.shape} rest positions, got {points.shape}")
    mesh2d = replace(mesh.mesh2d, points=points[:len(mesh.mesh2d.points), :2].copy())
    return replace(mesh, mesh2d=mesh2d, points=points)


def problem_at(problem: ElasticProblem, points: np.ndarray) -> ElasticProblem:
    """``problem`` with its mesh's vertices at rest positions ``points`` ``(n_vertices,
    3)``: rest nodes, inverse Jacobians and volumes recomputed; materials, pattern and
    scales kept (the 2D mesh takes the bottom level's x, y)."""
    mesh = _mesh_at(problem.mesh, points)
    rest_inv, rest_vol = rest_geometry(mesh, "moved rest mesh")
    return replace(problem, mesh=mesh, rest=node_values(problem, mesh.points), rest_inv=rest_inv,
                   rest_vol=rest_vol)


def moved(sim, fine_points: np.ndarray, elastic_points: np.ndarray | None = None):
    """``sim`` (without poses) with the electrostatic vertices at ``fine_points`` and the
    elastic mesh's vertices at ``elastic_points`` (ignored on a shared mesh, where
    ``fine_points`` moves both); the transfer matrix is kept."""
    mesh = _mesh_at(sim.mesh, fine_points)
    electro = replace(sim.electro, mesh=mesh)
    elastic = sim.elastic
    if elastic is not None:
        elastic = problem_at(elastic, fine_points if sim.transfer is None else elastic_points)
        if sim.transfer is None:
            elastic = replace(elastic, mesh=mesh)
    return replace(sim, mesh=mesh, electro=electro, elastic=elastic, poses=())


def solve_moved_pose(sim, pose, settings: NewtonSettings, start: np.ndarray | None = None
                     ) -> tuple[electrostatic.Capacitances, ElasticState | None]:
    """Capacitances (and equilibrium) of ``pose`` on ``sim`` (e.g. from :func:`moved`) with
    the Newton ``settings`` (a scene's ``[elastic]``).

    ``start`` is a displacement ``(n_nodes, 3)`` (e.g. of the pose at nearby rest
    positions): Newton then starts from ``rest + start`` in one load step (the forward
    loop :func:`mscap.fem.simulate.solve_poses` on this one pose)."""
    solver = LinearSolver("electro_")
    try:
        result = solve_poses(sim, (pose,), settings, solver, None, [start])[0]
    finally:
        solver.destroy()
    return result.capacitances, result.state
