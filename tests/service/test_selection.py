"""Start configurations and the choice of k (docs/hdf5.md, "Selection")."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.geometry.initial import initial_layout
from mscap.service.selection import (SCENE_START_INDEX, RunSummary, StartConfig, choose_k, configurations,
                                     decision_margin, repeated_starts, run_id, select, start_index)

TOL = 0.05


@pytest.fixture
def scene(small_scene_dict, write_scene):
    small_scene_dict["multistart"] = {"k_min": 2, "k_max": 4, "starts_per_k": 5, "lloyd_fraction": 0.2}
    return load_scene(write_scene(small_scene_dict))


def test_configurations(scene):
    configs = configurations(scene)
    assert len(configs) == 3 * 5
    assert [c.k for c in configs] == [2] * 5 + [3] * 5 + [4] * 5
    for k in (2, 3, 4):
        mine = [c for c in configs if c.k == k]
        assert [c.init for c in mine] == ["lloyd"] + ["random"] * 4  # ceil(0.2 · 5) = 1
        assert [c.seed for c in mine] == [k * 1000 + i for i in range(5)]
    assert len({c.id for c in configs}) == len(configs)
    assert configs[0] == StartConfig(2, 2000, "lloyd") and configs[0].id == "k2_s2000_lloyd"


def test_a_scene_start_is_one_more_start_from_the_scene_layout_at_its_k(scene):
    """`[multistart] scene_start`: index 999 of the scene layout's k (2 here), after that k's
    regular starts; none when that k is outside k_min..k_max; `--seeds` keeps it by index."""
    ms = replace(scene.multistart, scene_start=True)
    configs = configurations(replace(scene, multistart=ms))
    assert [c.id for c in configs if c.k == 2][-2:] == ["k2_s2004_random", "k2_s2999_scene"]
    assert len(configs) == 3 * 5 + 1 and start_index(configs[5]) == SCENE_START_INDEX
    assert [start_index(c) for c in configs[:6]] == [0, 1, 2, 3, 4, 999]
    layout = initial_layout(scene, 2, configs[5].seed, "scene")
    assert layout is scene.layout
    outside = replace(ms, k_min=3)
    assert all(c.init != "scene" for c in configurations(replace(scene, multistart=outside)))


@pytest.mark.parametrize("n, fraction, n_lloyd", [(25, 0.2, 5), (2, 0.2, 1), (3, 0.5, 2), (4, 0.0, 0),
                                                   (4, 1.0, 4), (10, 0.3, 3)])
def test_lloyd_count_rounds_up(scene, n, fraction, n_lloyd):
    ms = replace(scene.multistart, k_min=3, k_max=3, starts_per_k=n, lloyd_fraction=fraction)
    configs = configurations(replace(scene, multistart=ms))
    assert [c.init for c in configs] == ["lloyd"] * n_lloyd + ["random"] * (n - n_lloyd)


def test_configurations_depend_only_on_the_scene(small_scene_dict, write_scene, scene):
    """Same scene text, other path: same list; a k range that overlaps gives the same
    starts for the shared k (seeds are a function of (k, index), not of the position in
    the list); the scene's multistart.seed shifts every seed."""
    again = load_scene(write_scene({**small_scene_dict, "multistart": {"k_min": 2, "k_max": 4, "starts_per_k": 5,
                                                                      "lloyd_fraction": 0.2}}, "copy.toml"))
    assert configurations(again) == configurations(scene)
    narrower = replace(scene, multistart=replace(scene.multistart, k_min=3))
    assert configurations(narrower) == [c for c in configurations(scene) if c.k >= 3]
    shifted = configurations(replace(scene, multistart=replace(scene.multistart, seed=7)))
    assert [c.seed - 7_000_000 for c in shifted] == [c.seed for c in configurations(scene)]


def test_too_many_starts(scene):
    with pytest.raises(SceneError, match="starts_per_k"):
        configurations(replace(scene, multistart=replace(scene.multistart, starts_per_k=1000)))


def test_run_id():
    assert run_id(3, 7, "lloyd") == "k3_s0007_lloyd" and run_id(12, 123456, "random") == "k12_s123456_random"


