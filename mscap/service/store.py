"""The HDF5 results store of the multi-start service (h5py; plain datasets and
attributes only, readable with ``h5ls``/``h5dump``).

The schema is declared once, in :mod:`mscap.service.schema` (re-exported here with
:class:`RunRecord`); the checks of a file live in :mod:`mscap.service.checks`. Only one
process (the master) writes, holding the file's lock (:mod:`mscap.outfile`).
Before each run the room it needs is reserved; the run is written under a temporary
name, renamed when complete, then the file is flushed and ``fsync``-ed, so a ``kill -9``
leaves at most a temporary group and a full disk nothing at all; ``open_store`` deletes
the temporary groups and any damaged run (:func:`damaged_runs`). Readers check the file
first (:func:`check_store`).
"""

from __future__ import annotations

import logging
import math
import os
import tomllib
from datetime import datetime, timezone
from typing import TYPE_CHECKING

import h5py
import numpy as np

from mscap import __version__
from mscap.errors import StoreError, StoreFullError
from mscap.scene.loader import read_multistart
from mscap.scene.settings import MultistartSettings
from mscap.infile import dataset_problem, one_line
from mscap.service.checks import MAX_TEXT, check_store, damaged_runs, run_problem
from mscap.outfile import ResultsFile, WriteLock, check_output_path, room_text
from mscap.design.history import DEFAULT_TERMS, history_fields
from mscap.infile import check_regular
from mscap.service.schema import (CALIBRATION_ITEMS, FORMAT, HISTORY_COLUMNS, OPTIONAL_HISTORY, ROOT_ATTRS, RUN_ATTRS,
                                  RUN_DATASETS, SCHEMA_VERSION, SELECTION_ITEMS, TEMP_PREFIX, RunRecord, failed_record,
                                  history_kind, record_bytes, record_from_result, run_summary, schema_markdown,
                                  stored_terms)
from mscap.service.selection import SELECTION_RULE_BOUND, SELECTION_RULE_CALIBRATED, CalibratedDesign, RunSummary, \
    Selection, select, SELECTION_RULE

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["StoreError", "StoreFullError", "RunRecord", "ResultsFile", "check_store", "damaged_runs", "run_problem",
           "run_summary", "record_bytes", "WriteGuard", "FORMAT", "SCHEMA_VERSION", "ROOT_ATTRS", "RUN_ATTRS",
           "RUN_DATASETS", "HISTORY_COLUMNS", "SELECTION_ITEMS", "TEMP_PREFIX", "open_store", "create_store",
           "read_store", "finished_ids", "write_run", "read_run", "run_summaries", "write_selection", "store_selection",
           "record_from_result", "failed_record", "scene_settings", "schema_markdown", "CALIBRATION_ITEMS",
           "write_calibration", "read_calibration", "drop_calibration"]

log = logging.getLogger(__name__)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


#: Bytes a new file needs for its root attributes (the scene text) and ``/runs``, beyond the text.
CREATE_BYTES = 64 * 1024
#: Room reserved for one run beyond twice its data: object headers, attributes, the
#: growth of ``/runs``' index (measured: at most 21 KiB per run and selection rewrite,
#: 600 synthetic runs of k = 2..8; docs/hdf5.md "Writing safely").
RUN_OVERHEAD_BYTES = 64 * 1024
#: Per run already stored: the name index of ``/runs`` may be reallocated at twice its size.
INDEX_BYTES_PER_RUN = 64


class WriteGuard:
    """Turns an HDF5 write failure into a :class:`StoreError` naming the file, what was
    being written and the free space."""

    def __init__(self, store: ResultsFile, what: str):
        self.store, self.what = store, what

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if isinstance(exc, (OSError, RuntimeError)):
            self.store.failed = True
            raise StoreError(f"{self.store.lock.path}: writing {self.what} failed ({one_line(exc)}); "
                             f"{room_text(self.store.lock.path)}") from exc
        return False


def create_store(path, source: str, sha256: str, name: str, scene_path: str, mpi_size: int,
                 force: bool = True) -> ResultsFile:
    """Create (with ``force``: overwrite) a results file for the scene text ``source``;
    ``open_store`` and ``mscap merge`` use it. The file is locked first: one another
    process holds is refused, never truncated.

    Raises
    ------
    StoreError
        ``path`` is a link or a directory, another process holds it, or (without
        ``force``) it exists and is not empty.
    """
    path = check_output_path(path)
    lock = WriteLock(path, force)
    if not (force or lock.empty):
        lock.close()
        raise StoreError(f"{path} exists; use --force to overwrite it")
    return _create(lock, source, sha256, name, scene_path, mpi_size)


