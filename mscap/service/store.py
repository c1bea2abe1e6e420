"""The HDF5 results store of the multi-start service (h5py; plain datasets and
attributes only, readable with ``h5ls``/``h5dump``).

The schema is declared once, below (``ROOT_ATTRS``, ``RUN_ATTRS``, ``RUN_DATASETS``,
``HISTORY_COLUMNS``, ``SELECTION_ITEMS``); ``docs/hdf5.md`` is written from it and a
test checks the two agree. Only one process (the master) writes. A run is written
under a temporary name and renamed when complete, then the file is flushed, so a
``kill -9`` leaves at most a temporary group, which ``open_store`` deletes.
"""

from __future__ import annotations

import logging
import math
import tomllib
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from mscap import __version__
from mscap.design.history import min_pairwise_l1, pairwise_l1, HISTORY_FIELDS
from mscap.errors import StoreError
from mscap.scene.loader import read_multistart
from mscap.scene.settings import MultistartSettings
from mscap.service.accuracy import relative_difference
from mscap.service.selection import SELECTION_RULE_BOUND, RunSummary, Selection, select, SELECTION_RULE, run_id

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["StoreError", "RunRecord", "FORMAT", "SCHEMA_VERSION", "ROOT_ATTRS", "RUN_ATTRS",
           "RUN_DATASETS", "HISTORY_COLUMNS", "SELECTION_ITEMS", "TEMP_PREFIX", "open_store", "create_store", "read_store",
           "finished_ids", "write_run", "read_run", "run_summaries", "write_selection", "store_selection",
           "record_from_result", "failed_record", "scene_settings", "schema_markdown"]

log = logging.getLogger(__name__)

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
                      'or "failed"'),
    "error": ("str", 'error text of a failed run ("" if ok)'),
    "reason": ("str", 'why the optimiser stopped ("" if failed; for a pruned run the rule\'s numbers: step, J, '
                      'threshold, peers, eta)'),
    "wall_s": ("float", "wall time of the run on its worker (s)"),
    "iterations": ("int", "accepted optimiser steps (0 if failed)"),
    "rank": ("int", "MPI rank of the worker that ran it (0 without MPI)"),
    "metric_pF": ("float", "final min over pose pairs of the L1 distance of capacitance vectors (NaN if failed)"),
    "error_estimate": ("float", "max relative difference of the final capacitances from the same design's on a "
                                "mesh one level finer (mscap.service.accuracy; NaN if not checked)"),
    "finer_metric_pF": ("float", "metric_pF of the final design on that finer mesh (NaN if not checked)"),
    "error_estimate_wall_s": ("float", "wall time of that check (s), not part of wall_s (NaN if not checked)"),
    "bound_mm": ("float", "final read-back bound: soft max over the design family's grid of the Cramér–Rao "
                          "bound on the RMS per-vertex error (mm, mscap.design.readback; NaN without a design family)"),
    "initial_bound_mm": ("float", "the same for the initial layout (mm; NaN without a design family)"),
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
    "history/<column>": ("one 1-D dataset per column", "the optimiser history, one row per event (below)"),
}

#: History columns (``mscap.design.optimizer.HISTORY_FIELDS``) and their HDF5 types.
HISTORY_COLUMNS = {name: ("str" if name == "event" else
                          "int64" if name in ("iteration", "level", "evaluations", "newton_iterations")
                          else "float64") for name in HISTORY_FIELDS}

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
    "resolution": ("attribute str", "whether the finer mesh picks the same k, with the weakest decision's margin "
                   "and its two runs' metric errors (`Selection.verdict`)"),
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
                      table("Selection (`/selection`)", SELECTION_ITEMS)])


# ---------------------------------------------------------------- records
def _empty_history() -> dict[str, np.ndarray]:
    return {name: np.array([], dtype=object if kind == "str" else kind) for name, kind in HISTORY_COLUMNS.items()}