# ------------------------------------------------------------------ choose_k on constructed curves
@pytest.mark.parametrize("name, metrics, chosen", [
    ("rising", [1, 2, 3, 4, 5], 6),                     # never flattens: the largest k
    ("plateau", [1, 2, 3, 3.05, 3.1], 4),               # 3.1 ≤ 1.05 · 3
    ("plateau then late gain", [1, 2, 2.02, 2.05, 3], 6),  # a flat step is not a plateau
    ("falling", [5, 4, 3, 2, 1], 2),                    # more capacitors never help
    ("noisy plateau", [1, 2, 2.9, 3.0, 2.95], 4),       # 3.0 ≤ 1.05 · 2.9
    ("noisy drop after plateau", [1, 2, 3, 2.2, 3.1], 4),  # a dip below does not matter
    ("gain just over tol", [2, 2.1001], 3),
    ("gain exactly tol", [2, 2.1], 2),
    ("single k", [1.7], 2),
    ("flat zero", [0, 0, 0], 2),
])
def test_choose_k(name, metrics, chosen):
    ks = list(range(2, 2 + len(metrics)))
    assert choose_k(ks, metrics, TOL) == chosen, name


def test_choose_k_noisy_random_curves():
    """On saturating curves with multiplicative noise below tol/2, the choice lies on the
    plateau: m(chosen) is within tol of the best m."""
    import numpy as np

    rng = np.random.default_rng(0)
    ks = list(range(2, 12))
    for _ in range(200):
        k0 = rng.integers(2, 10)
        clean = np.minimum(ks, k0).astype(float)
        noisy = clean * (1 + rng.uniform(-0.02, 0.02, len(ks)))
        k = choose_k(ks, noisy, TOL)
        assert noisy[ks.index(k)] * (1 + TOL) >= noisy.max()
        assert k <= k0  # never past the knee: beyond it no value gains > 4 %


def test_choose_k_skips_failed_k():
    assert choose_k([2, 3, 4, 5], [1.0, math.nan, 2.0, 2.05], TOL) == 4
    assert choose_k([2, 3, 4], [math.nan, 3.0, None], TOL) == 3
    assert choose_k([2, 3], [math.nan, math.nan], TOL) is None
    assert choose_k([], [], TOL) is None


def test_choose_k_order_free():
    assert choose_k([4, 2, 3], [3.05, 1.0, 3.0], TOL) == 3


def runs(spec):
    """RunSummary list from {(k, seed): metric or None (failed)}."""
    return [RunSummary(id=run_id(k, s, "random"), k=k, ok=m is not None, metric=math.nan if m is None else m,
                       wall_s=2.0) for (k, s), m in spec.items()]


def test_select_best_per_k_and_chosen_run():
    sel = select(runs({(2, 1): 1.0, (2, 2): 1.4, (3, 1): 3.0, (3, 2): None, (3, 3): 3.0, (4, 1): 3.1,
                       (5, 1): None}), TOL, k_values=range(2, 7))
    assert [s.k for s in sel.per_k] == [2, 3, 4, 5, 6]
    assert [(s.runs_ok, s.runs_failed) for s in sel.per_k] == [(2, 0), (2, 1), (1, 0), (0, 1), (0, 0)]
    assert [s.best_metric for s in sel.per_k] == [1.4, 3.0, 3.1, None, None]
    assert sel.per_k[1].best_run == "k3_s0001_random"  # tie: smallest id
    assert sel.per_k[1].wall_s == 6.0
    assert sel.chosen_k == 3 and sel.chosen_run == "k3_s0001_random" and sel.plateau_reached
    assert sel.runs_total == 7


def test_select_rising_is_not_confirmed():
    """k_max chosen: the advice says how much the best grew from the k below and which
    k_max to try; a confirmed plateau needs no advice."""
    sel = select(runs({(2, 1): 1.0, (3, 1): 2.0}), TOL)
    assert sel.chosen_k == 3 and not sel.plateau_reached
    assert "min L1 grew 100.0 % from k = 2" in sel.advice() and "k_max to 5 (at least 4)" in sel.advice()
    assert select(runs({(2, 1): 1.0, (3, 1): 1.01}), TOL).advice() == ""