def _create(lock: WriteLock, source: str, sha256: str, name: str, scene_path: str, mpi_size: int) -> ResultsFile:
    try:
        f = ResultsFile(lock, "w")
    except OSError as exc:
        lock.remove()
        raise StoreError(f"{lock.path}: cannot create ({one_line(exc)}); {room_text(lock.path)}") from None
    now = _now()
    values = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "mscap_version": __version__,
              "scene_name": name, "scene_path": scene_path, "scene_toml": source, "scene_sha256": sha256,
              "start_time": now, "last_open_time": now, "mpi_size": int(mpi_size), "sessions": 1}
    assert set(values) == set(ROOT_ATTRS)
    try:
        f.make_room(CREATE_BYTES + 2 * len(source.encode()))
        with WriteGuard(f, "a new results file"):
            f.attrs.update(values)
            f.create_group("runs")
            f.commit()
    except BaseException:
        f.discard()
        raise
    return f


def _check_format(f: h5py.File, path) -> None:
    if f.attrs.get("format") != FORMAT:
        raise StoreError(f"{path}: not an mscap results file (no format = {FORMAT!r} attribute)")


def open_store(path, scene: Scene, mpi_size: int = 1, force: bool = False, new_session: bool = True) -> ResultsFile:
    """Create the results file of ``scene``, or reopen it to resume.

    The file is locked before anything is decided: a file another process writes is
    refused (``force`` included) and left untouched. A reopened file must hold the same
    scene (same ``Scene.sha256``); its half-written temporary run groups (from a killed
    job) and its damaged runs (:func:`damaged_runs`) are deleted, so they run again.
    ``force`` starts over: the file is recreated empty. ``new_session=False`` reopens the
    file within the session that opened it (the in-run calibration, after the starts): the
    session's attributes stay. ``path`` follows the rule of
    :func:`~mscap.outfile.check_output_path` (no link; directories created).
    Returns the open, writable :class:`ResultsFile`; close it (or use it as a context
    manager) when done.

    Raises
    ------
    StoreError
        The file holds another scene or is not an mscap results file (and not ``force``),
        another process holds it, or it cannot be written.
    """
    path = check_output_path(path)
    lock = WriteLock(path, force)
    if force or lock.empty:
        return _create(lock, scene.source, scene.sha256, scene.name, str(scene.path), mpi_size)
    try:
        f = ResultsFile(lock, "r+")
    except OSError as exc:
        lock.close()
        raise StoreError(f"{path}: cannot open as HDF5 ({one_line(exc)}); use --force to start over") from None
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
        runs = f.require_group("runs")
        drop = {n: "half-written" for n in runs if n.startswith(TEMP_PREFIX)}
        drop.update(damaged_runs(f))
        f.make_room(RUN_OVERHEAD_BYTES)
        with WriteGuard(f, "the session's attributes"):
            for rid, problem in drop.items():
                log.warning("%s: dropping run %s (%s); it runs again", path, rid.removeprefix(TEMP_PREFIX), problem)
                try:
                    del runs[rid]
                except (KeyError, OSError, RuntimeError):  # its index entry itself is damaged
                    f.close()
                    _rebuild(path, set(drop))
                    return open_store(path, scene, mpi_size, force, new_session)
            for half in (TEMP_PREFIX + "selection", TEMP_PREFIX + "calibration"):
                if half in f:
                    del f[half]
            if new_session:
                f.attrs["mpi_size"] = int(mpi_size)
                f.attrs["last_open_time"] = _now()
                f.attrs["sessions"] = int(f.attrs.get("sessions", 1)) + 1
            f.commit()
    except BaseException:
        f.close()
        raise
    return f


