"""An optimisation's state between two steps, to stop a start and resume it (issue 49 item 1).

At the top of each of its iterations the optimiser (:func:`mscap.design.optimizer.optimize`)
is fully described by

- **the design**, rebuilt by replaying how it was made: the sheet it was last meshed from
  (the start's layout, a remesh's or a revival's) and the control count per outline that
  build used (``None``: the scene's spacing, as a start builds it), then each control
  refinement of the cascade since, at the ``q`` it was made at
  (:meth:`~mscap.design.pipeline.Design.refined`);
- **the point**: ``q`` and each design pose's equilibrium displacement (the warm start that
  finds the same equilibria again in no Newton iteration);
- **the L-BFGS memory** (its curvature pairs), the steepest-descent step length, the level,
  the step counts, the reason so far, the level's first gradient norm, the fresh mesh's
  angles, the levels whose end tried a revival;
- **what it has recorded**: the history so far and the start's first evaluation (its
  baseline), and its wall time.

:func:`write_state` and :func:`read_state` keep it in an HDF5 group: arrays as datasets,
the rest as attributes and one JSON text for the history. A resumed optimisation
evaluates the design at ``q`` from the kept equilibria, takes the gradient there and goes
on as the uninterrupted one would: the same steps to round-off (the equilibria are found
again from their displacements, ``rest + u``, which need not be bit for bit the nodes the
solver ended on); where the path is chaotic (a remesh's triangulation) round-off can
grow into another path, as between two code versions (docs/results.md).

Not kept: the leads' route of ``[fabrication] route_during_optimisation`` (such a start is
not resumable, :func:`resumable`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields

import numpy as np

from mscap.design.history import Record

__all__ = ["OptimizerState", "write_state", "read_state", "resumable", "STATE_FORMAT"]

#: The group's ``format`` attribute.
STATE_FORMAT = "mscap optimizer state 1"


@dataclass(frozen=True, eq=False)
class OptimizerState:
    """The optimiser between two iterations (module docstring)."""

    #: The layout the design was last meshed from, and the control count per outline of
    #: that build (``None``: the scene's control spacing).
    outlines: tuple[np.ndarray, ...]
    counts: np.ndarray | None
    #: ``q`` of each control refinement since that build, in order.
    cascades: tuple[np.ndarray, ...]
    q: np.ndarray
    #: Per design pose, the equilibrium displacement ``(n_nodes, 3)`` (``None``: a free pose).
    displacements: tuple[np.ndarray | None, ...]
    memory: tuple[tuple[np.ndarray, np.ndarray], ...]
    step_length: float
    level: int
    iteration: int
    level_iterations: int
    reason: str
    level_gradient: float
    fresh: tuple[float, float]
    revived_at: tuple[int, ...]
    history: tuple[Record, ...]
    #: The start's first evaluation: q, J, terms, capacitances (its baseline).
    initial_q: np.ndarray
    initial_J: float
    initial_terms: dict
    initial_capacitance_pF: np.ndarray
    time_s: float


def resumable(scene) -> bool:
    """Can a start of ``scene`` be stopped and resumed? (Not with the leads routed during
    the optimisation: their route is not kept.)"""
    return not scene.fabrication.route_during_optimisation


def _records_json(history) -> str:
    names = [f.name for f in fields(Record) if f.name != "terms"]
    plain = lambda v: v.item() if isinstance(v, np.generic) else v  # noqa: E731
    return json.dumps([{"fields": {name: plain(getattr(r, name)) for name in names},
                        "terms": {key: plain(v) for key, v in r.terms.items()}} for r in history])


def _records(text: str) -> tuple[Record, ...]:
    return tuple(Record(terms=row["terms"], **row["fields"]) for row in json.loads(text))


def write_state(group, state: OptimizerState) -> None:
    """Write ``state`` into the (empty) HDF5 ``group``."""
    group.attrs["format"] = STATE_FORMAT
    for i, outline in enumerate(state.outlines):
        group[f"outlines/{i}"] = outline
    if state.counts is not None:
        group["counts"] = np.asarray(state.counts)
    for i, q in enumerate(state.cascades):
        group[f"cascades/{i}"] = q
    group["q"] = state.q
    for i, u in enumerate(state.displacements):
        if u is not None:
            group[f"displacements/{i}"] = u
    for i, (s, y) in enumerate(state.memory):
        group[f"memory/{i}/s"], group[f"memory/{i}/y"] = s, y
    group["initial_q"] = state.initial_q
    group["initial_capacitance_pF"] = state.initial_capacitance_pF
    group.attrs.update({
        "k": len(state.outlines), "cascade_count": len(state.cascades), "poses": len(state.displacements),
        "memory_pairs": len(state.memory), "step_length": state.step_length, "level": state.level,
        "iteration": state.iteration, "level_iterations": state.level_iterations, "reason": state.reason,
        "level_gradient": state.level_gradient, "fresh": np.asarray(state.fresh, dtype=float),
        "revived_at": np.asarray(state.revived_at, dtype=np.int64), "initial_J": state.initial_J,
        "initial_terms": json.dumps(state.initial_terms), "history": _records_json(state.history),
        "time_s": state.time_s})


def read_state(group) -> OptimizerState:
    """The :class:`OptimizerState` in an HDF5 ``group`` written by :func:`write_state`."""
    a = group.attrs
    k, poses = int(a["k"]), int(a["poses"])
    displacements = tuple(np.asarray(group[f"displacements/{i}"]) if f"displacements/{i}" in group else None
                          for i in range(poses))
    return OptimizerState(
        outlines=tuple(np.asarray(group[f"outlines/{i}"]) for i in range(k)),
        counts=np.asarray(group["counts"]) if "counts" in group else None,
        cascades=tuple(np.asarray(group[f"cascades/{i}"]) for i in range(int(a["cascade_count"]))),
        q=np.asarray(group["q"]), displacements=displacements,
        memory=tuple((np.asarray(group[f"memory/{i}/s"]), np.asarray(group[f"memory/{i}/y"]))
                     for i in range(int(a["memory_pairs"]))),
        step_length=float(a["step_length"]), level=int(a["level"]), iteration=int(a["iteration"]),
        level_iterations=int(a["level_iterations"]), reason=str(a["reason"]),
        level_gradient=float(a["level_gradient"]), fresh=tuple(float(x) for x in a["fresh"]),
        revived_at=tuple(int(x) for x in a["revived_at"]), history=_records(str(a["history"])),
        initial_q=np.asarray(group["initial_q"]), initial_J=float(a["initial_J"]),
        initial_terms=json.loads(str(a["initial_terms"])),
        initial_capacitance_pF=np.asarray(group["initial_capacitance_pF"]), time_s=float(a["time_s"]))

