"""The multi-start's ETA: each task left expected at the cost of the finished tasks of its k,
a start running to its end or pruned (mscap/service/forecast.py)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from mscap.service.forecast import PRIOR_STARTS, Forecast, duration, first_rung_s, prior_share, task_kind
from mscap.service.pruning import PruneRule
from mscap.service.selection import StartConfig


@dataclass(frozen=True)
class _Check:  # a finer-mesh check task: a stored run's record
    record: StartConfig

    @property
    def id(self) -> str:
        return f"check {self.record.id}"


RULE = PruneRule(3, 4)  # --prune 3:4: the share seen is weighed with 4 starts' worth of 1/4


def _share(ran: int, pruned: int) -> float:
    return (ran + PRIOR_STARTS / 4) / (ran + pruned + PRIOR_STARTS)


def _starts(k: int, lloyd: int, random: int) -> list[StartConfig]:
    return ([StartConfig(k, k * 1000 + i, "lloyd") for i in range(lloyd)]
            + [StartConfig(k, k * 1000 + lloyd + i, "random") for i in range(random)])


def test_task_kinds():
    start = StartConfig(4, 4003, "random")
    assert task_kind(start) == ("start", 4)
    assert task_kind(_Check(start)) == ("check", 4)


def test_the_rules_share_and_the_time_to_its_first_rung():
    assert prior_share(None) == prior_share(PruneRule(0, 4)) == 1.0  # no pruning: every start runs to its end
    assert prior_share(RULE) == 0.25 and prior_share(PruneRule(5, 3, envelope=True)) == 0.5
    history = {"event": ["start", "step", "step", "remesh", "step", "step"], "iteration": [0, 1, 2, 2, 3, 4],
               "time_s": [2.0, 4.0, 6.0, 7.5, 9.0, 11.0]}
    assert first_rung_s(history, 3) == 9.0
    assert first_rung_s(history, 2) == 6.0
    assert first_rung_s(history, 5) is None


def test_before_any_start_is_pruned_the_rule_says_what_one_costs():
    """One start ran to its end in 100 s and reached the first rung (step 3) at 12 s: a start
    left costs 12 s if pruned there, and the rule's own share 1/4, weighed as 4 starts
    against the one seen, says how likely that is."""
    tasks = _starts(4, 1, 3)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    history = {"event": ["start"] + ["step"] * 5, "iteration": list(range(6)),
               "time_s": [3.0, 6.0, 9.0, 12.0, 15.0, 100.0]}
    forecast.finished(tasks[0].id, 100.0, history=history)
    p = (1 + 1) / (1 + 4)
    assert _share(1, 0) == pytest.approx(p, rel=1e-15)
    assert forecast.outcomes(("start", 4), "lloyd") == [(pytest.approx(p, rel=1e-15), 100.0),
                                                        (pytest.approx(1 - p, rel=1e-15), 12.0)]
    assert forecast.outcomes(("start", 4), "random")[0][0] == _share(0, 0) == 0.25  # none seen: the rule's
    forecast.finished(tasks[1].id, 20.0, pruned=True)  # seen: the pruned starts' own cost
    assert forecast.outcomes(("start", 4), "random")[1][1] == 20.0


def test_a_start_either_finishes_or_is_pruned():
    """1 of the 4 finished random starts ran to its end: a random start left costs p of a
    whole start of its k and 1 − p of a pruned one; one worker does them one after another."""
    tasks = _starts(4, lloyd=0, random=8)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    assert forecast.seconds_left() is None  # nothing finished: nothing to expect from
    forecast.finished(tasks[0].id, 100.0)
    for task in tasks[1:4]:
        forecast.finished(task.id, 10.0, pruned=True)
    p, full, cut = _share(1, 3), 100.0, 10.0
    assert forecast.outcomes(("start", 4), "random") == [(pytest.approx(p, rel=1e-15), full),
                                                         (pytest.approx(1 - p, rel=1e-15), cut)]
    assert forecast.seconds_left() == pytest.approx(4 * (p * full + (1 - p) * cut), rel=1e-15)


def test_lloyd_and_random_starts_finish_in_shares_of_their_own():
    """The Lloyd starts, handed out first, ran to their end (2 of 2), the random ones were
    pruned (0 of 3): a Lloyd start left is expected to run to its end far more often."""
    tasks = _starts(4, lloyd=3, random=5)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    for task in tasks[:2]:
        forecast.finished(task.id, 100.0)
    for task in tasks[3:6]:
        forecast.finished(task.id, 10.0, pruned=True)
    lloyd, random = forecast.outcomes(("start", 4), "lloyd"), forecast.outcomes(("start", 4), "random")
    assert lloyd[0][0] == pytest.approx(_share(2, 0), rel=1e-15) and random[0][0] == pytest.approx(_share(0, 3), rel=1e-15)
    expected = (_share(2, 0) * 100 + (1 - _share(2, 0)) * 10) + 2 * (_share(0, 3) * 100 + (1 - _share(0, 3)) * 10)
    assert forecast.seconds_left() == pytest.approx(expected, rel=1e-15)


def test_each_k_costs_what_its_own_starts_cost():
    """Largest k first: k = 3's starts (90 s whole, 9 s pruned) say nothing of k = 2's once
    two of those finished (30 s, 3 s): the two left are expected at a fraction of what
    elapsed / done × left says; before any k = 2 start finished, k = 3's costs stand in."""
    tasks = _starts(3, 0, 2) + _starts(2, 0, 4)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    forecast.finished(tasks[0].id, 90.0)
    forecast.finished(tasks[1].id, 9.0, pruned=True)
    p = _share(1, 1)
    assert forecast.expected(("start", 2), init="random") == pytest.approx(p * 90 + (1 - p) * 9, rel=1e-15)
    forecast.finished(tasks[2].id, 30.0)
    forecast.finished(tasks[3].id, 3.0, pruned=True)
    p = _share(2, 2)
    assert forecast.seconds_left() == pytest.approx(2 * (p * 30 + (1 - p) * 3), rel=1e-15)
    assert forecast.seconds_left() < 0.4 * (90 + 9 + 30 + 3) / 4 * 2  # the old ETA: 66 s


