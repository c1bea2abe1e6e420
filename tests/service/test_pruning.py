"""Pruning dominated starts (asynchronous successive halving, and the envelope rule): the
rules on closed numbers, the optimiser's checkpoint, and ``mscap run --prune`` replayed run
by run from the file."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.loader import with_overrides
from mscap.service.pruning import (ENVELOPE_HEADROOM, Envelope, PruneRule, Rungs, goodness, history_values,
                                   prune_rule, rung_values, score, score_kind)
from mscap.service.store import finished_ids, read_run, read_store
from tests.conftest import to_toml
from tests.service.test_multistart import mscap_run, needs_mpirun, tiny_scene


# ---------------------------------------------------------------- the rule
def test_rungs_are_first_step_times_powers_of_eta():
    rule = PruneRule(first_step=2, eta=3)
    assert rule.rungs(60) == [2, 6, 18, 54]
    assert [s for s in range(1, 60) if rule.is_rung(s)] == [2, 6, 18, 54]
    assert not PruneRule(0, 3).enabled and PruneRule(0, 3).rungs(100) == []
    assert not any(PruneRule(0, 3).is_rung(s) for s in range(10))


def test_verdict_keeps_the_best_third():
    rule = PruneRule(first_step=1, eta=3)
    # Fewer than eta starts at the rung: everyone goes on, with no threshold.
    first = rule.verdict(2, 1, 5.0, [])
    assert first.keep and first.threshold == math.inf and first.peers == 1
    assert rule.verdict(2, 1, 9.0, [5.0]).keep
    # n = 3: keep the best 1; n = 6: the best 2 (J is minimised).
    v = rule.verdict(2, 1, 4.0, [5.0, 3.0])
    assert not v.keep and v.threshold == 3.0 and v.peers == 3
    assert rule.verdict(2, 1, 2.0, [5.0, 3.0]).keep
    v = rule.verdict(3, 3, 1.5, [1.0, 2.0, 3.0, 4.0, 5.0])
    assert v.keep and v.threshold == 1.5 and v.peers == 6
    v = rule.verdict(3, 3, 2.5, [1.0, 2.0, 3.0, 4.0, 5.0])
    assert not v.keep and v.threshold == 2.0
    assert v.reason(rule) == ("pruned at step 3: score 2.5 above 2, the best 2 of 6 starts of k = 3 at that step "
                              "(eta = 3)")


def test_the_table_sees_every_start_per_k_and_rung():
    rungs = Rungs(PruneRule(first_step=1, eta=2))
    assert rungs.decide(2, 1, 1.0).keep and not rungs.decide(2, 1, 2.0).keep
    assert rungs.decide(3, 1, 2.0).keep  # another k: its own table
    assert rungs.values[(2, 1)] == [1.0, 2.0]
    rungs.add(2, {1: 0.5, 2: 0.4})
    assert not rungs.decide(2, 1, 1.5).keep  # best 2 of 4 are 0.5 and 1.0 now


def test_envelope_checkpoints_every_first_step():
    rule = PruneRule(first_step=5, envelope=True)
    assert rule.rungs(22) == [5, 10, 15, 20]
    assert [s for s in range(1, 23) if rule.is_rung(s)] == [5, 10, 15, 20]
    assert isinstance(rule.table("min_l1"), Envelope) and isinstance(PruneRule(5, 3).table("min_l1"), Rungs)


def test_envelope_stops_what_no_finished_path_would_lift_to_the_best():
    # min L1 (pF): the score is −L1. Finished: a k = 2 start 2 → 6.6 pF from step 5 on
    # (gain 3.3), a k = 3 start 4 → 10 pF (gain 2.5). Best of k = 2: 6.6 pF, so at step 5
    # a k = 2 start needs 6.6 / (3.3 h) = 2 / h pF, h the headroom.
    h = ENVELOPE_HEADROOM
    table = Envelope(PruneRule(5, envelope=True), "min_l1")
    assert table.decide(2, 5, -0.1).keep  # nothing finished yet: no verdict
    table.finished(2, {5: -2.0, 10: -6.0}, -6.6)
    table.finished(3, {5: -4.0}, -10.0)
    v = table.decide(2, 5, -0.99 * 2 / h)
    assert not v.keep and v.threshold == pytest.approx(-2 / h) and v.peers == 2
    assert table.decide(2, 5, -1.01 * 2 / h).keep
    # At step 10 only the k = 2 start informs the gain (6.6 / 6 = 1.1): needs 6 / h pF.
    v = table.decide(2, 10, -0.99 * 6 / h)
    assert not v.keep and v.threshold == pytest.approx(-6 / h) and v.peers == 1
    assert table.decide(2, 15, -0.1).keep  # no finished start reached step 15
    assert table.decide(4, 5, -0.1).keep  # k = 4 has no finished start: no best to miss
    table.finished(3, {20: -8.0}, -7.0)  # lost L1 after step 20: the gain counts as 1
    assert table.decide(2, 20, -6.6 / h).keep and not table.decide(2, 20, -0.99 * 6.6 / h).keep
    v = Envelope(PruneRule(5, envelope=True), "min_l1")
    v.finished(2, {10: -5.0}, -5.5)
    verdict = v.decide(2, 10, -4.0)
    assert verdict.reason(PruneRule(5, envelope=True)) == (
        f"pruned at step 10: score -4 above {-5 / h:.6g}, from which the largest gain of 1 finished start from "
        f"step 10 on, with headroom, would just reach the best finished start of k = 2 (envelope rule)")


def test_envelope_on_the_bound_takes_gains_of_its_inverse():
    # A bound falls as the design improves: 0.5 → 0.4 mm is a gain of 1.25 in 1/bound.
    h = ENVELOPE_HEADROOM
    table = Envelope(PruneRule(3, envelope=True), "bound")
    table.finished(2, {3: 0.5}, 0.4)
    v = table.decide(2, 3, 1.01 * 0.5 * h)
    assert not v.keep and v.threshold == pytest.approx(0.5 * h)  # 0.4 × 1.25 × h
    assert table.decide(2, 3, 0.99 * 0.5 * h).keep
    np.testing.assert_allclose(goodness("bound", [0.5, 0.25]), [2.0, 4.0])
    with pytest.raises(ValueError, match="needs min L1 or the bound"):
        Envelope(PruneRule(3, envelope=True), "J")


def test_the_envelope_refuses_a_scene_designed_by_J():
    from dataclasses import replace

    scene = with_overrides(load_scene("jobs/wrist_quick.toml"), prune="envelope")
    assert prune_rule(scene).envelope  # the read-back bound has gains
    by_J = replace(scene, optimizer=replace(scene.optimizer, distance="pF"))
    assert score_kind(by_J) == "J"
    with pytest.raises(SceneError, match='multistart.prune_rule: the envelope rule .* use prune_rule = "rungs"'):
        prune_rule(by_J)
    assert not prune_rule(with_overrides(by_J, prune="3:4")).envelope


def test_a_resumed_envelope_learns_only_from_paths_that_ran_to_their_end():
    rule = PruneRule(1, envelope=True)
    history = {"iteration": np.array([0, 1, 2, 2]), "J": np.zeros(4), "d": np.zeros(4),
               "min_l1_pF": np.array([1.0, 2.0, 4.0, 4.0]),
               "event": np.array(["start", "step", "step", "max_iterations"])}
    values, final = history_values(rule, "min_l1", history)
    assert values == {1: -2.0, 2: -4.0} and final == -4.0
    table = Envelope(rule, "min_l1")
    table.restore(2, values, final, pruned=True)
    assert table.runs == []
    table.restore(2, values, final, pruned=False)
    assert table.runs == [(2, {1: 2.0, 2: 4.0}, 4.0)]
    assert not table.decide(2, 1, -1.9 / ENVELOPE_HEADROOM).keep and table.decide(2, 1, -2.0 / ENVELOPE_HEADROOM).keep


def test_rung_values_read_the_accepted_step_of_each_rung():
    rule = PruneRule(first_step=1, eta=2)
    iteration = np.array([0, 1, 2, 2, 3, 4])
    J = np.array([9.0, 8.0, 7.0, 6.5, 6.0, 5.0])
    event = np.array(["start", "step", "step", "remesh", "step", "step"])
    assert rung_values(rule, iteration, J, event) == {1: 8.0, 2: 7.0, 4: 5.0}


def test_the_score_is_what_selection_ranks_by():
    assert score_kind(load_scene("jobs/wrist_quick.toml")) == "bound"  # designs for read-back
    assert score_kind(load_scene("jobs/poking_cross_quick.toml")) == "min_l1"
    np.testing.assert_array_equal(score("bound", [1.0], [-0.3], [7.0]), [0.3])  # d = −bound
    np.testing.assert_array_equal(score("min_l1", [1.0], [-0.3], [7.0]), [-7.0])
    np.testing.assert_array_equal(score("J", [1.0], [-0.3], [7.0]), [1.0])


def test_settings_and_overrides_are_checked(small_scene_dict, write_scene):
    small_scene_dict["multistart"] = {"prune_first_step": 2, "prune_eta": 1}
    with pytest.raises(SceneError, match="multistart.prune_eta: must be at least 2"):
        load_scene(write_scene(small_scene_dict))
    small_scene_dict["multistart"] = {}
    scene = load_scene(write_scene(small_scene_dict))
    assert scene.multistart.prune_first_step == 0  # off unless asked for
    changed = with_overrides(scene, starts_per_k=8, prune="5:2")
    assert (changed.multistart.starts_per_k, changed.multistart.prune_first_step,
            changed.multistart.prune_eta) == (8, 5, 2)
    with pytest.raises(SceneError, match="--prune expects STEP, STEP:ETA or envelope:EVERY"):
        with_overrides(scene, prune="five")
    envelope = with_overrides(scene, prune="envelope").multistart
    assert (envelope.prune_rule, envelope.prune_first_step) == ("envelope", 5)
    assert with_overrides(scene, prune="envelope:3").multistart.prune_first_step == 3
    assert with_overrides(with_overrides(scene, prune="envelope"), prune="2:3").multistart.prune_rule == "rungs"
    with pytest.raises(SceneError, match="--prune expects"):
        with_overrides(scene, prune="envelope:x")
    with pytest.raises(SceneError, match=r"multistart.prune_first_step: must be >= 0, got -1 \(--prune envelope:-1\)"):
        with_overrides(scene, prune="envelope:-1")
    small_scene_dict["multistart"] = {"prune_rule": "median"}
    with pytest.raises(SceneError, match="multistart.prune_rule: must be one of 'rungs', 'envelope', got 'median'"):
        load_scene(write_scene(small_scene_dict))
    with pytest.raises(SceneError, match="multistart.prune_eta"):
        with_overrides(scene, prune="3:1")


# ---------------------------------------------------------------- the optimiser
def test_a_checkpoint_stops_the_optimiser_as_pruned(tmp_path):
    from mscap.design.optimizer import optimize
    from mscap.design.pipeline import build_design

    path = tmp_path / "tiny.toml"
    path.write_text(to_toml(tiny_scene()))
    seen = []

    def checkpoint(row):
        seen.append((row.iteration, row.J))
        return row.iteration < 2

    result = optimize(build_design(load_scene(path)), max_iterations=5, checkpoint=checkpoint)
    assert result.reason == "pruned" and result.iterations == 2
    assert [s for s, _ in seen] == [1, 2]
    assert result.history[-1].event == "pruned" and result.history[-1].J == seen[-1][1]


# ---------------------------------------------------------------- the service
def replay(store, rule: PruneRule, order: list[str]) -> dict[str, bool]:
    """Every start's verdicts recomputed from the stored histories, in the order the
    starts ran: True where it should have been pruned."""
    rungs, pruned = Rungs(rule), {}
    for rid in order:
        run = store["runs"][rid]
        h = run["history"]
        values = rung_values(rule, h["iteration"][()], score("min_l1", None, None, h["min_l1_pF"][()]),
                             h["event"].asstr()[()])
        pruned[rid] = False
        for step in sorted(values):
            if not rungs.decide(int(run.attrs["k"]), step, values[step]).keep:
                pruned[rid] = True
                break
    return pruned


PRUNED_RUN = ("--k-max", "2", "--prune", "1:2")


def pruned_run(tmp_path, ranks: int, starts: int):
    """``mscap run`` of the tiny scene's k = 2 with ``starts`` starts, pruning from the
    first step with η = 2; returns the scene file and the results file."""
    scene = tmp_path / "tiny.toml"
    scene.write_text(to_toml(tiny_scene()))
    out = tmp_path / "pruned.h5"
    done = mscap_run(ranks, scene, out, *PRUNED_RUN, "--starts-per-k", str(starts))
    assert done.returncode == 0, done.stderr
    return scene, out


def test_one_rank_prunes_exactly_by_the_rule(tmp_path, capsys):
    scene, out = pruned_run(tmp_path, 1, 5)
    store = read_store(out)
    ids = sorted(finished_ids(store), key=lambda rid: int(rid.split("_s")[1].split("_")[0]))
    assert len(ids) == 5
    records = {rid: read_run(store, rid) for rid in ids}
    status = {rid: r.status for rid, r in records.items()}
    # One rank runs the starts in index order: the replay gives the same verdicts.
    expected = replay(store, PruneRule(1, 2), ids)
    assert {rid: s == "pruned" for rid, s in status.items()} == expected
    assert status[ids[0]] == "ok"  # alone at its rungs
    for r in records.values():
        if r.pruned:
            assert r.reason.startswith(f"pruned at step {r.iterations}: score -")  # minus the min L1
            assert r.history["event"][-1] == "pruned" and r.ok and math.isfinite(r.metric)
            assert math.isnan(r.error_estimate)  # no finer-mesh check for a pruned start
        else:
            assert r.reason != "pruned" and math.isfinite(r.error_estimate)
    store.close()
    # A rerun finds nothing to do; --retry-failed does not count pruned starts as failed.
    again = mscap_run(1, scene, out, *PRUNED_RUN, "--starts-per-k", "5", "--retry-failed")
    assert again.returncode == 0 and "5 runs already stored, 0 to do" in again.stderr
    from mscap.cli import main

    assert main(["inspect", str(out), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["per_k"][0]
    assert row["runs_ok"] == 5 and row["runs_failed"] == 0
    assert row["runs_pruned"] == sum(expected.values()) >= 1
    assert status[row["best_run"]] == "ok"  # a pruned start is never the best of its k


@needs_mpirun
def test_three_ranks_ask_the_master_at_their_rungs(tmp_path):
    _, out = pruned_run(tmp_path, 3, 4)
    store = read_store(out)
    records = [read_run(store, rid) for rid in finished_ids(store)]
    store.close()
    assert len(records) == 4 and {r.status for r in records} <= {"ok", "pruned"}
    assert any(not r.pruned for r in records)
    for r in records:
        if r.pruned:  # the stored numbers say why: J above the threshold of its peers
            value, threshold = (float(x) for x in r.reason.split("score ")[1].split(", the best")[0].split(" above "))
            assert value > threshold and value == pytest.approx(-r.history["min_l1_pF"][-1], rel=1e-5)


def test_one_rank_prunes_by_the_envelope_and_resumes_with_it(tmp_path):
    """``--prune envelope:1`` on one rank: every verdict is the master's table replayed in
    index order from the stored histories, and a resumed job (more starts per k) learns
    from the stored paths that ran to their end, as if it had never stopped."""
    scene = tmp_path / "tiny.toml"
    scene.write_text(to_toml(tiny_scene()))
    out = tmp_path / "envelope.h5"
    for starts in (6, 8):
        done = mscap_run(1, scene, out, "--k-max", "2", "--prune", "envelope:1", "--starts-per-k", str(starts))
        assert done.returncode == 0, done.stderr
    store = read_store(out)
    ids = sorted(finished_ids(store), key=lambda rid: int(rid.split("_s")[1].split("_")[0]))
    records = [read_run(store, rid) for rid in ids]
    store.close()
    assert len(records) == 8
    rule = PruneRule(1, envelope=True)
    table, expected = rule.table("min_l1"), []
    for r in records:
        values, final = history_values(rule, "min_l1", r.history)
        verdict = next((v for v in (table.decide(2, s, values[s]) for s in sorted(values)) if not v.keep), None)
        expected.append(verdict is not None)
        if verdict is None:
            table.finished(2, values, final)
        else:
            assert r.reason == verdict.reason(rule) and r.history["event"][-1] == "pruned"
    assert [r.pruned for r in records] == expected
    assert any(expected) and not all(expected)
    best = max(records, key=lambda r: r.metric if not r.pruned else -1.0)
    assert all(r.metric <= best.metric for r in records if r.pruned)  # pruned starts end below the best


@needs_mpirun
def test_three_ranks_prune_by_the_envelope_with_its_numbers(tmp_path):
    """Under ``mpirun -n 3`` the master learns from the starts its workers finish: every
    pruned start's stored score is above the threshold it was told, and no pruned start
    ever stands above the best start of its k that ran to its end."""
    scene = tmp_path / "tiny.toml"
    scene.write_text(to_toml(tiny_scene()))
    out = tmp_path / "envelope3.h5"
    done = mscap_run(3, scene, out, "--k-max", "2", "--prune", "envelope:1", "--starts-per-k", "6")
    assert done.returncode == 0, done.stderr
    store = read_store(out)
    records = [read_run(store, rid) for rid in finished_ids(store)]
    store.close()
    assert len(records) == 6 and {r.status for r in records} <= {"ok", "pruned"}
    best = max(r.metric for r in records if not r.pruned)
    for r in (r for r in records if r.pruned):
        assert r.reason.endswith("(envelope rule)")
        value, threshold = (float(x) for x in r.reason.split("score ")[1].split(", from which")[0].split(" above "))
        assert value > threshold and value == pytest.approx(-r.history["min_l1_pF"][-1], rel=1e-5)
        assert r.metric < best
