"""Rest-geometry gradients of pose capacitances (mscap.fem.adjoint): the kernels against
central differences, then Taylor tests of the whole chain — electrostatic shape
derivative, elastic adjoint, rest-position derivatives, Dirichlet data — on coarse
stretch, poke and glue scenes, on the own elastic mesh and on a shared one.

Each scene is moved by a smooth in-plane field evaluated at each mesh's own 2D vertices
(the same function on the electrostatic and the elastic mesh), either vanishing on the
sheet boundary (what the deformer does) or sliding along it (which moves the grips and
held edges and so checks the Dirichlet term of stretch and poke poses too).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mscap.fem import adjoint

from mscap.fem.elastic import neohookean
from mscap.fem.elastic.contact import Ball
from mscap.fem.elastic.loading import top_surface
from mscap.fem.elastic.problem import assemble, build_problem
from mscap.fem.simulate import factorised, simulate
from mscap.scene import load_scene
from mscap.testing import taylor_test
from tests.conftest import to_toml
from tests.scenes import glue_scene, grid_mesh, poke_scene_dict, scene_dict, stack, strained

ORDERS = pytest.mark.parametrize("order", [1, 2])


# --- kernels ---------------------------------------------------------------------------

def test_piola_differential_matches_central_differences():
    rng = np.random.default_rng(0)
    F = np.eye(3) + 0.3 * rng.normal(size=(20, 3, 3))
    F[np.linalg.det(F) < 0, 0] *= -1  # keep J > 0
    L = rng.normal(size=(20, 3, 3))
    mu, lam = rng.uniform(0.1, 1.0, 20), rng.uniform(1.0, 10.0, 20)
    h = 1e-6
    fd = (neohookean.first_piola(F + h * L, mu, lam) - neohookean.first_piola(F - h * L, mu, lam)) / (2 * h)
    # Measured 5e-11 relative.
    np.testing.assert_allclose(neohookean.piola_differential(F, L, mu, lam), fd, rtol=0,
                               atol=1e-8 * np.abs(fd).max())


@pytest.fixture(scope="module")
def tiny_mesh():
    """2 × 2 cells on 1 × 0.8 mm, a plate over the left half (material jumps inside)."""
    return grid_mesh(2, 2, 1.0, 0.8, lambda c: np.where(c[:, 0] < 0.5, 0, -1), jitter=0.2)


@ORDERS
def test_elastic_rest_vjp_matches_central_differences(tiny_mesh, order):
    # −∂/∂X [λ · ∇ₓE(x, X)] at a large, indefinite strain, in a random 3D direction of
    # every vertex (z too: the kernel knows nothing about the design being in-plane).
    problem = build_problem(tiny_mesh, stack(), order)
    x = strained(problem)
    rng = np.random.default_rng(1)
    lam, direction = rng.normal(size=x.shape), rng.normal(size=(problem.n_vertices, 3))

    def work(h):
        moved = adjoint.problem_at(problem, problem.mesh.points + h * direction)
        return np.vdot(lam, assemble(moved, x, hessian=False).gradient)

    h = 1e-6
    fd = -(work(h) - work(-h)) / (2 * h)
    # Measured 4e-10 (P1) and 1e-10 (P2) relative.
    assert np.vdot(adjoint.elastic_rest_vjp(problem, x, lam), direction) == pytest.approx(fd, rel=1e-7)


@ORDERS
def test_ball_rest_vjp_matches_central_differences(tiny_mesh, order):
    # The barrier's lumped areas come from the rest top surface; d̂ is large so that
    # every top node is active.
    problem = build_problem(tiny_mesh, stack(), order)
    rng = np.random.default_rng(2)
    x = problem.rest + rng.normal(scale=0.01, size=problem.rest.shape)
    lam, direction = rng.normal(size=x.shape), rng.normal(size=(problem.n_vertices, 3))
    center = np.array([0.5, 0.4, problem.rest[:, 2].max() + 0.7])

    def ball(p):
        nodes, areas = top_surface(p)
        return Ball(center, 0.5, nodes, areas, 1.0, 3.0)

    def work(h):
        b = ball(adjoint.problem_at(problem, problem.mesh.points + h * direction))
        nodes, grad, _ = b.terms(x)
        assert len(nodes) == len(b.nodes)
        return np.vdot(lam[nodes], grad)

    h = 1e-6
    fd = -(work(h) - work(-h)) / (2 * h)
    assert abs(fd) > 1e-3
    got = np.vdot(adjoint.ball_rest_vjp(problem, ball(problem), x, lam), direction)
    assert got == pytest.approx(fd, rel=1e-7)


# --- Taylor tests of whole poses -------------------------------------------------------

STRETCH = [{"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"}]


SCENES = {
    # SMALL_SCENE (two plates, 3 / 0.5 mm edges) pulled by clamps; own 5 mm elastic mesh.
    "stretch": lambda: scene_dict(poses=STRETCH),
    # One 10 mm plate, a 5 mm ball 3 mm deep, ends held (pose 0 is the free rest pose).
    "poke": poke_scene_dict,
    "glue": lambda: glue_scene(1),
    "glue_P2": lambda: glue_scene(2),
    # A biaxial stretch on the electrostatic mesh itself (1 mm outline edges to keep it
    # small); grips on all four edges, so sliding them checks both stretch ratios.
    "shared": lambda: scene_dict(poses=[{"name": "pull", "kind": "stretch", "mode": "biaxial",
                                         "stretch": [1.2, 1.1], "grips": "clamp"}],
                                 elastic={"mesh": "shared"},
                                 mesh={"edge_length_mm": 3.0, "edge_length_outline_mm": 1.0,
                                       "grading_distance_mm": 3.0}),
}


@pytest.fixture(scope="module", params=list(SCENES))
def simulated(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("adjoint") / f"{request.param}.toml"
    path.write_text(to_toml(SCENES[request.param]()))
    scene = load_scene(path)
    # A tight Newton tolerance: the differences below resolve J to ~1e-13.
    scene = dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, tolerance=1e-12))
    return request.param, scene, simulate(scene, keep_factorisation=True)


def smooth_field(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, v: np.ndarray, slide: bool) -> np.ndarray:
    """In-plane ``(N, 3)`` field, the same at every level: ``sin(πs) sin(πt) v`` (zero on the
    box boundary) or, sliding, ``δ_x = sin(πs)(1 + cos(πt)/2) v_x``, ``δ_y`` alike, which
    moves boundary points along their edge (the box, its centre and its edge node sets
    stay the same)."""
    s, t = ((points[:, :2] - lo) / (hi - lo)).T
    delta = np.zeros_like(points)
    if slide:
        delta[:, 0] = np.sin(np.pi * s) * (1 + 0.5 * np.cos(np.pi * t)) * v[0]
        delta[:, 1] = np.sin(np.pi * t) * (1 + 0.5 * np.cos(np.pi * s)) * v[1]
    else:
        delta[:, :2] = (np.sin(np.pi * s) * np.sin(np.pi * t))[:, None] * v
    return delta


@pytest.mark.parametrize("slide", [False, True], ids=["vanishing", "sliding"])
def test_pose_gradient_taylor_and_central_differences(simulated, slide):
    name, scene, sim = simulated
    rng = np.random.default_rng(3)
    weights = rng.uniform(0.5, 1.5, sim.electro.k)
    v = rng.normal(size=2)
    v /= np.linalg.norm(v)
    lo, hi = sim.mesh.mesh2d.points.min(axis=0), sim.mesh.mesh2d.points.max(axis=0)
    fine, elastic = sim.mesh.points, sim.elastic.mesh.points
    # Both meshes' rest points in one vector x, moved together along δ = (δ_fine, δ_elastic).
    x0 = np.concatenate([fine.ravel(), elastic.ravel()])
    delta = np.concatenate([smooth_field(fine, lo, hi, v, slide).ravel(),
                            smooth_field(elastic, lo, hi, v, slide).ravel()])
    for i, result in enumerate(sim.poses):
        g = adjoint.pose_rest_gradient(sim, i, weights, scene.poses[i])
        if sim.transfer is None and result.state is not None:
            assert not g.fine.any()  # shared mesh: everything is in the elastic part
        start = None if result.state is None else result.state.nodes - sim.elastic.rest

        def J(x):
            moved = adjoint.moved(sim, x[:fine.size].reshape(fine.shape), x[fine.size:].reshape(elastic.shape))
            caps, _ = adjoint.solve_moved_pose(moved, scene.poses[i], scene.elastic, start=start)
            return weights @ caps.capacitance_pF

        taylor = taylor_test(J, x0, delta, np.concatenate([g.fine.ravel(), g.elastic.ravel()]),
                             value=weights @ result.capacitance_pF, h0=0.01, halvings=4, central_step=2e-5)
        remainders, steps, slope = taylor.second_order, taylor.steps, taylor.slope
        # First order dominates (a zero gradient would fail here, a wrong one below);
        # measured 1e-6 to 6e-3 (the poke, whose barrier curves the most).
        assert remainders[-1] < 0.05 * abs(steps[-1] * slope), (name, result.name, str(taylor))
        # Measured within 2 ± 0.03, except the poke: 1.87, 1.93, 1.96, 1.98 from h = 0.02
        # mm, within 2 ± 0.07 from 0.01 mm (the barrier's third derivative is large).
        np.testing.assert_allclose(taylor.rates, 2.0, atol=0.2, err_msg=f"{name}/{result.name}:\n{taylor}")
        # Central difference at h = 2e-5: measured 4e-10 to 1.3e-7 relative (the poke's
        # truncation error alone is 4e-7 at h = 1e-4, so h is small).
        assert slope == pytest.approx(taylor.central, rel=1e-5), (name, result.name)


def test_a_gradient_needs_the_kept_factorisation(simulated):
    name, scene, sim = simulated
    i = len(sim.poses) - 1
    lost = dataclasses.replace(sim.poses[i], state=dataclasses.replace(sim.poses[i].state, operator=None))
    sim = dataclasses.replace(sim, poses=sim.poses[:i] + (lost,))
    with pytest.raises(adjoint.AdjointError, match="keep_factorisation"):
        adjoint.pose_rest_gradient(sim, i, np.ones(sim.electro.k), scene.poses[i])


def test_a_factorisation_made_after_the_solve_gives_the_same_gradient(simulated):
    """The optimiser's evaluations keep no factorisation and the gradient factorises each
    pose's Hessian when it needs it (simulate.factorised): assembled again at the
    equilibrium, the Hessian is the one the solve kept, so every pose's rest gradient is the
    same to round-off on every scene (P1, P2, poke, glue, shared mesh)."""
    name, scene, sim = simulated
    weights = np.linspace(0.5, 1.5, sim.electro.k)
    for i, result in enumerate(sim.poses):
        if result.state is None:
            continue
        later = factorised(sim.elastic, scene.poses[i], scene.elastic, dataclasses.replace(result.state, operator=None))
        assert later.operator is not None and later.operator is not result.state.operator
        assert factorised(sim.elastic, scene.poses[i], scene.elastic, later) is later  # done once
        poses = list(sim.poses)
        poses[i] = dataclasses.replace(result, state=later)
        try:
            kept = adjoint.pose_rest_gradient(sim, i, weights, scene.poses[i])
            made = adjoint.pose_rest_gradient(dataclasses.replace(sim, poses=tuple(poses)), i, weights, scene.poses[i])
        finally:
            later.operator.destroy()
        scale = max(np.abs(kept.elastic).max(), np.abs(kept.fine).max())
        np.testing.assert_allclose(made.elastic, kept.elastic, rtol=0, atol=1e-10 * scale, err_msg=f"{name}/{result.name}")
        np.testing.assert_allclose(made.fine, kept.fine, rtol=0, atol=1e-10 * scale, err_msg=f"{name}/{result.name}")