def _rebuild(path, drop: set[str]) -> None:
    """Replace the results file ``path`` by a copy without the runs ``drop`` (damaged so
    that not even their names can be deleted): written beside it, then renamed over it."""
    rebuilt = path.with_name(f".{path.name}.rebuilt")
    with h5py.File(path, "r", locking=False) as old:
        a = old.attrs
        new = create_store(rebuilt, str(a["scene_toml"]), str(a["scene_sha256"]), str(a["scene_name"]),
                           str(a.get("scene_path", "")), int(a.get("mpi_size", 1)))
        try:
            new.attrs.update({name: a[name] for name in ROOT_ATTRS if name in a})
            for rid in sorted(set(finished_ids(old)) - drop):
                new.make_room(2 * RUN_OVERHEAD_BYTES)
                with WriteGuard(new, f"run {rid} into {rebuilt}"):
                    old.copy(old["runs"][rid], new["runs"], name=rid)
            new.commit()
        except BaseException:
            new.discard()
            raise
        new.close()
    os.replace(rebuilt, path)
    log.warning("%s: rebuilt without the damaged runs %s", path, ", ".join(sorted(drop)))


def read_store(path, check: bool = True) -> h5py.File:
    """Open an existing results file read-only (for inspection and merging), after
    checking it (:func:`check_store`) unless ``check`` is False.

    Without HDF5 file locking, so a running job's file can be inspected: it shows the
    runs as of the writer's last flush (the writer flushes after every run).

    Raises
    ------
    StoreError
        Not HDF5, not an mscap results file, a newer schema, or a damaged record (named).
    """
    try:
        check_regular(path, "a results file")  # HDF5 would wait on a FIFO for ever
        f = h5py.File(path, "r", locking=False)
    except ValueError as exc:
        raise StoreError(f"{path}: {exc}") from None
    except OSError as exc:
        raise StoreError(f"{path}: cannot open as HDF5 ({one_line(exc)})") from None
    try:
        _check_format(f, path)
        if check:
            check_store(f, path)
    except BaseException:
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


def _clipped(text: str, limit: int) -> str:
    """``text`` cut to ``limit`` characters (what a reader accepts, mscap.service.checks.MAX_TEXT)."""
    text, tail = str(text), " ... [cut]"
    return text if len(text) <= limit else text[:limit - len(tail)] + tail


def write_run(store: ResultsFile, record: RunRecord) -> str:
    """Write one run (replacing an earlier one of the same id), flush and ``fsync``;
    returns its id.

    Room for it is reserved first (twice its data plus :data:`RUN_OVERHEAD_BYTES`): a disk
    that cannot take it raises :class:`~mscap.errors.StoreFullError` before anything is
    written. The group is built as ``runs/.tmp_<id>`` and renamed to ``runs/<id>`` once
    complete, so the name ``runs/<id>`` only ever refers to a whole run.
    """
    runs = store["runs"]
    rid = record.id
    temp = TEMP_PREFIX + rid
    values = {"k": int(record.k), "seed": int(record.seed), "init": record.init, "status": record.status,
              "error": _clipped(record.error, MAX_TEXT["error"]), "reason": _clipped(record.reason, MAX_TEXT["reason"]),
              "wall_s": float(record.wall_s),
              "iterations": int(record.iterations), "rank": int(record.rank), "metric_pF": record.metric,
              "error_estimate": float(record.error_estimate), "finer_metric_pF": float(record.finer_metric_pF),
              "error_estimate_wall_s": float(record.error_estimate_wall_s), "cpu_s": float(record.cpu_s),
              "error_estimate_cpu_s": float(record.error_estimate_cpu_s),
              "peak_rss_mb": float(record.peak_rss_mb), "bound_mm": float(record.bound_mm),
              "initial_bound_mm": float(record.initial_bound_mm), "finer_bound_mm": float(record.finer_bound_mm)}
    assert set(values) == set(RUN_ATTRS)
    k = int(record.k)
    if k < 1:
        raise StoreError(f"{store.lock.path}: run {rid} has k = {k}; a stored run has at least one capacitor")
    store.make_room(2 * record_bytes(record) + RUN_OVERHEAD_BYTES + INDEX_BYTES_PER_RUN * len(runs))
    with WriteGuard(store, f"run {rid}"):
        if temp in runs:
            del runs[temp]
        g = runs.create_group(temp)
        g.attrs.update(values)
        for stage, outlines in (("initial", record.initial_outlines), ("final", record.final_outlines)):
            points, offsets = _ragged(outlines)
            g.create_dataset(f"{stage}_outline_points_mm", data=points)
            g.create_dataset(f"{stage}_outline_offsets", data=offsets)
        g.create_dataset("poses", data=np.array(record.poses, dtype=object), dtype=_STR)
        for name in ("initial_capacitance_pF", "final_capacitance_pF", "finer_capacitance_pF"):
            g.create_dataset(name, data=np.asarray(getattr(record, name), dtype=float).reshape(-1, k))
        h = g.create_group("history")
        required = [n for n in HISTORY_COLUMNS if n not in OPTIONAL_HISTORY]
        for name in dict.fromkeys([*required, *record.history]):
            column, kind = record.history.get(name, []), history_kind(name)
            if kind == "str":
                h.create_dataset(name, data=np.array([str(x) for x in column], dtype=object), dtype=_STR)
            else:
                h.create_dataset(name, data=np.asarray(column, dtype=kind))
        if rid in runs:
            del runs[rid]
        runs.move(temp, rid)
        store.commit()
    return rid