def test_select_all_failed():
    sel = select(runs({(2, 1): None, (3, 1): None}), TOL, k_values=[2, 3])
    assert sel.chosen_k is None and sel.chosen_run is None and not sel.plateau_reached
    assert [s.runs_failed for s in sel.per_k] == [1, 1]


def test_select_nothing():
    sel = select([], TOL, k_values=[2, 3])
    assert sel.chosen_k is None and sel.runs_total == 0 and len(sel.per_k) == 2


def test_decision_margin_is_the_closest_decision():
    # 1, 2, 2.05 (tol 0.05) chooses the k of 2: k = 4 stays out by 1.05·2/2.05 − 1, k = 2
    # is left because 2.05 beats it by 2.05/(1.05·1) − 1; the first is the closer one.
    assert choose_k([2, 3, 4], [1.0, 2.0, 2.05], TOL) == 3
    assert decision_margin([2, 3, 4], [1.0, 2.0, 2.05], TOL) == pytest.approx(1.05 * 2 / 2.05 - 1, rel=1e-12)
    # A smaller k beaten narrowly: 1.0 → 1.06 is 0.95 % past 1 + tol.
    assert decision_margin([2, 3], [1.0, 1.06], TOL) == pytest.approx(1.06 / 1.05 - 1, rel=1e-12)
    assert math.isnan(decision_margin([2], [1.0], TOL))


def _checked(metrics: dict, finer: dict) -> list[RunSummary]:
    return [RunSummary(id=run_id(k, 1, "random"), k=k, ok=True, metric=m, wall_s=1.0, finer_metric=finer[k])
            for k, m in metrics.items()]


def test_selection_says_whether_the_finer_mesh_picks_the_same_k():
    # make run's old quick scene: k = 3 beats k = 2 by 6.6 % on its mesh; the finer mesh
    # reads k = 3's metric 13.6 % lower, which puts it below 1.05 × k = 2's: k = 2 there.
    sel = select(_checked({2: 10.0, 3: 10.66}, {2: 10.0, 3: 10.66 / 1.136}), TOL)
    assert sel.chosen_k == 3 and sel.finer_chosen_k == 2 and sel.resolved is False
    assert sel.metric_error == pytest.approx(0.136, rel=1e-12)
    assert sel.weakest == (2, 3) and sel.margin == pytest.approx(10.66 / 10.5 - 1, rel=1e-12)
    # The decision itself on the finer mesh: k = 3 falls short of 1.05 × k = 2 there.
    assert sel.finer_margin == pytest.approx(10.66 / 1.136 / 10.5 - 1, rel=1e-12)
    assert sel.margin_error == pytest.approx(2 * 10.66 / 10.5 * (1 - 1 / 1.136), rel=1e-12)
    assert sel.verdict() == ("not resolved: on the finer mesh the rule picks k = 2; its weakest decision, k = 2 "
                             "against k = 3, holds by 1.5 % (-10.6 % on the finer mesh, error bound 24.3 %)")
    # Same choice on the finer mesh, with margins well above their changes: resolved.
    sel = select(_checked({2: 10.0, 3: 20.0, 4: 20.2}, {2: 10.1, 3: 20.1, 4: 20.1}), TOL)
    assert sel.chosen_k == 3 and sel.finer_chosen_k == 3 and sel.resolved
    assert sel.verdict().startswith("resolved:")
    # An error common to both runs does not move the decision: every metric 1 % high
    # leaves the 1.5 % margin as it is (the sum of the runs' errors, 2 %, would call it
    # marginal).
    sel = select(_checked({2: 10.0, 3: 10.66}, {2: 10.0 / 1.01, 3: 10.66 / 1.01}), TOL)
    assert sel.resolved and sel.margin_error == pytest.approx(0.0, abs=1e-12)
    assert sel.verdict().startswith("resolved:")
    # Errors in opposite directions add: k = 2 reads 1 % low and k = 3 1 % high, so the
    # 1.5 % margin is -0.5 % on the finer mesh, which picks k = 2.
    sel = select(_checked({2: 10.0, 3: 10.66}, {2: 10.0 * 1.01, 3: 10.66 / 1.01}), TOL)
    assert sel.finer_chosen_k == 2 and sel.resolved is False
    assert sel.finer_margin == pytest.approx(10.66 / 1.01 / (1.05 * 10.1) - 1, rel=1e-12)
    # Same k on both meshes, but the finer mesh keeps less than half of the 9.5 % margin:
    # its error bound, twice the change, exceeds it: marginal. Half of it or more: resolved.
    sel = select(_checked({2: 10.0, 3: 11.5}, {2: 10.0, 3: 10.9}), TOL)
    assert sel.chosen_k == 3 == sel.finer_chosen_k
    assert sel.margin == pytest.approx(11.5 / 10.5 - 1, rel=1e-12)
    assert sel.margin_error == pytest.approx(2 * 0.6 / 10.5, rel=1e-12)
    assert sel.verdict().startswith("marginal:")
    assert select(_checked({2: 10.0, 3: 11.5}, {2: 10.0, 3: 11.0}), TOL).verdict().startswith("resolved:")
    # ... and so is a margin that grows past one and a half times itself (make run's old
    # scene: 0.5 % on its mesh, 6.2 % on the finer one).
    sel = select(_checked({2: 0.798089, 3: 0.833586}, {2: 0.700412, 3: 0.692234}), TOL)
    assert sel.chosen_k == 2 == sel.finer_chosen_k and sel.verdict().startswith("marginal:")
    # The weakest decision is the one with the least margin left over its error: the
    # poking_cross paper run's k = 2 read 7.4 % high but is left by 84 %; k = 5 against
    # k = 6 decides (6.5 %, 6.9 % on the finer mesh).
    metrics = {2: 8.30335, 3: 10.9757, 4: 13.9965, 5: 16.064, 6: 15.8352}
    finer = {2: 7.73, 3: 10.47, 4: 13.73, 5: 15.72, 6: 15.44}
    sel = select(_checked(metrics, finer), TOL)
    assert sel.chosen_k == 5 == sel.finer_chosen_k and sel.weakest == (5, 6)
    assert sel.margin == pytest.approx(1.05 * 16.064 / 15.8352 - 1, rel=1e-12)
    assert sel.finer_margin == pytest.approx(1.05 * 15.72 / 15.44 - 1, rel=1e-12)
    assert sel.margin_error == pytest.approx(2 * abs(sel.margin - sel.finer_margin), rel=1e-12)
    assert sel.verdict().startswith("resolved:")  # 6.5 % against 2 × 0.4 %
    # A best run without its check: nothing to compare.
    sel = select(_checked({2: 10.0, 3: 10.66}, {2: 10.0, 3: math.nan}), TOL)
    assert sel.resolved is None and sel.finer_chosen_k is None and sel.verdict().startswith("resolution unknown")


