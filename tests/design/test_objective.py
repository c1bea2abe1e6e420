"""Objective terms: closed forms, limits, Taylor tests, and the collision-free step bound."""

from __future__ import annotations

import numpy as np
import pytest

from mscap.geometry import polygons as geometry
from mscap.fem.elastic.contact import barrier
from mscap.errors import GeometryError
from mscap.design.objective import (Dissimilarity, LaplacianSmoothing, SeparationBarrier, Sum,
                             Weighted, layout_objective)
from mscap.scene import load_scene
from tests.scenes import check_gradient

SHEET = geometry.square((0.0, 0.0), 40.0)


def brute_dissimilarity(c, tau):
    a, b = np.triu_indices(len(c), 1)
    return -tau * np.log(np.sum(np.exp(-np.sum((c[a] - c[b]) ** 2, axis=1) / tau)))


def min_pair_dist2(c):
    a, b = np.triu_indices(len(c), 1)
    return np.sum((c[a] - c[b]) ** 2, axis=1).min()


# --- dissimilarity -------------------------------------------------------------------

def test_dissimilarity_matches_brute_force_and_bounds():
    rng = np.random.default_rng(0)
    c = 57 + rng.standard_normal((6, 3))
    for tau in (0.3, 1.0, 5.0):
        d = Dissimilarity(tau).value(c)
        assert d == pytest.approx(brute_dissimilarity(c, tau), rel=1e-12)
        low = min_pair_dist2(c)
        assert low - tau * np.log(15) <= d <= low


@pytest.mark.parametrize("scale, tau", [(1e3, 1.0), (1.0, 1e-8)])
def test_dissimilarity_extreme_ratios_give_the_hard_minimum(scale, tau):
    # ‖ΔC‖²/τ ~ 1e6 (the brute-force sum underflows to 0) and τ → 0: d → min ‖C_a − C_b‖².
    rng = np.random.default_rng(1)
    c = 60 + scale * rng.standard_normal((5, 4))
    with np.errstate(divide="ignore"):
        assert np.isinf(brute_dissimilarity(c, tau))
    d, grad = Dissimilarity(tau).value_and_gradient(c)
    low = min_pair_dist2(c)
    assert np.isfinite(d) and d == pytest.approx(low, rel=1e-12)
    a, b = np.unravel_index(np.argmin(np.sum((c[:, None] - c[None]) ** 2, axis=2)
                                      + np.diag(np.full(5, np.inf))), (5, 5))
    hard = np.zeros_like(c)
    hard[a], hard[b] = 2 * (c[a] - c[b]), 2 * (c[b] - c[a])
    np.testing.assert_allclose(grad, hard, rtol=1e-12, atol=1e-12 * np.abs(hard).max())


def test_dissimilarity_gradient():
    rng = np.random.default_rng(2)
    c = 57 + 0.7 * rng.standard_normal((7, 3))
    rates, error = check_gradient(Dissimilarity(0.5), c, rng, 1e-2, geometric=False)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6


# --- separation barrier ----------------------------------------------------------------

def pair_of_squares(separation, size=4.0):
    return [geometry.square((-0.5 * size, 0.0), size),
            geometry.square((0.5 * size + separation, 0.0), size)]


def test_barrier_is_zero_beyond_gap_plus_dhat():
    term = SeparationBarrier(SHEET, gap_mm=1.0, dhat_mm=0.5)
    value, grad = term.value_and_gradient(pair_of_squares(1.5))
    assert value == 0 and all(np.all(g == 0) for g in grad)
    assert term.value(pair_of_squares(1.5 - 1e-9)) > 0


