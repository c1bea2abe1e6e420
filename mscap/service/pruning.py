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

The rank rule is not safe on every scene: the starts that separate the poses early often
end worst (the score at step 3 is anticorrelated with the final one on some k), so it
pruned the eventual best start of a k on poking_quick and biaxial_quick
(docs/performance.md §8). ``[multistart] prune_rule = "envelope"`` ranks nothing. Every
``prune_first_step`` accepted steps, a start stops when even the largest relative gain a
finished start made from that step to its end, and 10 % more, would leave it below the
best finished start of its k: it is dominated by every path seen so far. Gains are of
the min L1 distance, or of 1/bound (a bound falls as the design improves), and they come
from the finished starts of every k. Replayed on four quick scenes with 8 starts per k,
this rule kept every k's best at 0.54–0.82 of the unpruned cost (0.70–0.94 with repeated
starts skipped alone), where the rank rule cost 0.44–0.52 and lost up to 10.3 % of a k's
best.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mscap.errors import SceneError

__all__ = ["PruneRule", "Verdict", "Rungs", "Envelope", "ENVELOPE_HEADROOM", "rung_values", "score", "score_kind",
           "goodness", "prune_rule", "history_values"]


def score_kind(scene) -> str:
    """The scene's score: the bound, or the read-back estimate (bound ⊕ map noise), when it
    designs for it, else the min L1 distance on
    listed poses, else J (design poses from the family compared in read-out noise)."""
    if scene.optimizer.distance == "readback":
        return "readback"
    if scene.optimizer.distance == "reconstruction":
        return "bound"
    return "min_l1" if scene.optimizer.design_poses == "listed" else "J"


def score(kind: str, J, d, min_l1_pF):
    """A start's score at a rung, lower is better, from its history values (scalars or
    columns): the read-back bound (mm; −d when the objective is the bound), minus the min
    pairwise L1 distance (pF), or J."""
    if kind in ("bound", "readback"):
        return -np.asarray(d, dtype=float)
    if kind == "min_l1":
        return -np.asarray(min_l1_pF, dtype=float)
    return np.asarray(J, dtype=float)


def prune_rule(scene) -> "PruneRule":
    """The scene's rule (``[multistart] prune_*``), checked against its score: the envelope
    rule needs gains, which J (it changes sign) does not have."""
    rule = PruneRule.from_settings(scene.multistart)
    if rule.enabled and rule.envelope and score_kind(scene) == "J":
        raise SceneError(scene.path, "multistart.prune_rule",
                         'the envelope rule compares gains of the min L1 distance or of the read-back bound, but this '
                         'scene is designed by J (design_poses = "family" with distance = "pF"); use prune_rule = '
                         '"rungs"')
    return rule


def goodness(kind: str, value):
    """A score (lower is better, :func:`score`) as a positive quantity whose ratios are
    gains: the min L1 distance (pF), or 1 / bound (1/mm). ``kind`` ``"J"`` has none (J
    changes sign)."""
    value = np.asarray(value, dtype=float)
    if kind == "min_l1":
        return -value
    if kind in ("bound", "readback"):
        return 1.0 / value
    raise ValueError(f"score kind {kind!r} has no goodness: the envelope rule needs min L1 or the bound")


def _score_of(kind: str, good: float) -> float:
    """The score whose :func:`goodness` is ``good``."""
    return -good if kind == "min_l1" else 1.0 / good


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

    def reason(self, rule: "PruneRule") -> str:
        """The stored ``reason`` of a pruned run."""
        if rule.envelope:
            starts = f"{self.peers} finished start{'s' if self.peers != 1 else ''}"
            return (f"pruned at step {self.step}: score {self.score:.6g} above {self.threshold:.6g}, from which the "
                    f"largest gain of {starts} from step {self.step} on, with headroom, would just reach the best "
                    f"finished start of k = {self.k} (envelope rule)")
        return (f"pruned at step {self.step}: score {self.score:.6g} above {self.threshold:.6g}, the best "
                f"{max(self.peers // rule.eta, 1)} of {self.peers} starts of k = {self.k} at that step "
                f"(eta = {rule.eta})")