def test_a_choice_by_the_read_back_bound_is_checked_on_the_finer_mesh_bound():
    # The bound's precision 1/b decides: k = 3 (0.50 mm) against k = 4 (0.49 mm, 2 % better,
    # under the 5 % plateau) on the run's mesh; the finer mesh reads k = 4 at 0.45 mm, 11 %
    # better: there the rule picks k = 4.
    def runs(finer):
        return [RunSummary(id=run_id(k, 1, "random"), k=k, ok=True, metric=10.0 * k, wall_s=1.0, bound_mm=b,
                           finer_bound_mm=finer[k]) for k, b in {2: 0.80, 3: 0.50, 4: 0.49}.items()]

    sel = select(runs({2: 0.80, 3: 0.50, 4: 0.45}), TOL)
    assert sel.by_bound and sel.chosen_k == 3 and sel.finer_chosen_k == 4 and sel.resolved is False
    assert sel.metric_error == pytest.approx(0.04 / 0.45, rel=1e-12)
    assert sel.weakest == (3, 4) and sel.margin == pytest.approx(1.05 * 0.49 / 0.50 - 1, rel=1e-12)
    assert sel.finer_margin == pytest.approx(1.05 * 0.45 / 0.50 - 1, rel=1e-12)
    assert sel.verdict().startswith("not resolved: on the finer mesh the rule picks k = 4")
    # A bound that barely moves with the mesh (0.1-0.3 % on glove_quick): resolved.
    sel = select(runs({2: 0.801, 3: 0.5005, 4: 0.4905}), TOL)
    assert sel.chosen_k == 3 == sel.finer_chosen_k and sel.verdict().startswith("resolved:")
    # Files written before the finer bound was stored: unknown, and it says why.
    sel = select(runs({2: math.nan, 3: math.nan, 4: math.nan}), TOL)
    assert sel.resolved is None and sel.verdict() == ("resolution unknown: a best run has no finer-mesh check of "
                                                      "its read-back bound (files before it was stored have none)")


