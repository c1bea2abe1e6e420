"""Pruning dominated starts: asynchronous successive halving within each k.

A multi-start spends most of its time on starts that end far below the best start of
their k. With ``[multistart] prune_first_step = s`` and ``prune_eta = η``, every start
stops at the *rungs* s, sη, sη², … accepted optimiser steps and asks the master. The
master keeps, per k and rung, the score of every start that reached it (those of earlier
sessions are read back from the stored histories). A start continues while its score is
among the best ⌊n/η⌋ of the n starts of its k that reached that rung, itself included.
While fewer than η starts have reached the rung, every start continues. This is the
promotion rule of asynchronous successive halving (ASHA; Li et al., MLSys 2020), applied
to the quantity the k selection ranks runs by (:func:`score`): the read-back bound when the
scene designs for read-back, else the min pairwise L1 distance. Ranking by J instead
pruned the eventual best start of k = 2 on poking_cross_quick: J adds the barrier and
smoothing terms, and it softens the minimum (docs/performance.md §8).

A pruned start is stored with status ``"pruned"``. The record keeps its history up to
that point, its design at that point, and the rule's numbers in ``reason``. Such a run
is finished: a rerun does not repeat it, and it is never counted as failed. It is never
the best run of its k either (it is unfinished, and its finer-mesh check is skipped).
Pruning makes the set of finished runs depend on the order in which starts reach their
rungs, so with pruning a run no longer depends on (k, seed, init) alone. Each pruned run
stores the score, the threshold and the number of peers that decided it.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["PruneRule", "Verdict", "Rungs", "rung_values", "score", "score_kind"]


def score_kind(scene) -> str:
    """The scene's score: the bound when it designs for it, else the min L1 distance on
    listed poses, else J (design poses from the family compared in read-out noise)."""
    if scene.optimizer.distance == "reconstruction":
        return "bound"
    return "min_l1" if scene.optimizer.design_poses == "listed" else "J"


def score(kind: str, J, d, min_l1_pF):
    """A start's score at a rung, lower is better, from its history values (scalars or
    columns): the read-back bound (mm; −d when the objective is the bound), minus the min
    pairwise L1 distance (pF), or J."""
    if kind == "bound":
        return -np.asarray(d, dtype=float)
    if kind == "min_l1":
        return -np.asarray(min_l1_pF, dtype=float)
    return np.asarray(J, dtype=float)


@dataclass(frozen=True)
class Verdict:
    """The master's answer at a rung: ``keep`` going or stop; the start's ``score``
    (lower is better, :func:`score`), the ``threshold`` it had to reach (``inf`` while too
    few peers) and ``peers``, the number of starts of its k at that rung, itself included."""

    keep: bool
    k: int
    step: int
    score: float
    threshold: float
    peers: int

    def reason(self, eta: int) -> str:
        """The stored ``reason`` of a pruned run."""
        return (f"pruned at step {self.step}: score {self.score:.6g} above {self.threshold:.6g}, the best "
                f"{max(self.peers // eta, 1)} of {self.peers} starts of k = {self.k} at that step (eta = {eta})")


@dataclass(frozen=True)
class PruneRule:
    """Rungs at ``first_step · eta**i`` accepted steps (``first_step = 0``: never prune);
    keep the best ``1/eta`` at each."""

    first_step: int = 0
    eta: int = 3

    @classmethod
    def from_settings(cls, multistart) -> "PruneRule":
        return cls(multistart.prune_first_step, multistart.prune_eta)

    @property
    def enabled(self) -> bool:
        return self.first_step > 0

    def is_rung(self, step: int) -> bool:
        """Is ``step`` (accepted steps so far) a rung?"""
        if not self.enabled or step < self.first_step or step % self.first_step:
            return False
        ratio = step // self.first_step
        while ratio % self.eta == 0:
            ratio //= self.eta
        return ratio == 1

    def rungs(self, max_step: int) -> list[int]:
        """The rungs up to ``max_step``."""
        out, step = [], self.first_step
        while self.enabled and step <= max_step:
            out.append(step)
            step *= self.eta
        return out

    def verdict(self, k: int, step: int, value: float, peers: Sequence[float]) -> Verdict:
        """Keep ``value`` if it is among the best ⌊n/η⌋ of ``peers + [value]`` (n of them); keep
        every start while n < η."""
        values = np.sort(np.append(np.asarray(peers, dtype=float), value))
        n = len(values)
        if n < self.eta:
            return Verdict(True, k, step, float(value), math.inf, n)
        threshold = float(values[n // self.eta - 1])
        return Verdict(bool(value <= threshold), k, step, float(value), threshold, n)


def rung_values(rule: PruneRule, iteration: np.ndarray, value: np.ndarray, event: np.ndarray) -> dict[int, float]:
    """The score ``value`` (a history column, e.g. from :func:`score`) at each rung a stored
    history reached: the row of the accepted step (event ``"step"``) whose ``iteration``
    is the rung."""
    iteration, value, event = np.asarray(iteration), np.asarray(value, dtype=float), np.asarray(event).astype(str)
    out = {}
    for step in rule.rungs(int(iteration.max()) if len(iteration) else 0):
        rows = np.flatnonzero((iteration == step) & (event == "step"))
        if len(rows):
            out[step] = float(value[rows[0]])
    return out


class Rungs:
    """The master's table: per (k, rung) the score of every start that reached it."""

    def __init__(self, rule: PruneRule):
        self.rule = rule
        self.values: dict[tuple[int, int], list[float]] = defaultdict(list)

    def add(self, k: int, values: dict[int, float]) -> None:
        """Add a finished run's rung values (e.g. from :func:`rung_values`)."""
        for step, value in values.items():
            self.values[(k, step)].append(value)

    def decide(self, k: int, step: int, value: float) -> Verdict:
        """The verdict for a start of ``k`` reaching rung ``step`` with ``value``; its value joins
        the table whatever the verdict."""
        verdict = self.rule.verdict(k, step, value, self.values[(k, step)])
        self.values[(k, step)].append(float(value))
        return verdict
