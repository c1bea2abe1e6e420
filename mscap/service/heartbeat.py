"""Progress a user can trust: what every busy worker is doing, at a bounded rate.

After each accepted optimiser step a start sends the master a :class:`Progress` (its
pruning question, :mod:`mscap.service.multistart`). The master's :class:`Heartbeat` keeps
the latest one per run and, whenever no progress line has been printed for ``interval``
seconds while starts are running, prints one line for all busy workers::

    ... rank 1 k4_s4000_lloyd: step 7, 0.5122 pF, 35 s; rank 2 k4_s4001_random: setting up, 12 s

(``setting up``: the start has not finished its first step yet, e.g. meshing and the first
evaluation; the seconds count from when the master handed the start out). So a run never
stays silent much longer than ``interval`` (``mscap run --heartbeat``, default
:data:`HEARTBEAT_S`), and the line costs nothing when the finished-run lines are frequent.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["HEARTBEAT_S", "Progress", "Heartbeat"]

#: Longest silence (s) of ``mscap run`` while starts are running.
HEARTBEAT_S = 20.0


@dataclass(frozen=True)
class Progress:
    """A start after an accepted step: its ``run`` id, ``k``, optimiser ``iteration``,
    metric (min pairwise L1, pF), its pruning ``score`` and whether the step is a pruning
    ``rung`` (then the master answers with a verdict); ``kind``, what the score is
    (:func:`mscap.service.pruning.score_kind`: the read-back bound, the min L1 or J)."""

    run: str
    k: int
    iteration: int
    min_l1_pF: float
    score: float
    rung: bool = False
    kind: str = "min_l1"

    @property
    def objective(self) -> str:
        """What the start optimises, as its progress line says it: "bound 0.31 mm",
        "0.51 pF" (min L1) or "J -0.23 (min L1 0.51 pF)"."""
        if self.kind == "bound":
            return f"bound {self.score:.3g} mm"
        if self.kind == "readback":
            return f"read-back {self.score:.3g} mm (bound ⊕ map noise)"
        if self.kind == "J":
            return f"J {self.score:.4g} (min L1 {self.min_l1_pF:.4g} pF)"
        return f"{self.min_l1_pF:.4g} pF"


class Heartbeat:
    """The master's status lines; ``say`` prints one, ``clock`` is ``time.monotonic``
    (a test passes a fake one)."""

    def __init__(self, say: Callable[[str], None] | None, interval: float = HEARTBEAT_S,
                 clock: Callable[[], float] = time.monotonic):
        self._say, self.interval, self.clock = say, interval, clock
        self.last = clock()
        self.latest: dict[str, Progress] = {}
        self.busy: dict[int, tuple[Any, float]] = {}  # the farm's tasks in flight, as last ticked

    def say(self, message: str) -> None:
        """Print ``message`` (a progress line): the silence starts again."""
        if self._say is not None:
            self._say(message)
        self.last = self.clock()

    def update(self, progress: Progress) -> None:
        self.latest[progress.run] = progress

    def line(self, busy: dict[int, tuple[Any, float]]) -> str:
        """One status line for ``busy`` (``{worker: (start config, handed out at)}``)."""
        now, parts = self.clock(), []
        for worker, (task, since) in sorted(busy.items()):
            run = getattr(task, "id", str(task))
            p = self.latest.get(run)
            state = "setting up" if p is None else f"step {p.iteration}, {p.objective}"
            parts.append(f"rank {worker} {run}: {state}, {now - since:.0f} s")
        return "... " + "; ".join(parts)

    def running(self) -> dict[str, float]:
        """Seconds each task in flight has run: ``{task id: s}`` (the ETA's)."""
        now = self.clock()
        return {getattr(task, "id", str(task)): now - since for task, since in self.busy.values()}

    def tick(self, busy: dict[int, tuple[Any, float]]) -> None:
        """Keep ``busy`` (:meth:`running`); print :meth:`line` if starts are running and
        nothing was said for ``interval`` s."""
        self.busy = busy
        if self._say is None or self.interval <= 0 or not busy or self.clock() - self.last < self.interval:
            return
        self.say(self.line(busy))