def test_a_read_back_start_stores_its_bound_on_the_finer_mesh():
    """``run_start`` on a scene designed for read-back: the finer-mesh bound is the scene's
    bound of the finer capacitances (wrist_quick, no optimiser step: about 6 s)."""
    from mscap.design.readback import ReconstructionBound, design_poses
    from mscap.service.multistart import run_start

    scene = load_scene("jobs/wrist_quick.toml")
    record = run_start(scene, configurations(scene)[0], 0, 0, None)
    assert record.ok and record.checked, record.error
    bound = ReconstructionBound(design_poses(scene).family, scene.optimizer.tau_mm)
    assert record.finer_bound_mm == bound.value(record.finer_capacitance_pF)
    assert record.bound_mm == bound.value(record.final_capacitance_pF)
    # The bound is a ratio of signal to noise: it moves with the mesh far less than C does.
    assert abs(record.finer_bound_mm - record.bound_mm) / record.bound_mm < 0.5 * record.error_estimate


def _same_plates(a, b, ordered: bool) -> bool:
    if len(a.outlines) != len(b.outlines):
        return False
    key = (lambda layout: list(range(layout.k))) if ordered else \
        (lambda layout: np.lexsort(np.array([o.mean(axis=0) for o in layout.outlines]).T[::-1]))
    return all(np.array_equal(a.outlines[i], b.outlines[j]) for i, j in zip(key(a), key(b)))


def test_repeated_lloyd_starts_are_exact_repeats_and_only_those(scene):
    """Lloyd's relaxation on the 30 × 20 mm sheet ends in few tessellations: of 8 Lloyd
    starts per k, a repeat has the plates of the first start with that layout, in the same
    order (so the same run bit for bit); the starts run are pairwise different; the same
    plates in another order are run (the numbering changes the mesh and the path);
    random starts are never repeats."""
    from mscap.geometry.initial import initial_layout

    ms = replace(scene.multistart, k_min=2, k_max=3, starts_per_k=10, lloyd_fraction=0.8)
    s = replace(scene, multistart=ms)
    configs = configurations(s)
    repeats = repeated_starts(s, configs)
    assert len(repeats) == 5 and all(rid.endswith("_lloyd") for rid in repeats)
    layout = {c.id: initial_layout(s, c.k, c.seed, c.init) for c in configs if c.init == "lloyd"}
    index = {c.id: i for i, c in enumerate(configs)}
    for rid, first in repeats.items():
        assert rid[:3] == first[:3] and index[first] < index[rid] and first not in repeats
        assert _same_plates(layout[rid], layout[first], ordered=True)
    permuted = 0
    for k in (2, 3):
        kept = [v for rid, v in layout.items() if rid.startswith(f"k{k}_") and rid not in repeats]
        assert not any(_same_plates(a, b, ordered=True) for i, a in enumerate(kept) for b in kept[:i])
        permuted += sum(_same_plates(a, b, ordered=False) for i, a in enumerate(kept) for b in kept[:i])
    assert permuted >= 1  # the case the rule keeps exists on this sheet
    # A function of the scene alone: the same answer for any subset asked about later.
    assert repeated_starts(s) == repeats


def test_a_start_without_a_valid_layout_is_left_to_the_worker(scene, monkeypatch):
    """repeated_starts runs in the master: a layout that cannot be made is not a repeat
    (the worker then stores the start as failed, with the reason), never an exception."""
    from mscap.errors import GeometryError
    from mscap.geometry import initial

    def fail(scene, k, seed, init):
        raise GeometryError(f"no valid squares at the Lloyd centroids for k = {k}")
    monkeypatch.setattr(initial, "initial_layout", fail)
    s = replace(scene, multistart=replace(scene.multistart, starts_per_k=4, lloyd_fraction=1.0))
    assert repeated_starts(s) == {}
