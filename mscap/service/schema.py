"""The results file's schema, declared once (``ROOT_ATTRS``, ``RUN_ATTRS``,
``RUN_DATASETS``, ``HISTORY_COLUMNS``, ``SELECTION_ITEMS``; ``docs/hdf5.md`` is written
from it and a test checks the two agree), and :class:`RunRecord`, one finished start as
a worker sends it and the store writes it (:mod:`mscap.service.store`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mscap.design.history import DEFAULT_TERMS, HEAD, HISTORY_FIELDS, TAIL, min_pairwise_l1, pairwise_l1
from mscap.service.accuracy import relative_difference
from mscap.service.selection import RunSummary, run_id

__all__ = ["FORMAT", "SCHEMA_VERSION", "TEMP_PREFIX", "ROOT_ATTRS", "RUN_ATTRS", "RUN_DATASETS", "HISTORY_COLUMNS", "OPTIONAL_HISTORY",
           "history_kind", "stored_terms",
           "SELECTION_ITEMS", "schema_markdown", "RunRecord", "record_from_result", "history_columns", "failed_record",
           "record_bytes",
           "run_summary"]

FORMAT = "mscap-results"
SCHEMA_VERSION = 2  # 2: the finer-mesh error estimate of every run (mscap.service.accuracy)
TEMP_PREFIX = ".tmp_"

# ---------------------------------------------------------------- the schema, once
#: Attributes of the root group ``/``: name → (type, meaning).
ROOT_ATTRS = {
    "format": ("str", f'always "{FORMAT}"'),
    "schema_version": ("int", "version of this layout"),
    "mscap_version": ("str", "mscap version that created the file"),
    "scene_name": ("str", "the scene's name"),
    "scene_path": ("str", "the scene file as given when the file was created"),
    "scene_toml": ("str", "the scene file's full text"),
    "scene_sha256": ("str", "sha256 of scene_toml (Scene.sha256); a rerun must match it"),
    "start_time": ("str", "UTC time the file was created, ISO 8601"),
    "last_open_time": ("str", "UTC time the file was last opened for writing, ISO 8601"),
    "mpi_size": ("int", "number of MPI ranks of the latest session that wrote to it"),
    "sessions": ("int", "number of sessions that wrote to it (1 + resumes)"),
}

#: Attributes of a run group ``/runs/<id>``.
RUN_ATTRS = {
    "k": ("int", "number of capacitors"),
    "seed": ("int", "seed of the initial layout"),
    "init": ("str", '"lloyd" or "random" (or "scene")'),
    "status": ("str", '"ok", "pruned" (stopped at a rung as dominated within its k, mscap.service.pruning; '
                      'its design and history up to there are stored; it counts as finished, not failed, and is '
                      'never the best run of its k) '
                      'or "failed" (its history up to the failure is kept)'),
    "error": ("str", 'error text of a failed run ("" if ok)'),
    "reason": ("str", 'why the optimiser stopped ("" if failed; for a pruned run the rule\'s numbers: step, score, '
                      'threshold, peers, and eta or "envelope rule")'),
    "wall_s": ("float", "wall time of the run on its worker (s)"),
    "iterations": ("int", "accepted optimiser steps (if failed: before the failure)"),
    "rank": ("int", "MPI rank of the worker that ran it (0 without MPI)"),
    "metric_pF": ("float", "final min over pose pairs of the L1 distance of capacitance vectors (NaN if failed)"),
    "error_estimate": ("float", "max relative difference of the final capacitances from the same design's on a "
                                "mesh one level finer (mscap.service.accuracy; NaN if not checked: a run already "
                                "beaten within its k, unless `check_all_runs`)"),
    "finer_metric_pF": ("float", "metric_pF of the final design on that finer mesh (NaN if not checked)"),
    "error_estimate_wall_s": ("float", "wall time of that check (s), not part of wall_s (NaN if not checked)"),
    "cpu_s": ("float", "CPU seconds of the run on its worker, every thread (core-seconds; mscap.service.usage; "
                       "NaN in files written before it was stored)"),
    "error_estimate_cpu_s": ("float", "CPU seconds of the finer-mesh check (NaN if not checked, or not stored)"),
    "peak_rss_mb": ("float", "peak resident memory of the worker during the run and its check (MB; the "
                             "worker's peak so far where the kernel cannot reset it; NaN if not stored)"),
    "bound_mm": ("float", "final read-back bound: soft max over the design family's grid of the Cramér–Rao "
                          "bound on the RMS per-vertex error (mm, mscap.design.readback; with distance = "
                          "\"readback\" that bound ⊕ the calibration map's noise on the grid; NaN without a "
                          "design family)"),
    "initial_bound_mm": ("float", "the same for the initial layout (mm; NaN without a design family)"),
    "finer_bound_mm": ("float", "bound_mm of the final design on the finer mesh of error_estimate (mm; NaN without "
                                "a design family or a check, and in files written before it was stored)"),
}

#: Datasets of a run group (ragged outlines: ``points[offsets[j]:offsets[j+1]]`` is outline j).
RUN_DATASETS = {
    "initial_outline_points_mm": ("float64 (n, 2)", "initial outlines, concatenated (mm)"),
    "initial_outline_offsets": ("int64 (k + 1,)", "start of each initial outline in the points, then n"),
    "final_outline_points_mm": ("float64 (n, 2)", "optimised outlines, concatenated (mm); empty if failed"),
    "final_outline_offsets": ("int64 (k + 1,)", "start of each final outline, then n; [0] if failed"),
    "poses": ("str (n_poses,)", "pose names, the row order of the capacitance tables"),
    "initial_capacitance_pF": ("float64 (n_poses, k)", "capacitance per pose and capacitor, initial layout"),
    "final_capacitance_pF": ("float64 (n_poses, k)", "the same for the optimised layout (0 rows if failed)"),
    "finer_capacitance_pF": ("float64 (n_poses, k)", "the optimised layout on the finer mesh (0 rows if not checked)"),
    "history/<column>": ("one 1-D dataset per column", "the optimiser history, one row per event (below); "
                         "a failed run's up to the failure. Between J and grad_norm, one float64 column per "
                         "term of the run's objective, by the term's name (d, barrier, smoothing by default; "
                         "area with max_plate_area_mm2; a term of the user's own, its name)"),
}

#: History columns a run may lack, read as NaN (and not damaged for that): those added after
#: the first files were written, and the default objective's outline terms (an objective
#: without one has no column of it). The capacitance term ``d`` is always there.
OPTIONAL_HISTORY = ("size_ratio", "error_J", "margin_error_pF") + DEFAULT_TERMS[1:]
#: History columns of the default objective (``mscap.design.history.HISTORY_FIELDS``) and
#: their HDF5 types. Between ``J`` and ``grad_norm`` stand the objective's terms by name
#: (``d``, ``barrier``, ``smoothing`` by default; ``area`` with an area limit; a new term's
#: own name): every column not of ``HEAD``/``TAIL`` is a term, float64.
HISTORY_COLUMNS = {name: ("str" if name == "event" else
                          "int64" if name in ("iteration", "level", "evaluations", "newton_iterations")
                          else "float64") for name in HISTORY_FIELDS}


def history_kind(name: str) -> str:
    """The HDF5 type of history column ``name`` (a term's: float64)."""
    return HISTORY_COLUMNS.get(name, "float64")


def stored_terms(names) -> tuple[str, ...]:
    """The objective terms among history column ``names``, in history order: the default
    objective's first, in their order, then the others sorted (HDF5 lists a group's
    members sorted)."""
    terms = [n for n in names if n not in HEAD + TAIL]
    return tuple(n for n in DEFAULT_TERMS if n in terms) + tuple(sorted(n for n in terms if n not in DEFAULT_TERMS))

#: Items of ``/selection`` (rewritten after every run): datasets are per k, ascending.
SELECTION_ITEMS = {
    "k": ("dataset int64 (n_k,)", "k values"),
    "runs_ok": ("dataset int64 (n_k,)", "runs per k with a design: finished or pruned"),
    "runs_failed": ("dataset int64 (n_k,)", "failed runs per k"),
    "best_metric_pF": ("dataset float64 (n_k,)", "best run's metric per k (NaN if none succeeded)"),
    "best_bound_mm": ("dataset float64 (n_k,)", "best run's read-back bound per k (NaN without a design family)"),
    "best_run": ("dataset str (n_k,)", 'id of the best run per k ("" if none)'),
    "wall_s": ("dataset float64 (n_k,)", "summed wall time of the runs per k (s)"),
    "chosen_k": ("attribute int", "the chosen k (-1 if no run succeeded)"),
    "chosen_run": ("attribute str", 'best run of the chosen k ("" if none)'),
    "plateau_tol": ("attribute float", "the scene's multistart.plateau_tol used"),
    "plateau_reached": ("attribute int", "1 if a larger k with a successful run confirms the plateau"),
    "runs_total": ("attribute int", "runs stored when the selection was written"),
    "rule": ("attribute str", "the rule in words"),
    "finer_chosen_k": ("attribute int", "the k the rule picks from the best runs' finer-mesh metrics (-1: a best "
                       "run unchecked, or chosen by read-back bound)"),
    "resolution": ("attribute str", "what the choice rests on: with calibrated designs the calibrated errors of "
                   "the chosen design, the next best, the objective's own choice and the scene's layout; then "
                   "whether the finer mesh picks the objective's k, with the weakest decision's margin on both "
                   "meshes and its error bound (`Selection.verdict`)"),
    "best_design": ("dataset str (n_k,)", 'best calibrated design per k: a run id (its final layout) or '
                    '"RUN:initial" ("" if not calibrated)'),
    "best_error_mm": ("dataset float64 (n_k,)", "its calibrated read-back error (mm; NaN if not calibrated)"),
    "chosen_design": ("attribute str", 'the chosen layout: chosen_run (its final layout) or "RUN:initial"'),
    "objective_chosen_k": ("attribute int", "the k the objective alone chooses (differs from chosen_k only when "
                           "the choice was made on calibrated error)"),
}

#: Items of ``/calibration``: the designs the multi-start calibrated (:mod:`mscap.service.calibrated`),
#: one row each. Written once every design is scored; deleted when a new run is stored (the
#: next session's end calibrates again; the simulations stay in the cache).
CALIBRATION_ITEMS = {
    "label": ("dataset str (n,)", 'a run id (its final layout), "RUN:initial" or "scene" (the scene\'s own '
                                  'layout: a baseline, never chosen)'),
    "k": ("dataset int64 (n,)", "capacitors"),
    "error_mm": ("dataset float64 (n,)", "calibrated read-back error: the sequence's mean point error, averaged "
                                         "over the noise runs, then over the noise seeds (mm or parameter units; "
                                         "NaN if its family failed to simulate)"),
    "spread_mm": ("dataset float64 (n,)", "standard deviation of that error over the noise seeds"),
    "bound_mm": ("dataset float64 (n,)", "the layout's read-back bound (NaN: none, or the scene layout)"),
    "noise_seeds": ("attribute int64 (n_seeds,)", "the noise seeds (the scene's calibration.noise.seed onwards)"),
    "noise_runs": ("attribute int", "noisy runs per seed"),
    "cache": ("attribute str", "the simulation cache (beside the results file; `mscap calibrate` reuses it)"),
    "wall_s": ("attribute float", "wall time of the session's calibration (s): simulation, fits and scores"),
    "simulation_s": ("attribute float", "summed per-pose simulation wall time of the calibrated families (s, "
                                        "whichever session simulated them)"),
}


def schema_markdown() -> str:
    """The schema as Markdown tables (the body of ``docs/hdf5.md``'s "Schema")."""
    def table(title: str, items: dict) -> str:
        rows = "\n".join(f"| `{name}` | {kind} | {meaning} |" for name, (kind, meaning) in items.items())
        return f"### {title}\n\n| name | type | meaning |\n|---|---|---|\n{rows}\n"
    history = {name: (kind, "see docs/optimize.md") for name, kind in HISTORY_COLUMNS.items()}
    return "\n".join([table("Root attributes (`/`)", ROOT_ATTRS),
                      table("Run attributes (`/runs/<id>`)", RUN_ATTRS),
                      table("Run datasets (`/runs/<id>/...`)", RUN_DATASETS),
                      table("History columns (`/runs/<id>/history/<column>`)", history),
                      table("Selection (`/selection`)", SELECTION_ITEMS),
                      table("Calibrated designs (`/calibration`)", CALIBRATION_ITEMS)])


# ---------------------------------------------------------------- records
def _empty_history() -> dict[str, np.ndarray]:
    return {name: np.array([], dtype=object if kind == "str" else kind) for name, kind in HISTORY_COLUMNS.items()}


@dataclass(frozen=True, eq=False)
class RunRecord:
    """One finished start, as sent from a worker to the master and stored.

    Outlines are tuples of ``(n_j, 2)`` arrays (mm); capacitances ``(n_poses, k)`` (pF);
    ``history`` maps every name of ``HISTORY_FIELDS`` to a 1-D array. A failed run has
    ``status == "failed"``, its ``error`` text, empty final outlines/capacitances and
    its history up to the failure.
    Plain numpy and str only, so it pickles cheaply over MPI.
    """

    k: int
    seed: int
    init: str
    status: str
    error: str = ""
    reason: str = ""
    wall_s: float = 0.0
    iterations: int = 0
    rank: int = 0
    poses: tuple[str, ...] = ()
    initial_outlines: tuple[np.ndarray, ...] = ()
    final_outlines: tuple[np.ndarray, ...] = ()
    initial_capacitance_pF: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    final_capacitance_pF: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    history: dict = field(default_factory=_empty_history)
    finer_capacitance_pF: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    error_estimate_wall_s: float = math.nan
    cpu_s: float = math.nan
    error_estimate_cpu_s: float = math.nan
    peak_rss_mb: float = math.nan
    bound_mm: float = math.nan
    initial_bound_mm: float = math.nan
    finer_bound_mm: float = math.nan

    @property
    def id(self) -> str:
        return run_id(self.k, self.seed, self.init)

    @property
    def ok(self) -> bool:
        """Did the run produce a design (finished or pruned)?"""
        return self.status in ("ok", "pruned")

    @property
    def pruned(self) -> bool:
        return self.status == "pruned"

    @property
    def metric(self) -> float:
        """Final min pairwise L1 distance (pF); NaN if failed."""
        if not self.ok or len(self.final_capacitance_pF) == 0:
            return math.nan
        return min_pairwise_l1(self.final_capacitance_pF)

    @property
    def checked(self) -> bool:
        """Was the final design re-simulated on a finer mesh (:mod:`mscap.service.accuracy`)?"""
        return self.ok and np.size(self.finer_capacitance_pF) > 0

    @property
    def error_estimate(self) -> float:
        """Max relative difference of the final capacitances from the finer mesh's; NaN
        if not checked."""
        return relative_difference(self.final_capacitance_pF, self.finer_capacitance_pF) if self.checked \
            else math.nan

    @property
    def finer_metric_pF(self) -> float:
        """Min pairwise L1 distance on the finer mesh (pF); NaN if not checked."""
        return min_pairwise_l1(self.finer_capacitance_pF) if self.checked else math.nan

    @property
    def signal_error(self) -> float:
        """Largest relative difference of a pose-to-pose L1 distance ‖C_a − C_b‖₁ (the
        signal the objective and the k choice read) from the finer mesh's; NaN if not
        checked. Differences of capacitances carry more relative error than C itself."""
        if not self.checked or len(self.finer_capacitance_pF) < 2:
            return math.nan
        return relative_difference(pairwise_l1(self.final_capacitance_pF), pairwise_l1(self.finer_capacitance_pF))

    @property
    def metric_error(self) -> float:
        """Relative difference of the metric (min pairwise L1) from the finer mesh's; NaN if
        not checked."""
        return abs(self.metric - self.finer_metric_pF) / abs(self.finer_metric_pF) if self.checked else math.nan


def record_from_result(k: int, seed: int, init: str, initial_layout, result, poses, wall_s: float,
                       rank: int = 0) -> RunRecord:
    """A successful ``RunRecord`` from ``mscap.design.optimizer.optimize``'s ``OptimizeResult``.

    ``initial_layout`` is the layout the design was built from; ``poses`` the scene's
    poses (or their names).
    """
    names = tuple(p if isinstance(p, str) else p.name for p in poses)
    history = history_columns(result.history)
    return RunRecord(k=k, seed=seed, init=init, status="ok", reason=str(result.reason), wall_s=float(wall_s),
                     iterations=int(result.iterations), rank=rank, poses=names,
                     initial_outlines=tuple(np.array(o, dtype=float) for o in initial_layout.outlines),
                     final_outlines=tuple(np.array(o, dtype=float) for o in result.layout.outlines),
                     initial_capacitance_pF=np.array(result.initial.capacitance_pF, dtype=float),
                     final_capacitance_pF=np.array(result.evaluation.capacitance_pF, dtype=float),
                     history=history)


def history_columns(records) -> dict[str, np.ndarray]:
    """The stored history (one 1-D array per column: ``HISTORY_COLUMNS``'s, with the
    objective's own terms in place of the default's) of the optimiser's
    :class:`~mscap.design.history.Record` rows."""
    names = records[0].fields if len(records) else HISTORY_FIELDS
    return {name: np.array([r.value(name) for r in records], dtype=object if history_kind(name) == "str"
                           else history_kind(name)) for name in names}


def failed_record(k: int, seed: int, init: str, error: str, wall_s: float, rank: int = 0,
                  initial_layout=None, history=()) -> RunRecord:
    """A failed ``RunRecord`` with its error text (and the initial layout, if one was
    built before the failure, and the optimiser's ``history`` records up to it)."""
    outlines = () if initial_layout is None else tuple(np.array(o, dtype=float) for o in initial_layout.outlines)
    columns = history_columns(history)
    return RunRecord(k=k, seed=seed, init=init, status="failed", error=str(error), wall_s=float(wall_s),
                     iterations=int(history[-1].iteration) if len(history) else 0, history=columns,
                     rank=rank, initial_outlines=outlines, initial_capacitance_pF=np.zeros((0, k)),
                     final_capacitance_pF=np.zeros((0, k)))


def record_bytes(record: RunRecord) -> int:
    """The bytes of a record's data as HDF5 stores them (a variable-length string: its
    text plus a 32-byte heap entry)."""
    arrays = [*record.initial_outlines, *record.final_outlines, record.initial_capacitance_pF,
              record.final_capacitance_pF, record.finer_capacitance_pF]
    strings = [*record.poses, record.error, record.reason, *record.history.get("event", [])]
    numbers = [np.asarray(v).nbytes for n, v in record.history.items() if n != "event"]
    return sum(np.asarray(a).nbytes for a in arrays) + sum(numbers) + sum(len(str(x).encode()) + 32 for x in strings)


def run_summary(record: RunRecord) -> RunSummary:
    """What selection needs of a record (what :func:`run_summaries` reads back of it)."""
    return RunSummary(id=record.id, k=int(record.k), ok=record.status != "failed", metric=float(record.metric),
                      wall_s=float(record.wall_s), bound_mm=float(record.bound_mm), pruned=record.pruned,
                      finer_metric=float(record.finer_metric_pF), finer_bound_mm=float(record.finer_bound_mm))
