"""How long a multi-start has left: each task's cost expected from the finished tasks like it.

``elapsed / done × left`` assumes every task left costs what the mean finished one did. A
pruned multi-start is not like that: a start either runs to its end or stops at a rung at
a tenth of the cost (poking_quick: 43–65 s against 5–8 s), a start's cost grows with k, and
the master hands out the largest k first, so what has finished early is no sample of what
is left. :class:`Forecast` expects a start left to cost

    p · F + (1 − p) · P,

``F`` and ``P`` the mean wall times of the finished starts of its k that ran to their end
and that were pruned (else those of the nearest k that has any; before any start was
pruned, ``P`` is what the whole ones took to the first rung, from their histories), ``p``
the share of the finished starts of its initial layout that ran to their end, weighed
against the pruning rule's own share (:func:`prior_share`: ``1/eta``, what a rung keeps)
as :data:`PRIOR_STARTS` starts: Lloyd starts, handed out first and starting best, mostly
run to their end, random ones mostly do not (the paper poking run: 17 of 22 against 1 of
100), and the first whole starts to finish must not say that every start will. A
finer-mesh check is expected like the checks done, else like a start of its k that ran to
its end. A start in flight for ``t`` seconds has the outcomes longer than ``t`` left, less
``t`` (one that has outlived the pruned starts runs to its end). The job's rate is its
workers (the farm keeps them busy: 0.94 of the time on 2 workers, docs/performance.md §4).
``benchmarks/eta_replay.py`` measures the forecasts on a stored run (docs/performance.md §8).
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Iterable

__all__ = ["Forecast", "task_kind", "duration", "prior_share", "first_rung_s", "PRIOR_STARTS"]


def task_kind(task) -> tuple[str, int]:
    """``("start", k)`` of a start, ``("check", k)`` of a finer-mesh check (a task with a
    stored ``record``)."""
    record = getattr(task, "record", None)
    if record is not None:
        return "check", int(record.k)
    return "start", int(task.k)


#: Weight, in starts, of the pruning rule's own share of starts that run to their end
#: (:func:`prior_share`) against the share seen so far.
PRIOR_STARTS = 4


def prior_share(rule) -> float:
    """The share of starts expected to run to their end before any was seen: all without
    pruning, ``1/eta`` under a rung rule (what its first rung keeps), half under the
    envelope rule."""
    if rule is None or not rule.enabled:
        return 1.0
    return 0.5 if rule.envelope else 1.0 / rule.eta


def first_rung_s(history, first_step: int) -> float | None:
    """Seconds a start took to its first rung (``time_s`` of the first step with
    ``iteration ≥ first_step``): what a start pruned there costs; ``None`` if it never got
    there."""
    steps = [row for row, event in enumerate(history["event"]) if str(event) == "step"
             and int(history["iteration"][row]) >= first_step]
    return float(history["time_s"][steps[0]]) if steps else None


class Forecast:
    """Seconds left for ``tasks`` (objects with an ``id``; :func:`task_kind` of each) on
    ``workers`` workers under the pruning ``rule`` (a :class:`~mscap.service.pruning.PruneRule`,
    ``None``: none); :meth:`finished` records one task's wall time (s)."""

    def __init__(self, tasks: Iterable, workers: int, rule=None):
        self.workers = max(int(workers), 1)
        self.rule, self.prior = rule, prior_share(rule)
        tasks = list(tasks)
        self.left: dict[str, tuple[str, int]] = {task.id: task_kind(task) for task in tasks}
        self.init: dict[str, str] = {task.id: str(getattr(task, "init", "")) for task in tasks}
        #: wall times by (kind, k, pruned)
        self.walls: dict[tuple[str, int, bool], list[float]] = defaultdict(list)
        #: finished starts by initial layout: [ran to their end, pruned]
        self.count: dict[str, list[int]] = defaultdict(lambda: [0, 0])
        #: seconds to the first rung of the whole starts, by k ("start", k, True)
        self.to_rung: dict[tuple[str, int, bool], list[float]] = defaultdict(list)

    def finished(self, task_id: str, wall_s: float, pruned: bool = False,
                 kind: tuple[str, int] | None = None, history=None, init: str | None = None) -> None:
        """``task_id`` is done after ``wall_s`` seconds of a worker, ``pruned`` or not
        (``kind`` and a start's ``init``: its :func:`task_kind` and initial layout, if it was
        not one of ``tasks``: a run stored by an earlier session); the ``history`` of a
        start that ran to its end says what a start pruned at the first rung costs."""
        if init is not None:
            self.init.setdefault(task_id, init)
        kind = self.left.pop(task_id, kind)
        if kind is None or not math.isfinite(wall_s) or wall_s < 0:
            return
        self.walls[(*kind, bool(pruned))].append(float(wall_s))
        if kind[0] != "start":
            return
        self.count[self.init.get(task_id, "")][bool(pruned)] += 1
        if history is not None and not pruned and self.prior < 1.0 and not self.rule.envelope:
            rung = first_rung_s(history, self.rule.first_step)
            if rung is not None:
                self.to_rung[(*kind, True)].append(rung)

    def _cost(self, kind: str, k: int, pruned: bool, table=None) -> float | None:
        """Mean wall time of the tasks of ``kind`` and ``pruned`` at the nearest k to ``k``
        that has any (both on a tie), from ``table`` (default: the finished tasks)."""
        table = self.walls if table is None else table
        alike = [key for key, walls in table.items() if walls and key[0] == kind and key[2] == pruned]
        if not alike:
            return None
        nearest = min(abs(key[1] - k) for key in alike)
        return _mean([w for key in alike if abs(key[1] - k) == nearest for w in table[key]])

    def outcomes(self, kind: tuple[str, int], init: str = "") -> list[tuple[float, float]]:
        """``[(probability, wall time s)]`` of a task of ``kind`` (a start's initial layout
        ``init``): a start runs to its end or is pruned; empty before any task finished."""
        what, k = kind
        full = self._cost("start", k, False)
        if what == "check":
            cost = self._cost("check", k, False)
            cost = cost if cost is not None else full
            return [] if cost is None else [(1.0, cost)]
        cut = self._cost("start", k, True)
        if cut is None and full is not None and self.prior < 1.0:  # no start pruned yet
            cut = self._cost("start", k, True, self.to_rung)
        if full is None or cut is None:
            cost = full if full is not None else cut
            cost = cost if cost is not None else self._cost("check", k, False)
            return [] if cost is None else [(1.0, cost)]
        ran, stopped = self.count.get(init, (0, 0))
        p = (ran + PRIOR_STARTS * self.prior) / (ran + stopped + PRIOR_STARTS)
        return [(p, full), (1.0 - p, cut)]

    def expected(self, kind: tuple[str, int], elapsed: float = 0.0, init: str = "") -> float | None:
        """Expected wall time (s) still to come of a task of ``kind`` (``init``: a start's
        initial layout) that has run for ``elapsed`` s (0: not started): the outcomes it
        can still have, weighed by their probabilities; ``None`` before any task finished."""
        outcomes = self.outcomes(kind, init)
        if not outcomes:
            return None
        later = [(p, cost - elapsed) for p, cost in outcomes if cost > elapsed and p > 0]
        if not later:  # it has already run longer than any task of its kind
            return 0.0
        return sum(p * rest for p, rest in later) / sum(p for p, _ in later)

    def seconds_left(self, running: dict[str, float] | None = None) -> float | None:
        """Expected wall time (s) until every task left is done: their expected costs
        shared by the workers, and never less than the longest one; ``running`` maps the
        tasks in flight to how long they have run (s). ``None`` while no task has
        finished (nothing to expect from)."""
        running = running or {}
        costs = [self.expected(kind, running.get(tid, 0.0), self.init.get(tid, "")) for tid, kind in self.left.items()]
        if None in costs:
            return None
        return max(sum(costs) / self.workers, max(costs, default=0.0))


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


def duration(seconds: float | None) -> str:
    """``seconds`` for a progress line: ``"42 s"``, ``"17 min"``, ``"3 h 05 min"``, or
    ``"unknown"`` (``None``: nothing to expect from yet)."""
    if seconds is None or not math.isfinite(seconds):
        return "unknown"
    seconds = max(seconds, 0.0)
    if seconds < 100:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 100 else f"{minutes // 60} h {minutes % 60:02d} min"