@dataclass(frozen=True)
class PruneRule:
    """Rungs at ``first_step · eta**i`` accepted steps (``first_step = 0``: never prune);
    keep the best ``1/eta`` at each. With ``envelope``: checkpoints every ``first_step``
    steps, decided by :class:`Envelope` (``eta`` unused)."""

    first_step: int = 0
    eta: int = 3
    envelope: bool = False

    @classmethod
    def from_settings(cls, multistart) -> "PruneRule":
        return cls(multistart.prune_first_step, multistart.prune_eta, multistart.prune_rule == "envelope")

    @property
    def enabled(self) -> bool:
        return self.first_step > 0

    def table(self, kind: str) -> "Rungs | Envelope":
        """The master's table for this rule and score kind."""
        return Envelope(self, kind) if self.envelope else Rungs(self)

    def is_rung(self, step: int) -> bool:
        """Is ``step`` (accepted steps so far) a rung?"""
        if not self.enabled or step < self.first_step or step % self.first_step:
            return False
        if self.envelope:
            return True
        ratio = step // self.first_step
        while ratio % self.eta == 0:
            ratio //= self.eta
        return ratio == 1

    def rungs(self, max_step: int) -> list[int]:
        """The rungs up to ``max_step``."""
        if self.envelope:
            return list(range(self.first_step, max_step + 1, self.first_step)) if self.enabled else []
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

    def restore(self, k: int, values: dict[int, float], final: float, pruned: bool) -> None:
        """A run of an earlier session (pruned or not): its rung values join the table."""
        self.add(k, values)

    def finished(self, k: int, values: dict[int, float], final: float) -> None:
        """A start of this session ran to its end: its rung values joined at :meth:`decide`."""

    def decide(self, k: int, step: int, value: float) -> Verdict:
        """The verdict for a start of ``k`` reaching rung ``step`` with ``value``; its value joins
        the table whatever the verdict."""
        verdict = self.rule.verdict(k, step, value, self.values[(k, step)])
        self.values[(k, step)].append(float(value))
        return verdict


#: The envelope rule lets a start gain this much more than any finished path did. Without
#: it the rule lost a k's best start on poking_quick (5.7 %) and wrist_quick (14.6 %): a
#: later start out-gained the few finished before it. 1.05 still lost 3.7 % on poking_quick;
#: 1.1 kept every k's best on poking, biaxial, wrist and glove quick, starts taken largest k
#: first or smallest first (docs/performance.md §8).
ENVELOPE_HEADROOM = 1.1


class Envelope:
    """The master's table for the envelope rule: the finished (not pruned) starts' goodness
    (:func:`goodness`) at each checkpoint and at their end. A start of k at checkpoint
    ``step`` with goodness g goes on unless g · h · G < B, where h is
    :data:`ENVELOPE_HEADROOM`, G the largest gain final / (goodness at ``step``) of the
    finished starts of any k that reached ``step``, at least 1 (a start that already
    reaches B goes on even if every path seen lost some of its metric after ``step``: the
    objective is J, not the metric), and B the best final goodness of the finished starts
    of k. While k has no finished start, or no finished start reached ``step``, every
    start goes on."""

    def __init__(self, rule: PruneRule, kind: str):
        goodness(kind, 1.0)  # the kind has gains
        self.rule, self.kind = rule, kind
        self.runs: list[tuple[int, dict[int, float], float]] = []

    def finished(self, k: int, values: dict[int, float], final: float) -> None:
        """A start ran to its end: its scores at the checkpoints (:func:`rung_values`) and its
        final score."""
        self.runs.append((k, {step: float(goodness(self.kind, v)) for step, v in values.items()},
                          float(goodness(self.kind, final))))

    def restore(self, k: int, values: dict[int, float], final: float, pruned: bool) -> None:
        """A run of an earlier session: only one that ran to its end says how far a path goes."""
        if not pruned:
            self.finished(k, values, final)

    def decide(self, k: int, step: int, value: float) -> Verdict:
        best = [final for kk, _, final in self.runs if kk == k]
        gains = [final / at[step] for _, at, final in self.runs if at.get(step, 0.0) > 0.0]
        if not best or not gains:
            return Verdict(True, k, step, float(value), math.inf, len(gains))
        threshold = _score_of(self.kind, max(best) / (ENVELOPE_HEADROOM * max(max(gains), 1.0)))
        return Verdict(bool(value <= threshold), k, step, float(value), float(threshold), len(gains))


def history_values(rule: PruneRule, kind: str, history) -> tuple[dict[int, float], float]:
    """A stored history's score at each rung and at its end (columns ``iteration``, ``J``,
    ``d``, ``min_l1_pF``, ``event``)."""
    values = score(kind, history["J"], history["d"], history["min_l1_pF"])
    return rung_values(rule, history["iteration"], values, history["event"]), float(values[-1])