def read_run(store: h5py.File, rid: str) -> RunRecord:
    """The stored run ``rid`` as a ``RunRecord``."""
    runs = store["runs"]
    if rid not in runs or rid.startswith(TEMP_PREFIX):
        known = sorted(finished_ids(store))
        hint = ", ".join(known[:8]) + (", ..." if len(known) > 8 else "")
        raise StoreError(f"{store.filename}: no run {rid!r} (runs: {hint or 'none'})")
    problem = run_problem(store, rid, deep=True)  # types and declared sizes before a byte is read
    if problem is not None:
        raise StoreError(f"{store.filename}: run {rid} is damaged: {problem}")
    try:
        return _read_run(runs[rid])
    except (KeyError, OSError, RuntimeError, ValueError, TypeError) as exc:
        raise StoreError(f"{store.filename}: run {rid} is damaged: {one_line(exc)}") from None


def _read_run(g: h5py.Group) -> RunRecord:
    a = g.attrs
    rows = g["history"]["iteration"].shape[0]
    stored = g["history"]
    terms = stored_terms(n for n in stored if n.isidentifier())
    history = {name: (stored[name].asstr()[()].astype(object) if history_kind(name) == "str"
                      else stored[name][()] if name in stored else np.full(rows, np.nan))
               for name in history_fields(terms or DEFAULT_TERMS)}  # OPTIONAL_HISTORY: NaN if absent
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
                     cpu_s=float(a.get("cpu_s", math.nan)),
                     error_estimate_cpu_s=float(a.get("error_estimate_cpu_s", math.nan)),
                     peak_rss_mb=float(a.get("peak_rss_mb", math.nan)),
                     bound_mm=float(a.get("bound_mm", math.nan)),
                     initial_bound_mm=float(a.get("initial_bound_mm", math.nan)),
                     finer_bound_mm=float(a.get("finer_bound_mm", math.nan)))


def run_summaries(store: h5py.File) -> list[RunSummary]:
    """The attributes selection needs, for every finished run (no datasets read)."""
    out = []
    for rid in sorted(finished_ids(store)):
        a = store["runs"][rid].attrs
        out.append(RunSummary(id=rid, k=int(a["k"]), ok=a["status"] != "failed", metric=float(a["metric_pF"]),
                              wall_s=float(a["wall_s"]), bound_mm=float(a.get("bound_mm", math.nan)),
                              pruned=a["status"] == "pruned",
                              finer_metric=float(a.get("finer_metric_pF", math.nan)),
                              finer_bound_mm=float(a.get("finer_bound_mm", math.nan))))
    return out


def scene_settings(store: h5py.File) -> MultistartSettings:
    """The ``[multistart]`` settings of the stored scene text (defaults filled in)."""
    return read_multistart(tomllib.loads(store.attrs["scene_toml"]).get("multistart", {}),
                           f"{store.filename} (stored scene)")


def store_selection(store: h5py.File) -> Selection:
    """Selection over the store's finished runs, with the stored scene's k range and
    ``plateau_tol`` (what ``write_selection`` should be given after each run), made on
    the calibrated designs of ``/calibration`` when the file has them."""
    ms = scene_settings(store)
    return select(run_summaries(store), ms.plateau_tol, range(ms.k_min, ms.k_max + 1), read_calibration(store))