def test_barrier_diverges_at_the_min_gap():
    term = SeparationBarrier(SHEET, gap_mm=1.0, dhat_mm=0.5)
    values = [term.value(pair_of_squares(1.0 + s)) for s in (0.25, 1e-2, 1e-4, 1e-8)]
    assert np.all(np.diff(values) > 0) and values[-1] > 10, values
    assert term.value(pair_of_squares(1.0)) == np.inf
    with pytest.raises(GeometryError, match="capacitor 0 .* capacitor 1"):
        term.value_and_gradient(pair_of_squares(0.999))
    # The distance between the edges is the separation; 8 vertex–edge pairs see it (2+2
    # facing edges, and each facing vertex against the adjacent edge through its corner).
    assert values[0] == pytest.approx(8 * barrier(np.array([0.25]), 0.5)[0], rel=1e-12)


def test_barrier_ignores_a_capacitor_s_own_edges():
    # A U whose arms are 0.2 mm apart, far closer than the 1 mm gap.
    u = np.array([[0, 0], [5, 0], [5, 5], [2.6, 5], [2.6, 1], [2.4, 1], [2.4, 5], [0, 5]], float)
    assert SeparationBarrier(SHEET, gap_mm=1.0).value([u]) == 0


def test_barrier_margin_to_the_sheet():
    term = SeparationBarrier(SHEET, gap_mm=1.0, dhat_mm=1.0, margin_mm=2.0)
    near_edge = lambda s: [geometry.square((20.0 - 2.0 - s, 0.0), 4.0)]  # right edge 20 − s
    assert term.value(near_edge(3.0)) == 0
    value, (grad,) = term.value_and_gradient(near_edge(2.5))
    assert value > 0
    assert np.all(grad[[1, 2], 0] > 0)  # descent pulls the right-hand vertices inwards
    assert term.value(near_edge(2.0)) == np.inf


def barrier_scene(rng):
    """Two jittered 24-gons 1.3 mm apart (gap 1, d̂ 1) and one 2.5 mm from the sheet edge
    (margin 2): several active pairs of every kind."""
    def blob(center):
        o = geometry.disk(center, 6.0, 0.8)
        return o + 0.05 * rng.standard_normal(o.shape)
    return [blob((0.0, 0.0)), blob((7.3, 0.5)), blob((0.0, 20.0 - 2.5 - 3.0))]


def test_barrier_gradient():
    rng = np.random.default_rng(3)
    term = SeparationBarrier(SHEET, gap_mm=1.0, dhat_mm=1.0, margin_mm=2.0)
    outlines = barrier_scene(rng)
    assert term.value(outlines) > 0
    rates, error = check_gradient(term, outlines, rng, 1e-3)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6


def pair_distances(outlines, shift_gap, shift_margin):
    """Brute force: shifted distance d − g of every (vertex, edge) of different outlines
    and the sheet, as one flat array in a fixed order."""
    polygons = list(outlines) + [SHEET]
    out = []
    for i, p in enumerate(polygons):
        for j, q in enumerate(polygons):
            if i != j:
                shift = shift_margin if len(polygons) - 1 in (i, j) else shift_gap
                out.append(geometry.point_segment_distance(p, geometry.edges(q)).ravel() - shift)
    return np.concatenate(out)


@pytest.mark.parametrize("seed", range(4))
def test_barrier_value_equals_the_brute_force_sum_over_every_pair(seed):
    """The pair search (a k-d tree per outline) finds every vertex–edge pair within d̂ of
    its gap: the barrier equals the sum over all pairs of outlines and sheet, with finely
    sampled outlines whose own neighbours are many (as after a cascade)."""
    rng = np.random.default_rng(seed)
    gap, margin = 1.0, 0.5
    term = SeparationBarrier(SHEET, gap_mm=gap, margin_mm=margin)
    centers = np.array([[-5.4, 0.0], [0.0, 0.0], [5.4, 0.0], [0.0, 16.8]]) + rng.uniform(-0.2, 0.2, (4, 2))
    outlines = [geometry.disk(c, 4.0, 0.1) for c in centers]  # 2 mm radius, 0.1 mm edges
    shifted = pair_distances(outlines, gap, margin)
    assert shifted.min() > 0 and (shifted < term.dhat_mm).sum() > 100  # many pairs inside d̂
    brute = barrier(shifted[shifted < term.dhat_mm], term.dhat_mm).sum()
    value, _ = term.value_and_gradient(outlines)
    assert value == pytest.approx(brute, rel=1e-12) and term.value(outlines) == pytest.approx(brute, rel=1e-12)