@dataclass(frozen=True, eq=False)
class RunRecord:
    """One finished start, as sent from a worker to the master and stored.

    Outlines are tuples of ``(n_j, 2)`` arrays (mm); capacitances ``(n_poses, k)`` (pF);
    ``history`` maps every name of ``HISTORY_FIELDS`` to a 1-D array. A failed run has
    ``status == "failed"``, its ``error`` text and empty final outlines/capacitances.
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
    bound_mm: float = math.nan
    initial_bound_mm: float = math.nan

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
    rows = [r.row() for r in result.history]
    history = {name: np.array([row[i] for row in rows], dtype=object if kind == "str" else kind)
               for i, (name, kind) in enumerate(HISTORY_COLUMNS.items())}
    return RunRecord(k=k, seed=seed, init=init, status="ok", reason=str(result.reason), wall_s=float(wall_s),
                     iterations=int(result.iterations), rank=rank, poses=names,
                     initial_outlines=tuple(np.array(o, dtype=float) for o in initial_layout.outlines),
                     final_outlines=tuple(np.array(o, dtype=float) for o in result.layout.outlines),
                     initial_capacitance_pF=np.array(result.initial.capacitance_pF, dtype=float),
                     final_capacitance_pF=np.array(result.evaluation.capacitance_pF, dtype=float),
                     history=history)


def failed_record(k: int, seed: int, init: str, error: str, wall_s: float, rank: int = 0,
                  initial_layout=None) -> RunRecord:
    """A failed ``RunRecord`` with its error text (and the initial layout, if one was
    built before the failure)."""
    outlines = () if initial_layout is None else tuple(np.array(o, dtype=float) for o in initial_layout.outlines)
    return RunRecord(k=k, seed=seed, init=init, status="failed", error=str(error), wall_s=float(wall_s),
                     rank=rank, initial_outlines=outlines, initial_capacitance_pF=np.zeros((0, k)),
                     final_capacitance_pF=np.zeros((0, k)))


# ---------------------------------------------------------------- files
def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def create_store(path, source: str, sha256: str, name: str, scene_path: str, mpi_size: int) -> h5py.File:
    """Create (overwrite) a results file for the scene text ``source``; ``open_store``
    and ``mscap merge`` use it."""
    # Default libver (no "latest"): files not closed cleanly carry no open-for-write flag
    # and reopen without h5clear.
    f = h5py.File(path, "w")
    now = _now()
    values = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "mscap_version": __version__,
              "scene_name": name, "scene_path": scene_path, "scene_toml": source, "scene_sha256": sha256,
              "start_time": now, "last_open_time": now, "mpi_size": int(mpi_size), "sessions": 1}
    assert set(values) == set(ROOT_ATTRS)
    f.attrs.update(values)
    f.create_group("runs")
    f.flush()
    return f


def _check_format(f: h5py.File, path) -> None:
    if f.attrs.get("format") != FORMAT:
        raise StoreError(f"{path}: not an mscap results file (no format = {FORMAT!r} attribute)")


def open_store(path, scene: Scene, mpi_size: int = 1, force: bool = False) -> h5py.File:
    """Create the results file of ``scene``, or reopen it to resume.

    A reopened file must hold the same scene (same ``Scene.sha256``); its half-written
    temporary run groups (from a killed job) are deleted. ``force`` starts over: the
    file is recreated empty. Returns the open, writable ``h5py.File``; close it (or use
    it as a context manager) when done.

    Raises
    ------
    StoreError
        The file holds another scene or is not an mscap results file (and not ``force``).
    """
    path = Path(path)
    args = (path, scene.source, scene.sha256, scene.name, str(scene.path), mpi_size)
    if force or not path.exists():
        return create_store(*args)
    try:
        f = h5py.File(path, "r+")
    except OSError as exc:
        if "temporarily unavailable" in str(exc):
            raise StoreError(f"{path} is open for writing in another process (another mscap run?): "
                             f"{exc}") from None
        if "lock" in str(exc):
            raise StoreError(f"{path}: HDF5 file locking failed ({exc}); on file systems without "
                             "locking set HDF5_USE_FILE_LOCKING=FALSE") from None
        raise StoreError(f"{path}: cannot open as HDF5 ({exc}); use --force to start over") from None
    try:
        _check_format(f, path)
        version = int(f.attrs.get("schema_version", -1))
        if version != SCHEMA_VERSION:
            raise StoreError(f"{path} has schema_version {version}; this mscap writes {SCHEMA_VERSION}: "
                             "use --force to start over or another output file")
        stored = f.attrs["scene_sha256"]
        if stored != scene.sha256:
            raise StoreError(f"{path} holds results of another scene ({f.attrs.get('scene_path', '?')}, "
                             f"sha256 {stored}) than {scene.path} (sha256 {scene.sha256}); "
                             "use --force to start over or another output file")
    except BaseException:
        f.close()
        raise
    runs = f.require_group("runs")
    for name in [n for n in runs if n.startswith(TEMP_PREFIX)]:
        log.warning("%s: dropping half-written run %s", path, name[len(TEMP_PREFIX):])
        del runs[name]
    if TEMP_PREFIX + "selection" in f:
        del f[TEMP_PREFIX + "selection"]
    f.attrs["mpi_size"] = int(mpi_size)
    f.attrs["last_open_time"] = _now()
    f.attrs["sessions"] = int(f.attrs.get("sessions", 1)) + 1
    f.flush()
    return f


def read_store(path) -> h5py.File:
    """Open an existing results file read-only (for inspection and merging).

    Without HDF5 file locking, so a running job's file can be inspected: it shows the
    runs as of the writer's last flush (the writer flushes after every run).
    """
    try:
        f = h5py.File(path, "r", locking=False)
    except OSError as exc:
        raise StoreError(f"{path}: cannot open as HDF5 ({exc})") from None
    try:
        _check_format(f, path)
    except StoreError:
        f.close()
        raise
    return f


def finished_ids(store: h5py.File, failed: bool = True) -> set[str]:
    """Ids of the completely written runs: the ones a resume skips. ``failed=False``
    leaves out the failed ones (``mscap run --retry-failed`` runs them again)."""
    return {name for name in store["runs"] if not name.startswith(TEMP_PREFIX)
            and (failed or store["runs"][name].attrs.get("status") != "failed")}


def _ragged(outlines) -> tuple[np.ndarray, np.ndarray]:
    arrays = [np.asarray(o, dtype=float).reshape(-1, 2) for o in outlines]
    offsets = np.concatenate([[0], np.cumsum([len(a) for a in arrays], dtype=np.int64)]).astype(np.int64)
    points = np.concatenate(arrays) if arrays else np.zeros((0, 2))
    return points, offsets


def _unragged(points: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(points[a:b] for a, b in zip(offsets[:-1], offsets[1:]))


_STR = h5py.string_dtype()


def write_run(store: h5py.File, record: RunRecord) -> str:
    """Write one run (replacing an earlier one of the same id) and flush; returns its id.

    The group is built as ``runs/.tmp_<id>`` and renamed to ``runs/<id>`` once complete,
    so the name ``runs/<id>`` only ever refers to a whole run.
    """
    runs = store["runs"]
    rid = record.id
    temp = TEMP_PREFIX + rid
    if temp in runs:
        del runs[temp]
    g = runs.create_group(temp)
    values = {"k": int(record.k), "seed": int(record.seed), "init": record.init, "status": record.status,
              "error": record.error, "reason": record.reason, "wall_s": float(record.wall_s),
              "iterations": int(record.iterations), "rank": int(record.rank), "metric_pF": record.metric,
              "error_estimate": float(record.error_estimate), "finer_metric_pF": float(record.finer_metric_pF),
              "error_estimate_wall_s": float(record.error_estimate_wall_s), "bound_mm": float(record.bound_mm),
              "initial_bound_mm": float(record.initial_bound_mm)}
    assert set(values) == set(RUN_ATTRS)
    g.attrs.update(values)
    for stage, outlines in (("initial", record.initial_outlines), ("final", record.final_outlines)):
        points, offsets = _ragged(outlines)
        g.create_dataset(f"{stage}_outline_points_mm", data=points)
        g.create_dataset(f"{stage}_outline_offsets", data=offsets)
    g.create_dataset("poses", data=np.array(record.poses, dtype=object), dtype=_STR)
    k = int(record.k)
    for name in ("initial_capacitance_pF", "final_capacitance_pF", "finer_capacitance_pF"):
        g.create_dataset(name, data=np.asarray(getattr(record, name), dtype=float).reshape(-1, k))
    h = g.create_group("history")
    for name, kind in HISTORY_COLUMNS.items():
        column = record.history.get(name, [])
        if kind == "str":
            h.create_dataset(name, data=np.array([str(x) for x in column], dtype=object), dtype=_STR)
        else:
            h.create_dataset(name, data=np.asarray(column, dtype=kind))
    if rid in runs:
        del runs[rid]
    runs.move(temp, rid)
    store.flush()
    return rid


def read_run(store: h5py.File, rid: str) -> RunRecord:
    """The stored run ``rid`` as a ``RunRecord``."""
    runs = store["runs"]
    if rid not in runs or rid.startswith(TEMP_PREFIX):
        known = sorted(finished_ids(store))
        hint = ", ".join(known[:8]) + (", ..." if len(known) > 8 else "")
        raise StoreError(f"{store.filename}: no run {rid!r} (runs: {hint or 'none'})")
    g = runs[rid]
    a = g.attrs
    history = {name: (g["history"][name].asstr()[()].astype(object) if kind == "str"
                      else g["history"][name][()]) for name, kind in HISTORY_COLUMNS.items()}
    return RunRecord(k=int(a["k"]), seed=int(a["seed"]), init=str(a["init"]), status=str(a["status"]),
                     error=str(a["error"]), reason=str(a["reason"]), wall_s=float(a["wall_s"]),
                     iterations=int(a["iterations"]), rank=int(a["rank"]),
                     poses=tuple(g["poses"].asstr()[()]),
                     initial_outlines=_unragged(g["initial_outline_points_mm"][()], g["initial_outline_offsets"][()]),
                     final_outlines=_unragged(g["final_outline_points_mm"][()], g["final_outline_offsets"][()]),
                     initial_capacitance_pF=g["initial_capacitance_pF"][()],
                     final_capacitance_pF=g["final_capacitance_pF"][()], history=history,
                     # schema 1 files have no check: NaN
                     finer_capacitance_pF=g["finer_capacitance_pF"][()] if "finer_capacitance_pF" in g
                     else np.zeros((0, int(a["k"]))),
                     error_estimate_wall_s=float(a.get("error_estimate_wall_s", math.nan)),
                     bound_mm=float(a.get("bound_mm", math.nan)),
                     initial_bound_mm=float(a.get("initial_bound_mm", math.nan)))


def run_summaries(store: h5py.File) -> list[RunSummary]:
    """The attributes selection needs, for every finished run (no datasets read)."""
    out = []
    for rid in sorted(finished_ids(store)):
        a = store["runs"][rid].attrs
        out.append(RunSummary(id=rid, k=int(a["k"]), ok=a["status"] != "failed", metric=float(a["metric_pF"]),
                              wall_s=float(a["wall_s"]), bound_mm=float(a.get("bound_mm", math.nan)),
                              pruned=a["status"] == "pruned",
                              finer_metric=float(a.get("finer_metric_pF", math.nan))))
    return out


def scene_settings(store: h5py.File) -> MultistartSettings:
    """The ``[multistart]`` settings of the stored scene text (defaults filled in)."""
    return read_multistart(tomllib.loads(store.attrs["scene_toml"]).get("multistart", {}),
                           f"{store.filename} (stored scene)")


def store_selection(store: h5py.File) -> Selection:
    """Selection over the store's finished runs, with the stored scene's k range and
    ``plateau_tol`` (what ``write_selection`` should be given after each run)."""
    ms = scene_settings(store)
    return select(run_summaries(store), ms.plateau_tol, range(ms.k_min, ms.k_max + 1))


def write_selection(store: h5py.File, selection: Selection) -> None:
    """Replace ``/selection`` with ``selection`` and flush (built under a temporary name)."""
    temp = TEMP_PREFIX + "selection"
    if temp in store:
        del store[temp]
    g = store.create_group(temp)
    per_k = selection.per_k
    g.create_dataset("k", data=np.array([s.k for s in per_k], dtype=np.int64))
    g.create_dataset("runs_ok", data=np.array([s.runs_ok for s in per_k], dtype=np.int64))
    g.create_dataset("runs_failed", data=np.array([s.runs_failed for s in per_k], dtype=np.int64))
    g.create_dataset("best_metric_pF", data=np.array([math.nan if s.best_metric is None else s.best_metric
                                                      for s in per_k], dtype=float))
    g.create_dataset("best_bound_mm", data=np.array([math.nan if s.best_bound_mm is None else s.best_bound_mm
                                                     for s in per_k], dtype=float))
    g.create_dataset("best_run", data=np.array([s.best_run or "" for s in per_k], dtype=object), dtype=_STR)
    g.create_dataset("wall_s", data=np.array([s.wall_s for s in per_k], dtype=float))
    g.attrs.update({"chosen_k": -1 if selection.chosen_k is None else int(selection.chosen_k),
                    "chosen_run": selection.chosen_run or "", "plateau_tol": float(selection.plateau_tol),
                    "plateau_reached": int(selection.plateau_reached), "runs_total": int(selection.runs_total),
                    "rule": SELECTION_RULE_BOUND if selection.by_bound else SELECTION_RULE,
                    "finer_chosen_k": -1 if selection.finer_chosen_k is None else int(selection.finer_chosen_k),
                    "resolution": selection.verdict()})
    assert set(g) | set(g.attrs) == set(SELECTION_ITEMS)
    if "selection" in store:
        del store["selection"]
    store.move(temp, "selection")
    store.flush()