def test_the_nearest_k_stands_in_for_one_not_seen():
    """k = 6 and 2 finished, k = 4 not yet: both are 2 away and both stand in; k = 5 is
    nearest to 6."""
    tasks = _starts(6, 0, 2) + _starts(5, 0, 1) + _starts(4, 0, 1) + _starts(2, 0, 2)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    forecast.finished(tasks[0].id, 300.0)
    forecast.finished(tasks[1].id, 20.0, pruned=True)
    forecast.finished(tasks[4].id, 100.0)
    forecast.finished(tasks[5].id, 10.0, pruned=True)
    p = _share(2, 2)
    assert [cost for _, cost in forecast.outcomes(("start", 4))] == [200.0, 15.0]
    assert [cost for _, cost in forecast.outcomes(("start", 5))] == [300.0, 20.0]
    assert forecast.seconds_left() == pytest.approx(p * 500 + (1 - p) * 35, rel=1e-15)


def test_a_start_in_flight_has_its_remaining_outcomes_left():
    """A start that has run 30 s has outlived every pruned start (20 s): it runs to its end,
    170 s more; at 5 s it may still be pruned."""
    tasks = _starts(3, 0, 3)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    forecast.finished(tasks[0].id, 200.0)
    forecast.finished(tasks[1].id, 20.0, pruned=True)
    p = _share(1, 1)
    assert forecast.expected(("start", 3), elapsed=30.0, init="random") == pytest.approx(170.0, rel=1e-15)
    assert forecast.expected(("start", 3), elapsed=5.0, init="random") == pytest.approx(p * 195 + (1 - p) * 15, rel=1e-15)
    assert forecast.expected(("start", 3), elapsed=250.0, init="random") == 0.0  # longer than any: about to end
    assert forecast.seconds_left({tasks[2].id: 30.0}) == pytest.approx(170.0, rel=1e-15)


def test_workers_share_the_work_but_not_a_task():
    tasks = _starts(3, lloyd=1, random=4)
    forecast = Forecast(tasks, workers=2)
    forecast.finished(tasks[1].id, 30.0)
    forecast.finished(tasks[2].id, 50.0)
    assert forecast.seconds_left() == pytest.approx(3 * 40.0 / 2, rel=1e-15)  # three of 40 s on two workers
    forecast.finished(tasks[3].id, 40.0)
    forecast.finished(tasks[4].id, 40.0)
    assert forecast.seconds_left() == pytest.approx(40.0, rel=1e-15)  # one left: two workers do not halve it
    forecast.finished(tasks[0].id, 40.0)
    assert forecast.seconds_left() == 0.0


def test_a_check_is_expected_like_the_checks_else_like_a_whole_start_of_its_k():
    start = StartConfig(4, 4000, "lloyd")
    check = _Check(start)
    forecast = Forecast([start, StartConfig(4, 4001, "random"), check], workers=1, rule=RULE)
    forecast.finished(start.id, 120.0)
    forecast.finished("k4_s4001_random", 12.0, pruned=True)
    assert forecast.expected(task_kind(check)) == pytest.approx(120.0, rel=1e-15)
    forecast.finished("an earlier check", 30.0, kind=("check", 2))
    assert forecast.expected(task_kind(check)) == pytest.approx(30.0, rel=1e-15)


def test_a_resumed_job_knows_the_runs_it_stored():
    """Runs of an earlier session are not tasks of this one, but say what the tasks left
    cost, as the master feeds them in (mscap.service.multistart)."""
    tasks = _starts(3, 0, 2)
    forecast = Forecast(tasks, workers=1, rule=RULE)
    assert forecast.seconds_left() is None
    forecast.finished("k3_s3005_random", 50.0, kind=("start", 3), init="random")
    forecast.finished("k3_s3006_random", 5.0, pruned=True, kind=("start", 3), init="random")
    p = _share(1, 1)
    assert forecast.seconds_left() == pytest.approx(2 * (p * 50 + (1 - p) * 5), rel=1e-15)
    assert set(forecast.left) == {task.id for task in tasks}


def test_a_failed_wall_time_is_not_a_cost():
    tasks = _starts(2, 0, 3)
    forecast = Forecast(tasks, workers=1)
    forecast.finished(tasks[0].id, float("nan"))
    assert forecast.seconds_left() is None
    forecast.finished(tasks[1].id, 8.0)
    assert forecast.seconds_left() == pytest.approx(8.0, rel=1e-15)


@pytest.mark.parametrize("seconds, text", [(None, "unknown"), (float("nan"), "unknown"), (-3.0, "0 s"),
                                           (42.4, "42 s"), (99.4, "99 s"), (1000.0, "17 min"),
                                           (5999.0, "1 h 40 min"), (11100.0, "3 h 05 min")])
def test_durations_read_as_people_say_them(seconds, text):
    assert duration(seconds) == text