@pytest.mark.parametrize("seed", range(12))
def test_step_bound_never_reaches_contact(seed):
    rng = np.random.default_rng(seed)
    gap, margin, keep = 1.0, 0.5, rng.uniform(0.1, 0.5)
    term = SeparationBarrier(SHEET, gap_mm=gap, margin_mm=margin)
    centers = np.array([[-6.0, 0.0], [0.0, 0.0], [6.0, 0.0], [0.0, 14.0]])
    centers[:, 0] += rng.uniform(-0.3, 0.3, 4)
    outlines = [geometry.disk(c, 4.0, 1.0) for c in centers]
    outlines = [o + 0.1 * rng.standard_normal(o.shape) for o in outlines]
    # Converge on the middle one, the top one towards the sheet edge, plus deformation.
    pull = [np.array([4.0, 0.0]), np.array([0.0, 0.0]), np.array([-4.0, 0.0]), np.array([0.0, 6.0])]
    directions = [t + rng.normal(0, 1.0, o.shape) for t, o in zip(pull, outlines)]
    start = pair_distances(outlines, gap, margin)
    assert start.min() > 0
    bound = term.max_step(outlines, directions, keep)
    moved = lambda a: [o + a * v for o, v in zip(outlines, directions)]
    assert 0 < bound < 1 and pair_distances(moved(1.0), gap, margin).min() < 0
    worst = min(np.min(pair_distances(moved(a), gap, margin) / start)
                for a in np.linspace(0, bound, 41))
    assert worst >= keep * (1 - 1e-9), worst
    for o in moved(bound):
        assert not geometry.self_intersections(o)


def test_step_bound_is_tight_head_on_and_one_when_clear():
    term = SeparationBarrier(SHEET, gap_mm=1.0)
    outlines = pair_of_squares(3.0)
    still, left = np.zeros((4, 2)), np.tile([-2.0, 0.0], (4, 1))
    exact = (1 - 0.2) * (3.0 - 1.0) / 2.0  # shifted gap 2 mm closing at 2 mm per unit α
    bound = term.max_step(outlines, [still, left], keep=0.2)
    assert exact * (1 - 1e-6) <= bound <= exact
    assert term.max_step(outlines, [still, -left], keep=0.2) == 1.0  # moving apart
    assert term.max_step(outlines, [left, left], keep=0.2) == 1.0  # translating together
    assert term.max_step(pair_of_squares(10.0), [still, 0.1 * left]) == 1.0  # nothing near
    # Towards the sheet: its edge is 13 mm from the right square, margin 1, closing at 8 mm per α.
    exact = (1 - 0.5) * (13.0 - 1.0) / 8.0
    bound = term.max_step(outlines, [still, -4 * left], keep=0.5)
    assert exact * (1 - 1e-6) <= bound <= exact