def write_calibration(store: ResultsFile, designs, attrs: dict) -> None:
    """Replace ``/calibration`` with the calibrated ``designs``
    (:class:`~mscap.service.selection.CalibratedDesign`) and ``attrs`` (the rest of
    :data:`CALIBRATION_ITEMS`), flushed and ``fsync``-ed; built under a temporary name."""
    designs = list(designs)
    store.make_room(SELECTION_BYTES + 256 * len(designs))
    with WriteGuard(store, "/calibration"):
        temp = TEMP_PREFIX + "calibration"
        if temp in store:
            del store[temp]
        g = store.create_group(temp)
        g.create_dataset("label", data=np.array([d.label for d in designs], dtype=object), dtype=_STR)
        g.create_dataset("k", data=np.array([d.k for d in designs], dtype=np.int64))
        for name in ("error_mm", "spread_mm", "bound_mm"):
            g.create_dataset(name, data=np.array([getattr(d, name) for d in designs], dtype=float))
        g.attrs.update(attrs)
        assert set(g) | set(g.attrs) == set(CALIBRATION_ITEMS)
        if "calibration" in store:
            del store["calibration"]
        store.move(temp, "calibration")
        store.commit()


def read_calibration(store: h5py.File) -> tuple[CalibratedDesign, ...]:
    """The calibrated designs of ``/calibration`` (empty without one, or with a damaged
    one: the selection then stays the objective's, and says so)."""
    if "calibration" not in store:
        return ()
    try:
        g = store["calibration"]
        if not isinstance(g, h5py.Group):
            raise ValueError("it is not a group")
        kinds = {"label": "str", "k": "iu", "error_mm": "f", "spread_mm": "f", "bound_mm": "f"}
        problem = next(filter(None, (dataset_problem(g[name] if name in g else None, name, kind, 1)
                                     for name, kind in kinds.items())), None)
        if problem:  # from declarations, before a byte is read
            raise ValueError(problem)
        labels = g["label"].asstr()[()]
        columns = [g[name][()] for name in ("k", "error_mm", "spread_mm", "bound_mm")]
        return tuple(CalibratedDesign(str(label), int(k), float(e), float(s), float(b))
                     for label, k, e, s, b in zip(labels, *columns, strict=True))
    except (KeyError, OSError, RuntimeError, ValueError, TypeError) as exc:
        log.warning("%s: /calibration is unreadable (%s); choosing by the objective", store.filename, one_line(exc))
        return ()


def drop_calibration(store: ResultsFile) -> None:
    """Delete ``/calibration`` (a new run makes it stale: the session's end calibrates again)."""
    if "calibration" in store:
        with WriteGuard(store, "/calibration"):
            del store["calibration"]
            store.commit()


#: Room reserved for ``/selection`` beyond 128 bytes per k (measured: at most 4 KiB with 3 k values).
SELECTION_BYTES = 32 * 1024


def write_selection(store: ResultsFile, selection: Selection) -> None:
    """Replace ``/selection`` with ``selection``, flush and ``fsync`` (built under a
    temporary name, room reserved first as for a run)."""
    per_k = selection.per_k
    store.make_room(SELECTION_BYTES + 128 * len(per_k))
    with WriteGuard(store, "/selection"):
        _write_selection(store, selection)


def _write_selection(store: ResultsFile, selection: Selection) -> None:
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
    g.create_dataset("best_design", data=np.array([s.best_design or "" for s in per_k], dtype=object), dtype=_STR)
    g.create_dataset("best_error_mm", data=np.array([math.nan if s.best_error_mm is None else s.best_error_mm
                                                     for s in per_k], dtype=float))
    g.attrs.update({"chosen_k": -1 if selection.chosen_k is None else int(selection.chosen_k),
                    "chosen_design": selection.chosen_design or "",
                    "objective_chosen_k": -1 if selection.objective_k is None else int(selection.objective_k),
                    "chosen_run": selection.chosen_run or "", "plateau_tol": float(selection.plateau_tol),
                    "plateau_reached": int(selection.plateau_reached), "runs_total": int(selection.runs_total),
                    "rule": SELECTION_RULE_CALIBRATED if selection.by_calibration else
                    SELECTION_RULE_BOUND if selection.by_bound else SELECTION_RULE,
                    "finer_chosen_k": -1 if selection.finer_chosen_k is None else int(selection.finer_chosen_k),
                    "resolution": selection.verdict()})
    assert set(g) | set(g.attrs) == set(SELECTION_ITEMS)
    if "selection" in store:
        del store["selection"]
    store.move(temp, "selection")
    store.commit()
