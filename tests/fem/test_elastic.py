"""Elastic solver: exact derivatives, the patch test, homogeneous stretches with closed
forms, contact, glue, the command line and clean failures.

Meshes are tiny structured triangulations (or coarse gmsh scenes) extruded through the
0.14/0.07/0.14/0.07/0.14 mm stack, so that the whole file runs in about half a minute.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import brentq

from mscap.cli import main
from mscap.errors import SceneError
from mscap.fem import electrostatic as es
from mscap.fem.elastic.contact import Ball, barrier, barrier_derivatives
from mscap.fem.elastic.loading import loading_for
from mscap.fem.elastic.newton import Loading, NewtonSettings, solve_pose
from mscap.fem.elastic.problem import ElasticError, assemble, build_problem, tet_fields, total_energy
from mscap.fem.simulate import simulate
from mscap.mesh.layered import extrude
from mscap.scene import load_scene
from mscap.scene.poses import StretchPose
from mscap.testing import taylor_test
from tests.conftest import grid_trimesh, to_toml
from tests.scenes import (CARBON, CLEAR, STACK_MM, free_thickness_stretch, grid_mesh, poke_scene_dict, scene_dict,
                          stack, strained)

ORDERS = pytest.mark.parametrize("order", [1, 2])


def dense(problem, data):
    return sp.csr_matrix((data, problem.indices, problem.indptr), shape=(problem.n_dofs,) * 2).toarray()


# --- derivatives -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny():
    """2 × 2 cells on 1 × 0.8 mm with a plate over the left half: carbon next to clear in
    the conductive layers, so material jumps run through the element patches."""
    mesh = grid_mesh(2, 2, 1.0, 0.8, lambda c: np.where(c[:, 0] < 0.5, 0, -1), jitter=0.2)
    problems = {order: build_problem(mesh, stack(), order) for order in (1, 2)}
    assert len(np.unique(problems[1].mu)) == 2
    return problems


def unit_steps(problem, h):
    for k in range(problem.n_dofs):
        step = np.zeros(problem.n_dofs)
        step[k] = h
        yield k, step.reshape(-1, 3)


@ORDERS
def test_gradient_and_hessian_match_central_differences(tiny, order):
    problem = tiny[order]
    x = strained(problem)
    a = assemble(problem, x)
    assert a.min_j > 0.2
    assert a.energy == pytest.approx(total_energy(problem, x)[0], rel=1e-13)
    h = 1e-6
    g_fd = np.empty(problem.n_dofs)
    h_fd = np.empty((problem.n_dofs, problem.n_dofs))
    for k, step in unit_steps(problem, h):
        g_fd[k] = (total_energy(problem, x + step)[0] - total_energy(problem, x - step)[0]) / (2 * h)
        h_fd[:, k] = (assemble(problem, x + step, hessian=False).gradient
                      - assemble(problem, x - step, hessian=False).gradient).ravel() / (2 * h)
    g = a.gradient.ravel()
    hessian = dense(problem, a.hessian)
    # Measured: gradient 9e-10 (P1) and 6e-9 (P2), Hessian 9e-10 and 1e-8 of the largest
    # entry: the O(h²) truncation of central differences. Comparing with the dense
    # matrix also checks that no nonzero falls outside the CSR pattern.
    assert np.abs(g_fd - g).max() < 1e-7 * np.abs(g).max()
    assert np.abs(h_fd - hessian).max() < 1e-7 * np.abs(hessian).max()
    assert np.abs(hessian - hessian.T).max() < 1e-14 * np.abs(hessian).max()


@ORDERS
def test_projected_hessian_is_psd_with_the_exact_gradient(tiny, order):
    problem = tiny[order]
    x = strained(problem)
    exact, projected = assemble(problem, x), assemble(problem, x, project=True)
    assert projected.energy == exact.energy
    np.testing.assert_array_equal(projected.gradient, exact.gradient)
    h_exact, h_proj = dense(problem, exact.hessian), dense(problem, projected.hessian)
    assert np.abs(h_proj - h_proj.T).max() < 1e-13 * np.abs(h_proj).max()
    eig_exact, eig_proj = np.linalg.eigvalsh(h_exact), np.linalg.eigvalsh(h_proj)
    assert eig_exact[0] < -1e-3 * eig_exact[-1]  # indefinite here, so projection matters
    assert eig_proj[0] >= -1e-10 * eig_proj[-1]  # measured -8e-18 (P1), -2e-17 (P2)

    # A homogeneous stretch with J > 1 has a positive definite tangent at every
    # quadrature point (its rotation-mode eigenvalues μ ± (μ − λ ln J)/(λ_i λ_j) are
    # positive here): projection must leave the Hessian as it is.
    x = problem.rest @ np.diag([1.1, 1.05, 0.95])
    h_exact = dense(problem, assemble(problem, x).hessian)
    h_proj = dense(problem, assemble(problem, x, project=True).hessian)
    np.testing.assert_allclose(h_proj, h_exact, rtol=0, atol=1e-12 * np.abs(h_exact).max())


@ORDERS
def test_energy_taylor_remainders_fall_like_h2_and_h3(tiny, order):
    # |E(x + hδ) − E − h gᵀδ| = O(h²) and |… − h²/2 δᵀHδ| = O(h³): rates of a log-log fit
    # over four halvings (pyadjoint's Taylor test, one order further for the Hessian).
    # Measured rates 1.999 and 2.99 (P1), 2.002 and 3.04 (P2); from h = 0.2 on, P2 is
    # still pre-asymptotic (3.35).
    problem = tiny[order]
    x = strained(problem, seed=1)
    delta = np.random.default_rng(2).normal(scale=0.01, size=x.shape)
    a = assemble(problem, x)
    curvature = float(delta.ravel() @ dense(problem, a.hessian) @ delta.ravel())
    taylor = taylor_test(lambda y: total_energy(problem, y)[0], x, delta, a.gradient, value=a.energy,
                         curvature=curvature, h0=0.02, halvings=4)
    assert taylor.fit_rate(2) == pytest.approx(2.0, abs=0.05), taylor
    assert taylor.fit_rate(3) == pytest.approx(3.0, abs=0.1), taylor


def test_ball_barrier_derivatives_match_central_differences():
    rng = np.random.default_rng(3)
    n, dhat, center, radius = 40, 0.1, np.array([1.0, 2.0, 3.0]), 2.0
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    gap = rng.uniform(0.05, 1.5, n) * dhat  # about two thirds inside d̂, the rest outside
    x = center + (radius + gap)[:, None] * direction
    ball = Ball(center, radius, np.arange(n), rng.uniform(0.5, 2.0, n), dhat, 0.3)
    np.testing.assert_allclose(ball.distances(x), gap, rtol=0, atol=1e-14)

    def full_gradient(y, project=False):
        nodes, grad, _ = ball.terms(y, project)
        out = np.zeros_like(y)
        out[nodes] = grad
        return out

    nodes, grad, hess = ball.terms(x)
    np.testing.assert_array_equal(nodes, np.flatnonzero(gap < dhat))
    assert 0 < len(nodes) < n
    blocks = np.zeros((n, 3, 3))
    blocks[nodes] = hess
    h = 1e-7
    g_fd = np.empty((n, 3))
    h_fd = np.empty((n, 3, n, 3))
    for i in range(n):
        for c in range(3):
            step = np.zeros_like(x)
            step[i, c] = h
            g_fd[i, c] = (ball.energy(x + step) - ball.energy(x - step)) / (2 * h)
            h_fd[:, :, i, c] = (full_gradient(x + step) - full_gradient(x - step)) / (2 * h)
    # Measured 1.2e-9 and 1.0e-9 of the largest entry.
    g = full_gradient(x)
    assert np.abs(g_fd - g).max() < 1e-7 * np.abs(g).max()
    expected = np.zeros((n, 3, n, 3))
    expected[np.arange(n), :, np.arange(n), :] = blocks  # one 3 × 3 block per node
    assert np.abs(h_fd - expected).max() < 1e-6 * np.abs(blocks).max()

    # Projected: same gradient; the negative tangential term b'/ρ (I − n nᵀ) is dropped,
    # leaving κ a b'' n nᵀ, positive semi-definite since b'' > 0 on (0, d̂).
    nodes_p, grad_p, hess_p = ball.terms(x, project=True)
    np.testing.assert_array_equal(nodes_p, nodes)
    np.testing.assert_array_equal(grad_p, grad)
    assert np.linalg.eigvalsh(hess).min() < 0
    assert np.linalg.eigvalsh(hess_p).min() >= -1e-12 * np.abs(hess_p).max()
    normal = direction[nodes]
    np.testing.assert_allclose(np.einsum("ni,nij,nj->n", normal, hess_p, normal),
                               np.einsum("ni,nij,nj->n", normal, hess, normal), rtol=1e-12)

    inside = x.copy()
    inside[0] = center + 0.5 * radius * direction[0]
    assert ball.energy(inside) == np.inf


def test_barrier_is_c2_at_dhat():
    dhat = 0.1
    at_and_beyond = np.array([dhat, 1.5 * dhat, 10.0])
    assert np.all(barrier(at_and_beyond, dhat) == 0)
    assert all(np.all(v == 0) for v in barrier_derivatives(at_and_beyond, dhat))
    assert np.all(barrier(np.array([0.0, -1.0]), dhat) == np.inf)
    # With d = d̂(1 − ε): b = ε³ d̂² (1 + ε/2 + …), b' = −3 ε² d̂ (1 + 2ε/3 + …) and
    # b'' = 6 ε (1 + ε + …), so all three vanish continuously at d̂, at the right orders.
    for eps in (1e-2, 1e-3, 1e-4):
        d = np.array([dhat * (1 - eps)])
        b = barrier(d, dhat)[0]
        db, d2b = (v[0] for v in barrier_derivatives(d, dhat))
        assert b / (eps ** 3 * dhat ** 2) == pytest.approx(1 + eps / 2, abs=2 * eps ** 2)
        assert db / (-3 * eps ** 2 * dhat) == pytest.approx(1 + 2 * eps / 3, abs=2 * eps ** 2)
        assert d2b / (6 * eps) == pytest.approx(1 + eps, abs=2 * eps ** 2)
    # b' and b'' against central differences over the whole range, through d̂ (measured
    # 8e-10 and 2e-9 of the largest value).
    d, h = np.linspace(0.02, 1.5, 60) * dhat, 1e-7
    db, d2b = barrier_derivatives(d, dhat)
    np.testing.assert_allclose((barrier(d + h, dhat) - barrier(d - h, dhat)) / (2 * h), db,
                               rtol=0, atol=1e-7 * np.abs(db).max())
    np.testing.assert_allclose((barrier_derivatives(d + h, dhat)[0] - barrier_derivatives(d - h, dhat)[0])
                               / (2 * h), d2b, rtol=0, atol=1e-6 * np.abs(d2b).max())


# --- exact answers ---------------------------------------------------------------------

@ORDERS
def test_affine_patch_test(order):
    # One material everywhere: x = A X + b has a constant first Piola stress, so div P = 0
    # inside and, with x = A X + b on the whole boundary, it is the equilibrium. P1 and P2
    # contain affine fields, so the discrete solution must be A X + b at every node.
    problem = build_problem(grid_mesh(4, 3, 4.0, 3.0), stack(CLEAR, CLEAR, CLEAR), order)
    rest = problem.rest
    lo, hi = rest.min(axis=0), rest.max(axis=0)
    boundary = ((np.abs(rest - lo) < 1e-12) | (np.abs(rest - hi) < 1e-12)).any(axis=1)
    assert (~boundary).sum() >= 24  # interior nodes on every interior level
    theta = np.radians(25.0)
    rotation = np.array([[np.cos(theta), -np.sin(theta), 0], [np.sin(theta), np.cos(theta), 0], [0, 0, 1]])
    a = rotation @ np.array([[1.3, 0.15, 0.05], [0.0, 0.9, -0.1], [0.08, 0.0, 1.1]])
    assert np.linalg.det(a) > 1.2
    target = rest @ a.T + np.array([0.3, -0.2, 0.1])
    noise = np.random.default_rng(4).normal(scale=0.01 if order == 1 else 0.003, size=rest.shape)
    noise[boundary] = 0.0

    # The solver's own predictor (the linearised response to the affine boundary data)
    # is already exact; start from a perturbed guess instead so that Newton has work to do.
    loading = Loading("patch", np.repeat(boundary[:, None], 3, axis=1),
                      lambda t: rest + t * (target - rest), guess=lambda x, t: target + noise)
    state = solve_pose(problem, loading, NewtonSettings(tolerance=1e-12))
    assert state.newton_iterations >= 3
    size = float(np.max(hi - lo))
    # Measured 1.1e-16 (P1) and 3.3e-16 (P2) of the sheet size.
    assert np.abs(state.nodes - target).max() < 1e-10 * size


@ORDERS
def test_a_carried_start_is_the_deformation_at_the_moved_nodes(order):
    # A design step moves rest nodes inside unchanged layers. For the affine map x = A X + b
    # (the equilibrium of one material with those boundary values, the patch test above),
    # the nodal deformation gradient is A exactly, so the start carried to moved rest nodes
    # is A X' + b at every node: Newton has nothing left to do. Keeping the displacement
    # instead (x = X' + u) leaves a residual of the order of (A − I) ∇δX.
    from mscap.fem.adjoint import problem_at
    from mscap.fem.elastic.problem import carried_displacement, nodal_deformation_gradients

    problem = build_problem(grid_mesh(4, 3, 4.0, 3.0), stack(CLEAR, CLEAR, CLEAR), order)
    a = np.array([[1.3, 0.15, 0.05], [0.0, 0.9, -0.1], [0.08, 0.0, 1.1]])
    shift = np.array([0.3, -0.2, 0.1])
    x = problem.rest @ a.T + shift
    assert np.abs(nodal_deformation_gradients(problem, x) - a).max() < 1e-13

    points = problem.mesh.points.copy()
    lo, hi = points.min(axis=0), points.max(axis=0)
    side = ((np.abs(points - lo) < 1e-12) | (np.abs(points - hi) < 1e-12))[:, :2].any(axis=1)
    points[~side, :2] += np.random.default_rng(5).uniform(-0.1, 0.1, size=((~side).sum(), 2))
    moved = problem_at(problem, points)
    carried = moved.rest + carried_displacement(problem, x, moved.rest)
    assert np.abs(carried - (moved.rest @ a.T + shift)).max() < 1e-12

    boundary = ((np.abs(moved.rest - lo) < 1e-12) | (np.abs(moved.rest - hi) < 1e-12)).any(axis=1)
    target = moved.rest @ a.T + shift
    iterations = {}
    for name, start in (("carried", carried), ("kept", moved.rest + x - problem.rest)):
        loading = Loading("patch", np.repeat(boundary[:, None], 3, axis=1), lambda t: target,
                          guess=lambda x0, t, start=start: start)
        state = solve_pose(moved, loading, NewtonSettings(tolerance=1e-10))
        assert np.abs(state.nodes - target).max() < 1e-9
        iterations[name] = state.newton_iterations
    assert iterations["carried"] == 0 and iterations["kept"] >= 2, iterations


@pytest.fixture(scope="module")
def full_plate():
    """One capacitor covering a 6 × 4 mm sheet: at rest and after any in-plane affine map
    and uniform thinning its field is uniform, so C = ε A / d holds to round-off."""
    mesh = grid_mesh(4, 3, 6.0, 4.0)
    electro = es.build_problem(mesh, stack(), 1)
    return {"mesh": mesh, "electro": electro, "c0": es.solve(electro).capacitance_pF[0],
            "elastic": {order: build_problem(mesh, stack(), order) for order in (1, 2)}}


def stretched_capacitance(full_plate, pose, order):
    problem = full_plate["elastic"][order]
    state = solve_pose(problem, loading_for(problem, pose), NewtonSettings(tolerance=1e-10))
    vertices = state.vertices(problem.n_vertices)
    return es.solve(full_plate["electro"], vertices).capacitance_pF[0] / full_plate["c0"], state


@pytest.mark.parametrize("mode, stretch, axis, order", [
    ("uniaxial", (2.0, 1.0), 0, 1),
    ("uniaxial", (1.0, 2.0), 1, 2),
    ("biaxial", (1.25, 1.25), 0, 1),
    ("biaxial", (1.3, 1.1), 0, 2),
    ("plane_strain", (2.0, 1.0), 0, 1),
    ("plane_strain", (1.0, 1.5), 1, 2),
])
def test_roller_stretch_of_a_full_plate_has_the_closed_form(full_plate, mode, stretch, axis, order):
    # Rollers leave the deformation free to be homogeneous: F = diag(λ1, λ2, λ3) with the
    # free stretches fixed by zero normal stress. The two materials differ in E but share
    # ν, hence λ/μ, so every layer finds the same λ3 (and a uniaxial pose the same free
    # lateral λ): the layers fit together without shear, P e3 = 0 on every interface, and
    # this F is the exact equilibrium, which P1 and P2 represent exactly. Then
    # C/C0 = (A λ1 λ2) / (d λ3).
    assert free_thickness_stretch(1.3, 1.1, CLEAR) == pytest.approx(
        free_thickness_stretch(1.3, 1.1, CARBON), rel=1e-14)
    pose = StretchPose("s", mode, stretch, "roller", axis, load_steps=4)
    ratio, state = stretched_capacitance(full_plate, pose, order)
    l1, l2 = stretch
    if mode == "uniaxial":
        # P22 = P33 = 0 is one equation for both free stretches, so λ_lateral = λ3 and
        # C/C0 = λ whatever the material law: the elastic answer is checked by the shape.
        lateral = brentq(lambda s: free_thickness_stretch(max(stretch), s, CLEAR) - s, 0.1, 1.0, xtol=1e-15)
        l1, l2 = (l1, lateral) if axis == 0 else (lateral, l2)
    l3 = free_thickness_stretch(l1, l2, CLEAR)
    expected = l1 * l2 / l3
    if mode == "uniaxial":
        assert expected == pytest.approx(max(stretch), rel=1e-14)
    rest, nodes = full_plate["mesh"].points, state.nodes
    np.testing.assert_allclose(np.ptp(nodes, axis=0) / np.ptp(rest, axis=0), [l1, l2, l3], rtol=1e-9)
    # Homogeneous in both materials: the same J in every tet.
    j = tet_fields(full_plate["elastic"][order], nodes)[0]
    np.testing.assert_allclose(j, l1 * l2 * l3, rtol=1e-9)
    # Measured |C/C0 − closed form| ≤ 4e-14 (P1 and P2) with Newton tolerance 1e-10;
    # the sheet's extents and J match to 1e-13.
    assert ratio == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("order", [1, 2])
def test_a_warm_start_on_a_stale_hessian_reaches_the_newton_equilibrium(full_plate, order):
    """newton.solve_pose with ``stale``: warm from a clamped 1.5 stretch's equilibrium to
    1.52, modified Newton on the 1.5 equilibrium's factorised Hessian reaches the state
    plain Newton reaches from the same start (nodes to 1e-9 mm) with no factorising
    iteration; from the rest state's Hessian (a far one: the 1.52 stretch is not near it)
    it stops after a few iterations and Newton finishes at the same equilibrium."""
    problem = full_plate["elastic"][order]
    settings = NewtonSettings(tolerance=1e-10)

    def pose(stretch):
        return StretchPose("s", "uniaxial", (stretch, 1.0), "clamp", 0, 4)

    near = solve_pose(problem, loading_for(problem, pose(1.5)), settings, keep_factorisation=True)
    rest = solve_pose(problem, loading_for(problem, pose(1.0 + 1e-9)), settings, keep_factorisation=True)
    try:
        target = replace(loading_for(problem, pose(1.52)), load_steps=1, guess=lambda x, t: near.nodes)
        plain = solve_pose(problem, target, settings)
        stale = solve_pose(problem, target, settings, stale=near.operator)
        far = solve_pose(problem, target, settings, stale=rest.operator)
    finally:
        near.operator.destroy()
        rest.operator.destroy()
    assert plain.newton_iterations >= 3 and plain.stale_iterations == 0
    assert stale.newton_iterations == 0 and 0 < stale.stale_iterations <= 30
    assert 0 < far.newton_iterations and 0 < far.stale_iterations < 30
    for state in (stale, far):
        assert state.residual <= 1e-10
        assert np.abs(state.nodes - plain.nodes).max() < 1e-9


def test_clamped_uniaxial_stretch_is_not_homogeneous(full_plate):
    # Clamps stop the gripped edges from contracting, so the sheet necks between them:
    # no longer the homogeneous answer C/C0 = λ (measured 1.9536 for λ = 2).
    ratio, state = stretched_capacitance(full_plate, StretchPose("s", "uniaxial", (2.0, 1.0), "clamp", 0, 4), 1)
    assert abs(ratio - 2.0) > 1e-3
    assert np.ptp(tet_fields(full_plate["elastic"][1], state.nodes)[0]) > 1e-3


# --- poke ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def poked(tmp_path_factory):
    path = tmp_path_factory.mktemp("poke") / "poke.toml"
    path.write_text(to_toml(poke_scene_dict()))
    scene = load_scene(path)
    return scene, simulate(scene)


def test_poke_converges_in_contact_and_raises_the_capacitance(poked):
    scene, sim = poked
    pose, result = scene.poses[1], sim.poses[1]
    state = result.state
    assert state.residual <= scene.elastic.tolerance
    assert state.min_j > 0.5
    # In contact at the end, and nothing inside the ball.
    dhat = pose.barrier_distance_mm
    assert 0 < state.min_gap_mm < dhat
    ball = loading_for(sim.elastic, pose).ball(1.0)
    top_z = float(sim.mesh.level_z_mm[-1])
    assert ball.center[2] == pytest.approx(top_z + pose.radius_mm - pose.depth_mm, rel=1e-14)
    gap_of_every_node = np.linalg.norm(state.nodes - ball.center, axis=1) - ball.radius
    assert gap_of_every_node.min() == pytest.approx(state.min_gap_mm, rel=1e-12)
    # The ball really went in: the sheet under it sits ~depth below the rest top.
    assert state.nodes[:, 2].min() < top_z - 0.9 * pose.depth_mm
    # Pressing thins and stretches the capacitor under the ball (measured +3.1 %).
    rest_c, poked_c = sim.capacitance_pF[:, 0]
    assert poked_c > 1.01 * rest_c


def test_poke_does_not_depend_on_the_hessian_mode(poked):
    # "auto" (the exact Hessian, projected only where it fails or after a damped step) and
    # element-wise projection everywhere take different paths, but run to a scaled residual
    # of 1e-10 they must land within ~80 mm × residual (the poked sheet's compliance) of
    # the same nodes.
    scene, sim = poked
    loading = loading_for(sim.elastic, scene.poses[1])
    states = {}
    for mode in ("auto", "projected"):
        settings = NewtonSettings(tolerance=1e-10, max_iterations=scene.elastic.max_iterations,
                                  max_cuts=scene.elastic.max_cuts, hessian=mode)
        states[mode] = solve_pose(sim.elastic, loading, settings)
        assert states[mode].residual <= 1e-10
    assert states["projected"].projected == states["projected"].newton_iterations
    # Measured 3.0e-9 mm and 6e-13 (15 auto, 21 projected iterations).
    assert np.abs(states["projected"].nodes - states["auto"].nodes).max() < 5e-8
    c = [es.solve(sim.electro, sim.vertices(states[mode].nodes)).capacitance_pF for mode in states]
    np.testing.assert_allclose(c[0], c[1], rtol=1e-10)


# --- glue ------------------------------------------------------------------------------

GLUE_RADIUS_MM = 50.0


@pytest.fixture(scope="module", params=[1, 2], ids=["P1", "P2"])
def glued(request, tmp_path_factory):
    """A 20 × 10 mm sheet glued onto a cylinder of radius 50 mm, P1 and P2 elasticity."""
    data = scene_dict(
        name="glued",
        sheet={"width_mm": 20.0, "height_mm": 10.0},
        capacitors={"min_gap_mm": 1.0, "outlines_mm": [[[5.0, 2.5], [15.0, 2.5], [15.0, 7.5], [5.0, 7.5]]]},
        mesh={"edge_length_mm": 3.0, "edge_length_outline_mm": 1.5, "grading_distance_mm": 2.0},
        objects={"arm": {"generator": "cylinder", "width_mm": 30.0, "height_mm": 20.0,
                         "corner_mm": [-5.0, -5.0], "edge_length_mm": 1.0}},
        poses=[{"name": "rest", "kind": "free"},
               {"name": "bent", "kind": "glue", "object": "arm", "radius_mm": GLUE_RADIUS_MM}],
        # The measured numbers below are on the electrostatic mesh itself; on the default
        # own mesh (5 mm, one element through the stack: 4 × 2 triangles here) P1 gives
        # 1.01318 and P2 1.01045 (docs/elastic.md).
        elastic={"order": request.param, "mesh": "shared"})
    path = tmp_path_factory.mktemp("glue") / "glue.toml"
    path.write_text(to_toml(data))
    scene = load_scene(path)
    return scene, simulate(scene)


def test_glued_bottom_lies_on_the_posed_surface(glued):
    scene, sim = glued
    state, problem = sim.poses[1].state, sim.elastic
    assert problem.order == scene.elastic.order
    assert state.residual <= scene.elastic.tolerance
    assert state.min_j > 0.9
    bottom = np.flatnonzero(problem.rest[:, 2] == 0.0)  # with P2 also the edge nodes
    on_surface = scene.poses[1].positions(problem.rest[bottom, :2])
    # Measured: 0 (the Dirichlet values are copied).
    np.testing.assert_allclose(state.nodes[bottom], on_surface, rtol=0, atol=1e-12)
    assert np.ptp(state.nodes[bottom, 2]) > 0.5  # really bent (sagitta of 10 mm at R = 50)


def test_gentle_bending_barely_changes_the_capacitance(glued):
    # The cylinder roll is isometric, so the glued bottom does not stretch; a layer at
    # height Z above it stretches by (R + Z)/R along the bend and not at all along the
    # axis. With R = 50 mm against a 0.56 mm sheet, the dielectric (mid-height 0.28 mm)
    # stretches by 0.56 % in plane strain and thins by the plane-strain λ3, so
    # C/C0 ≈ λ1/λ3 ≈ 1.0106: bending this gently is far inside 2 %. Curvature terms
    # are O((t/R)²) ~ 1e-4; the larger discrepancy is the coarse mesh's fringing excess
    # (C0 is 18 % above ε A/d here), which deforms with the plate edges: measured
    # 1.01129 (P1), 1.01038 (P2); on a finer mesh (edges 2 and 0.5 mm) 1.01066 (P1) and
    # 1.01009 (P2), against 1.01060.
    scene, sim = glued
    ratio = sim.capacitance_pF[1, 0] / sim.capacitance_pF[0, 0]
    assert abs(ratio - 1.0) < 0.02
    mid_height = STACK_MM[0] + STACK_MM[1] + 0.5 * STACK_MM[2]
    l1 = 1.0 + mid_height / GLUE_RADIUS_MM
    estimate = l1 / free_thickness_stretch(l1, 1.0, CLEAR)
    assert ratio == pytest.approx(estimate, abs=1.5e-3)  # 15 % of the effect


# --- command line ----------------------------------------------------------------------

def test_simulate_json(write_scene, capsys):
    data = scene_dict(
        mesh={"edge_length_mm": 5.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 3.0},
        poses=[{"name": "rest", "kind": "free"},
               {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"}])
    path = str(write_scene(data))
    assert main(["simulate", path, "--json", "-q"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert {"scene", "poses", "capacitance_pF", "newton_iterations", "time_s"} <= set(record)
    assert record["scene"] == "small" and record["poses"] == ["rest", "pull"]
    caps = np.array(record["capacitance_pF"])
    assert caps.shape == (2, 2)
    assert record["newton_iterations"][0] == 0 and record["newton_iterations"][1] > 0
    times = record["time_s"]
    assert {"mesh", "elastic", "electrostatic", "total"} <= set(times)
    assert times["total"] >= max(times["mesh"], times["elastic"], times["electrostatic"]) > 0
    # Stretching along x increases both capacitors' plate areas more than their gap.
    assert np.all(caps[1] > 1.05 * caps[0])

    assert main(["capacitance", path, "--json"]) == 0
    rest = json.loads(capsys.readouterr().out)["capacitance_pF"]
    np.testing.assert_allclose(caps[0], rest, rtol=1e-12)


def test_out_of_core_sets_its_own_electrostatic_mesh_aside_through_the_elastic_phase(write_scene, tmp_path,
                                                                                      monkeypatch):
    """Out of core (the finer-mesh check), a simulation that meshed the scene itself drops
    the electrostatic mesh while the poses' equilibria are solved (an elastic mesh of its
    own needs nothing of it; 79 MB of biaxial's check) and extrudes it again from its
    triangulation: the same tets, points and capacitances as with that mesh given."""
    import mscap.fem.simulate as simulation
    from mscap.mesh.layered import mesh_sheet

    monkeypatch.setenv("MUMPS_OOC_TMPDIR", str(tmp_path))
    data = scene_dict(
        mesh={"edge_length_mm": 5.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 3.0},
        poses=[{"name": "rest", "kind": "free"},
               {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"}])
    scene = load_scene(str(write_scene(data)))
    seen, solve_equilibria = [], simulation.equilibria

    def equilibria(sim, *args, **kwargs):
        seen.append(sim.mesh)  # what the elastic phase holds
        return solve_equilibria(sim, *args, **kwargs)

    monkeypatch.setattr(simulation, "equilibria", equilibria)
    given = mesh_sheet(scene.sheet)
    aside = simulate(scene, out_of_core=True)
    kept = simulate(scene, out_of_core=True, mesh=given)
    in_core = simulate(scene)
    assert seen[0] is None and seen[1] is given and seen[2] is in_core.mesh  # only the first set it aside
    assert aside.elastic.mesh is not aside.mesh
    np.testing.assert_array_equal(aside.mesh.tets, given.tets)
    np.testing.assert_array_equal(aside.mesh.points, given.points)
    np.testing.assert_array_equal(aside.mesh.capacitor_of_tet, given.capacitor_of_tet)
    np.testing.assert_array_equal(aside.capacitance_pF, kept.capacitance_pF)
    np.testing.assert_allclose(aside.capacitance_pF, in_core.capacitance_pF, rtol=1e-9)  # MUMPS out of core vs in core
    assert aside.capacitance_pF[1, 0] > 1.05 * aside.capacitance_pF[0, 0]


# --- failures --------------------------------------------------------------------------

FAILURES = [
    ({"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.5, "grips": "clamp"},
     {"max_iterations": 1, "max_cuts": 1}, r"t = 0 → 0\.25\) failed after 1 step cuts"),
    ({"name": "press", "kind": "poke", "center_mm": [8.0, 10.0], "radius_mm": 5.0, "depth_mm": 3.0},
     {"max_iterations": 1, "max_cuts": 0}, r"t = 0 → 0\.5\) failed after 0 step cuts"),
]


@pytest.mark.parametrize("pose, elastic, when", FAILURES, ids=["stretch", "poke"])
def test_an_impossible_request_fails_cleanly(write_scene, capsys, pose, elastic, when):
    data = scene_dict(mesh={"edge_length_mm": 5.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 3.0},
                      poses=[{"name": "rest", "kind": "free"}, pose], elastic=elastic)
    path = write_scene(data)
    with pytest.raises(ElasticError) as info:
        simulate(load_scene(path))
    message = str(info.value)
    pattern = (rf"pose '{pose['name']}': load step 1 \({when}: no convergence in 1 Newton "
               rf"iterations; residual (\S+)$")
    match = re.search(pattern, message)
    assert match, message
    assert 1e-8 < float(match.group(1)) < 1e3  # a finite residual above the tolerance

    # The command line prints that one line, no traceback and no result.
    assert main(["simulate", str(path), "--json", "-q"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip() == f"mscap: error: {message}"


def test_an_inverting_boundary_path_raises_instead_of_returning_nan():
    # Mirroring z on the boundary passes through a flat sheet at t = 1/2: no load step
    # can cross it, so the steps are cut until max_cuts and the pose fails (nothing
    # non-finite is ever accepted on the way).
    problem = build_problem(grid_mesh(3, 2, 3.0, 2.0), stack(CLEAR, CLEAR, CLEAR), 1)
    rest = problem.rest
    lo, hi = rest.min(axis=0), rest.max(axis=0)
    boundary = ((np.abs(rest - lo) < 1e-12) | (np.abs(rest - hi) < 1e-12)).any(axis=1)
    mirrored = rest * [1.0, 1.0, -1.0]
    loading = Loading("mirror", np.repeat(boundary[:, None], 3, axis=1),
                      lambda t: rest + t * (mirrored - rest))
    with pytest.raises(ElasticError, match=r"^pose 'mirror': load step \d+ \(t = 0\.4\d* → 0\.5\d*\) "
                                           r"failed after 8 step cuts: no feasible start"):
        solve_pose(problem, loading, NewtonSettings(max_cuts=8))


# --- scene errors ----------------------------------------------------------------------

@pytest.mark.parametrize("pose, key, message", [
    ({"kind": "stretch", "mode": "uniaxal", "stretch": 1.2}, "mode",
     "unknown value 'uniaxal'; expected one of uniaxial, biaxial, plane_strain"),
    ({"kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "glue"}, "grips",
     "unknown value 'glue'; expected one of clamp, roller"),
    ({"kind": "stretch", "mode": "biaxial", "stretch": [1.2]}, "stretch",
     "biaxial stretch needs [λx, λy], got [1.2]"),
    ({"kind": "stretch", "mode": "uniaxial", "stretch": -1.5}, "stretch",
     "stretch ratios must be numbers > 0, got -1.5"),
    ({"kind": "poke", "center_mm": [10.0, 10.0], "radius_mm": 5.0, "depth_mm": 2.0,
      "held_edges": ["x_min", "z_max"]}, "held_edges",
     "unknown edge 'z_max'; expected some of x_min, x_max, y_min, y_max"),
    ({"kind": "poke", "center_mm": [10.0, 10.0], "radius_mm": 0.0, "depth_mm": 2.0}, "radius_mm",
     "must be > 0, got 0.0"),
    ({"kind": "poke", "center_mm": [10.0, 10.0], "radius_mm": -5.0, "depth_mm": 2.0}, "radius_mm",
     "must be > 0, got -5.0"),
    ({"kind": "poke", "center_mm": [10.0, 25.0], "radius_mm": 5.0, "depth_mm": 2.0}, "center_mm",
     "(10, 25) mm lies outside the sheet [0, 30] × [0, 20] mm"),
], ids=["mode", "grips", "biaxial-one-ratio", "negative-stretch", "edge", "zero-radius", "negative-radius",
        "ball-off-sheet"])
def test_bad_pose_names_file_key_and_value(write_scene, pose, key, message):
    path = write_scene(scene_dict(poses=[{"name": "rest", "kind": "free"}, {"name": "p"} | pose]))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert info.value.path == str(path)
    assert info.value.key == f"poses[1].{key}"
    assert str(info.value) == f"{path}: poses[1].{key}: {message}"


# --- memory: the elastic phase ends before the electrostatic one begins ----------------------

def test_simulate_frees_the_elastic_solver_before_building_the_electrostatic_problem(tmp_path, monkeypatch):
    # A simulation's peak is then the larger of its two phases, not their sum (biaxial's
    # finer-mesh check: a 420 MB P2 MUMPS factorisation; docs/performance.md §9).
    import mscap.fem.simulate as simulation

    operators, seen = [], []

    class Recorded(simulation.Operator):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.destroyed = False
            operators.append(self)

        def destroy(self):
            self.destroyed = True
            super().destroy()

    build = es.build_problem

    def build_problem(*args, **kwargs):
        seen.append([op.destroyed for op in operators])
        return build(*args, **kwargs)

    monkeypatch.setattr(simulation, "Operator", Recorded)
    monkeypatch.setattr(simulation.electrostatic, "build_problem", build_problem)
    path = tmp_path / "poke.toml"
    path.write_text(to_toml(poke_scene_dict()))
    sim = simulate(load_scene(path))
    assert seen == [[True]] and sim.poses[1].state.residual > 0


def test_touching_plates_fail_before_any_elastic_solve(tmp_path, monkeypatch):
    import mscap.fem.simulate as simulation

    def equilibrium(*args, **kwargs):
        raise AssertionError("an elastic solve ran before the layout was checked")

    monkeypatch.setattr(simulation, "equilibrium", equilibrium)
    path = tmp_path / "poke.toml"
    path.write_text(to_toml(poke_scene_dict()))
    touching = grid_trimesh(15, 15, 30.0, 30.0, lambda c: np.where(c[:, 0] < 15.0, 0, 1))
    with pytest.raises(es.ElectrostaticError, match="plate of capacitor 0 and the bottom plate of capacitor 1 touch"):
        simulate(load_scene(path), mesh=extrude(touching, STACK_MM))


@ORDERS
def test_hessian_pattern_is_int32_and_assembles_as_with_int64(tiny, order):
    # 55 MB less on biaxial's finer-mesh check (P2, 6.9 M nonzeros); not a bit different.
    problem = tiny[order]
    assert problem.indices.dtype == np.int32 and problem.csr_of_block.dtype == np.int32
    wide = replace(problem, indices=problem.indices.astype(np.int64), csr_of_block=problem.csr_of_block.astype(np.int64))
    x = problem.rest + 1e-3 * np.random.default_rng(3).normal(size=problem.rest.shape)
    np.testing.assert_array_equal(dense(wide, assemble(wide, x).hessian), dense(problem, assemble(problem, x).hessian))


@ORDERS
def test_blockwise_hessian_equals_one_shot_coo_sum(tiny, order, monkeypatch):
    """The Hessian assembled a chunk of elements at a time, each chunk's 3 × 3 blocks
    written in CSR-block order (no transposed copy: 65 MB less on biaxial's finer-mesh
    check), is scipy's COO → CSR sum of every element Hessian at once, for any chunk size."""
    from mscap.fem import elements as fem
    from mscap.fem.elastic import neohookean

    problem = tiny[order]
    x = problem.rest + 1e-3 * np.random.default_rng(5).normal(size=problem.rest.shape)
    terms = neohookean.element_terms(problem.element, problem.rest_inv, problem.rest_vol, x[problem.nodes],
                                     problem.mu, problem.lam)
    nb = problem.nodes.shape[1]
    # hessian[i, k, a, b, m] = d²E / dx_ai dx_bk: row 3 node_a + i, column 3 node_b + k.
    i, k, a, b, m = np.meshgrid(*(np.arange(n) for n in terms.hessian.shape), indexing="ij")
    rows = 3 * problem.nodes[m, a] + i
    cols = 3 * problem.nodes[m, b] + k
    full = sp.coo_matrix((terms.hessian.ravel(), (rows.ravel(), cols.ravel())), shape=(problem.n_dofs,) * 2)
    full = full.toarray()
    scale = np.abs(full).max()
    for block in (1, 5, 10 ** 6):  # elements per chunk: one, a few, all at once
        monkeypatch.setattr(fem, "BLOCK", block)
        monkeypatch.setattr("mscap.fem.elastic.problem.HESSIAN_ENTRIES_PER_BLOCK", block * 9 * nb * nb)
        chunked = build_problem(problem.mesh, stack(), order)
        assert chunked.block == block and len(chunked.scatter) == -(-len(chunked.nodes) // block)
        np.testing.assert_allclose(dense(chunked, assemble(chunked, x).hessian), full, rtol=0, atol=1e-14 * scale)


def test_a_poked_scene_without_an_order_gets_p2_and_p1_is_said_to_lock(tmp_path, caplog):
    """Issue 44's poke: a 16 mm plate on a 40 mm sheet held at two edges, a 5 mm ball 4 mm
    deep, no [mesh] or [elastic] table. P2 converges on the gain C(poke) − C(rest): 1.2267,
    1.1697, 1.1331 pF at 5, 2.5, 1.25 mm edges (measured here; 1.1270 at 0.8 mm, limit
    ≈ 1.122 pF in the issue's study). The default is now P2 refined under the ball and
    along the held edges (sizing.p2_poke_refinement: +2.7 %; uniform P2 at 5 mm +9.3 %),
    where P1 read +36 % without a word; a scene that asks for P1 gets a warning saying so."""
    import logging

    from tests.conftest import to_toml
    from tests.scenes import scene_dict

    data = scene_dict(name="poke16", sheet={"width_mm": 40.0, "height_mm": 40.0},
                      capacitors={"min_gap_mm": 1.0,
                                  "outlines_mm": [[[12.0, 12.0], [28.0, 12.0], [28.0, 28.0], [12.0, 28.0]]]},
                      poses=[{"name": "rest", "kind": "free"},
                             {"name": "poke", "kind": "poke", "center_mm": [20.0, 20.0], "radius_mm": 5.0,
                              "depth_mm": 4.0, "held_edges": ["x_min", "x_max"]}])
    del data["mesh"]
    converged = 1.122
    gains = {}
    caplog.set_level(logging.WARNING, logger="mscap.fem.simulate")
    for order in (None, 1, "uniform"):
        if order is not None:
            data["elastic"] = {"order": 2, "refine_pokes": False} if order == "uniform" else {"order": order}
        path = tmp_path / f"poke_{order}.toml"
        path.write_text(to_toml(data))
        scene = load_scene(path)
        assert scene.elastic.order == (1 if order == 1 else 2)
        c = simulate(scene).capacitance_pF[:, 0]
        gains[order] = c[1] - c[0]
    assert 0 < gains[None] / converged - 1 < 0.03, gains
    assert 0.08 < gains["uniform"] / converged - 1 < 0.10, gains
    assert gains[1] / converged - 1 > 0.25, gains
    warnings = [r.getMessage() for r in caplog.records if "P1 elements lock where the sheet bends" in r.getMessage()]
    assert len(warnings) == 1 and "(poses poke)" in warnings[0]


def test_a_glued_scene_without_an_order_gets_p2(tmp_path):
    """The glued bend of benchmarks/element_bias.py (ν = 0.47): P1 at 5 mm reads the gain
    6.9 % low, P2 1.2 % high against P2 at 1.25 mm; a glued scene that gives no order gets P2,
    one that gives an order keeps it."""
    from tests.conftest import to_toml
    from tests.scenes import glue_scene

    for given, expected in ((None, 2), (1, 1)):
        data = glue_scene(1)
        if given is None:
            del data["elastic"]["order"]
        path = tmp_path / f"glue_{given}.toml"
        path.write_text(to_toml(data))
        assert load_scene(path).elastic.order == expected


def test_p1_under_glue_is_warned_about_only_on_a_coarse_elastic_mesh(tmp_path, caplog):
    """P1 reads the glued paper scenes' signals within 3.3 % of P2 on their 2.5 mm elastic
    meshes (benchmarks/glued_element.py): no warning there; a coarser P1 mesh, a shared
    one, or a poke is warned about, once."""
    import logging

    from mscap.fem import simulate as simulation
    from tests.conftest import to_toml
    from tests.scenes import glue_scene

    caplog.set_level(logging.WARNING, logger="mscap.fem.simulate")
    for edge, mesh, warned in ((2.5, "own", False), (4.0, "own", True), (2.5, "shared", True)):
        data = glue_scene(1)
        data["elastic"].update(edge_length_mm=edge, mesh=mesh)
        path = tmp_path / f"glue_{edge}_{mesh}.toml"
        path.write_text(to_toml(data))
        caplog.clear()
        for _ in range(2):
            scene = load_scene(path)
            simulation._warn_p1_bending(scene.path, scene.name, 1, scene.poses, scene.elastic)
        said = [r.getMessage() for r in caplog.records if "P1 elements lock where the sheet bends" in r.getMessage()]
        assert len(said) == warned and all("(poses bent)" in m for m in said), (edge, mesh, said)