def test_step_bound_sees_fast_approaches_from_afar():
    # Poles 10 mm apart closing at 6 mm per α: target 1 + 0.5·9 mm is reached at α = 0.75,
    # although the vertices are 10 mm apart, far beyond gap + d̂ + the 0.48 mm edges.
    disks = [geometry.disk((-2.0, 0.0), 4.0, 0.5), geometry.disk((12.0, 0.0), 4.0, 0.5)]
    assert np.allclose(disks[0][0], [0.0, 0.0]) and np.allclose(disks[1][len(disks[1]) // 2], [10, 0])
    still, left = np.zeros_like(disks[0]), np.tile([-6.0, 0.0], (len(disks[1]), 1))
    bound = SeparationBarrier(SHEET, gap_mm=1.0).max_step(disks, [still, left], keep=0.5)
    assert 0.75 * (1 - 1e-6) <= bound <= 0.75


def test_step_bound_stops_self_intersection():
    u = np.array([[0, 0], [5, 0], [5, 5], [3, 5], [3, 1], [2, 1], [2, 5], [0, 5]], float)
    closing = np.zeros_like(u)
    closing[[3, 4], 0] = -3.0  # the right arm sweeps through the left one
    bound = SeparationBarrier(SHEET, gap_mm=1.0).max_step([u], [closing], keep=0.1)
    assert bound == pytest.approx(0.9 / 3, rel=1e-6) and bound <= 0.9 / 3
    assert not geometry.self_intersections(u + bound * closing)


def slotted_square(width, spacing=None):
    """A 5 mm square with a slot ``width`` wide cut 4 mm down from its top edge (a U);
    with ``spacing``, every edge split into pieces about that long."""
    half = 0.5 * width
    u = np.array([[0, 0], [5, 0], [5, 5], [2.5 + half, 5], [2.5 + half, 1], [2.5 - half, 1], [2.5 - half, 5],
                  [0, 5]], float)
    if spacing is None:
        return u
    pieces = [np.linspace(a, b, max(1, int(np.ceil(np.linalg.norm(b - a) / spacing))), endpoint=False)
              for a, b in zip(u, np.roll(u, -1, axis=0))]
    return np.vstack(pieces)


def test_a_neck_narrower_than_the_feature_size_is_infeasible_and_a_wider_one_repelled():
    # [optimizer] min_feature_mm: the slot's two sides (a neck of the outline: far apart
    # along it) keep the feature size apart, the barrier acting over one more of it; the
    # slot's bottom corners and the square's own corners are not necks.
    term = SeparationBarrier(SHEET, gap_mm=1.0, feature_mm=0.5)
    assert SeparationBarrier(SHEET, gap_mm=1.0).value([slotted_square(0.2)]) == 0  # off: as before
    assert term.value([slotted_square(0.4)]) == np.inf
    with pytest.raises(GeometryError, match="capacitor 0 has a neck or slot narrower than .*min_feature_mm = 0.5"):
        term.value_and_gradient([slotted_square(0.4)])
    assert term.value([slotted_square(1.01)]) == 0
    assert term.value([geometry.square((0.0, 0.0), 3.0)]) == 0
    # Four pairs see the 0.8 mm slot: each arm's top vertex against the other arm's side
    # and against the top edge beyond it (a vertex near a vertex counts once per incident
    # edge); the bottom vertices are too close to the other side along the outline.
    assert term.value([slotted_square(0.8)]) == pytest.approx(4 * barrier(np.array([0.3]), 0.5)[0], rel=1e-12)
    value, (grad,) = term.value_and_gradient([slotted_square(0.8)])
    assert value > 0 and grad[3, 0] < 0 < grad[6, 0]  # descent opens the slot


def test_neck_barrier_gradient_and_step_bound():
    rng = np.random.default_rng(8)
    term = SeparationBarrier(SHEET, gap_mm=1.0, feature_mm=0.5)
    u = slotted_square(0.8, spacing=0.25)
    u = u + 0.01 * rng.standard_normal(u.shape)
    assert term.value([u]) > 0
    rates, error = check_gradient(term, [u], rng, 1e-3)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6
    # Closing the upper slot at 1 mm per unit α: the bound stops the sides at the feature
    # size plus keep times the rest (0.8 → 0.5 + 0.1 · 0.3): α ≤ 0.27 (the jitter moves it
    # by a few hundredths), where the neck-blind bound (feature 0) lets them touch.
    arm = (u[:, 0] > 2.5) & (u[:, 0] < 4.0) & (u[:, 1] > 2.0)
    closing = np.where(arm[:, None], [-1.0, 0.0], 0.0)
    bound = term.max_step([u], [closing], keep=0.1)
    assert 0.2 < bound <= 0.3
    assert SeparationBarrier(SHEET, gap_mm=1.0).max_step([u], [closing], keep=0.1) > 0.6
    assert term.value([u + bound * closing]) < np.inf


# --- smoothing -------------------------------------------------------------------------

def test_smoothing_of_a_regular_polygon_and_invariances():
    n, r = 12, 3.0
    polygon = r * np.column_stack([np.cos(2 * np.pi * np.arange(n) / n),
                                   np.sin(2 * np.pi * np.arange(n) / n)])
    term = LaplacianSmoothing()
    value = term.value([polygon])
    assert value == pytest.approx(n * r ** 2 * (1 - np.cos(2 * np.pi / n)) ** 2, rel=1e-13)
    rng = np.random.default_rng(4)
    blob = polygon + 0.3 * rng.standard_normal(polygon.shape)
    angle = 0.7
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    s = term.value([blob])
    assert term.value([blob + [5.0, -3.0]]) == pytest.approx(s, rel=1e-12)
    assert term.value([blob @ rotation.T]) == pytest.approx(s, rel=1e-12)
    assert term.value([2.5 * blob]) == pytest.approx(2.5 ** 2 * s, rel=1e-12)
    assert term.value([polygon, blob]) == pytest.approx(value + s, rel=1e-13)
    grad = term.gradient([blob])[0]
    np.testing.assert_allclose(grad.sum(axis=0), 0, atol=1e-12)  # translation invariance
    spike = polygon.copy()
    spike[0] *= 1.5
    assert term.value([spike]) > value


def test_smoothing_gradient():
    rng = np.random.default_rng(5)
    outlines = [geometry.disk((0, 0), 6, 1.0) + 0.1 * rng.standard_normal((19, 2)),
                geometry.square((10, 0), 3)]
    rates, error = check_gradient(LaplacianSmoothing(), outlines, rng, 1e-2)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6


# --- combination -----------------------------------------------------------------------

def test_weighted_sum_from_the_scene(small_scene_dict, write_scene):
    small_scene_dict["optimizer"] = {"tau_pF2": 2.0, "barrier_weight": 3.0, "smoothing_weight": 0.5}
    small_scene_dict["capacitors"]["min_gap_mm"] = 1.5
    scene = load_scene(write_scene(small_scene_dict))
    objective = layout_objective(scene)
    outlines = [np.array(o) for o in scene.layout.outlines]
    outlines[1] = outlines[1] - [2.0, 0.0]  # 2 mm from capacitor 0: the barrier is active
    rng = np.random.default_rng(6)
    c = 57 + rng.standard_normal((4, 2))
    barrier_term = SeparationBarrier(scene.sheet_outline_mm, 1.5)
    b, gb = barrier_term.value_and_gradient(outlines)
    s, gs = LaplacianSmoothing().value_and_gradient(outlines)
    d, gd = Dissimilarity(2.0).value_and_gradient(c)
    assert b > 0 and s > 0
    assert objective.value(c, outlines) == pytest.approx(-d + 3 * b + 0.5 * s, rel=1e-13)
    np.testing.assert_allclose(objective.capacitance.gradient(c), -gd, rtol=1e-13)
    for g, x, y in zip(objective.geometry.gradient(outlines), gb, gs):
        np.testing.assert_allclose(g, 3 * x + 0.5 * y, rtol=1e-13, atol=1e-13)
    assert isinstance(objective.geometry, Sum) and isinstance(objective.capacitance, Weighted)
    rates, error = check_gradient(objective.geometry, outlines, rng, 1e-3)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6
    assert objective.max_step(outlines, [np.zeros_like(o) for o in outlines]) == 1.0


def test_the_feature_size_comes_from_the_scene(small_scene_dict, write_scene):
    from mscap.errors import SceneError

    assert layout_objective(load_scene(write_scene(small_scene_dict))).separation.feature_mm == 0
    small_scene_dict["optimizer"] = {"min_feature_mm": 0.75}
    assert layout_objective(load_scene(write_scene(small_scene_dict))).separation.feature_mm == 0.75
    small_scene_dict["optimizer"] = {"min_feature_mm": -1.0}
    with pytest.raises(SceneError, match=r"optimizer\.min_feature_mm: must be >= 0, got -1.0"):
        load_scene(write_scene(small_scene_dict))
