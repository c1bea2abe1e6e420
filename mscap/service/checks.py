"""Checks of a results file before anything reads or resumes it: root attributes, schema
version, the stored scene text, every run's attributes and datasets (docs/hdf5.md). A
damaged record becomes a :class:`~mscap.errors.StoreError` naming the file and the record
(readers) or is dropped and run again (the resume, :func:`mscap.service.store.open_store`)."""

from __future__ import annotations

import tomllib

import h5py

from mscap.errors import StoreError
from mscap.service.schema import HISTORY_COLUMNS, OPTIONAL_HISTORY, RUN_DATASETS, SCHEMA_VERSION, TEMP_PREFIX

__all__ = ["REQUIRED_RUN_ATTRS", "REQUIRED_ROOT_ATTRS", "one_line", "run_problem", "damaged_runs", "check_store"]


def one_line(exc: BaseException) -> str:
    """An h5py/HDF5 error as one line (HDF5's messages span several)."""
    return " ".join(str(exc).split()) or type(exc).__name__


#: Run attributes every schema has; the others read as NaN when absent (schema 1).
REQUIRED_RUN_ATTRS = ("k", "seed", "init", "status", "error", "reason", "wall_s", "iterations", "rank", "metric_pF")
#: Root attributes the readers need.
REQUIRED_ROOT_ATTRS = ("format", "schema_version", "scene_name", "scene_toml", "scene_sha256")
_STATUSES = ("ok", "pruned", "failed")


def run_problem(store: h5py.File, rid: str, deep: bool = True) -> str | None:
    """What is wrong with the stored run ``rid`` (a missing attribute or dataset, an
    unreadable group; with ``deep``, also a shape that does not fit its k), or ``None``.

    The shallow check reads names and two attributes (about 1 ms a run), what ``mscap
    inspect`` and ``plot`` afford on every file; the deep one opens every dataset (the
    resume, ``mscap merge``)."""
    try:
        g = store["runs"][rid]
        a = g.attrs
        missing = [n for n in REQUIRED_RUN_ATTRS if n not in a]
        if missing:
            return f"no attribute {missing[0]!r}"
        k, status = int(a["k"]), str(a["status"])
        if k < 1:
            return f"k = {k}"
        if status not in _STATUSES:
            return f"status {status!r} (not one of {', '.join(_STATUSES)})"
        names = set(g)
        history = set(g["history"]) if "history" in names else set()
        missing = [n for n in RUN_DATASETS if "/" not in n and n != "finer_capacitance_pF" and n not in names] \
            or [f"history/{n}" for n in HISTORY_COLUMNS if n not in history and n not in OPTIONAL_HISTORY]
        # finer_capacitance_pF: schema 2; OPTIONAL_HISTORY: files written before it
        if missing:
            return f"no dataset {missing[0]!r}"
        if deep:
            return _shape_problem(g, k, status)
    except (KeyError, OSError, RuntimeError, ValueError, TypeError) as exc:
        return f"unreadable ({one_line(exc)})"
    return None


def _shape_problem(g: h5py.Group, k: int, status: str) -> str | None:
    float(g.attrs["metric_pF"]), float(g.attrs["wall_s"])
    for stage in ("initial", "final"):
        points, offsets = g[f"{stage}_outline_points_mm"], g[f"{stage}_outline_offsets"][()]
        if points.ndim != 2 or points.shape[1] != 2 or offsets.ndim != 1 or len(offsets) == 0 \
                or offsets[-1] != points.shape[0]:
            return f"{stage} outlines: points {points.shape} do not match offsets {offsets.shape}"
    for name in ("initial_capacitance_pF", "final_capacitance_pF", "finer_capacitance_pF"):
        if name in g and (g[name].ndim != 2 or g[name].shape[1] != k):
            return f"dataset {name!r} has shape {g[name].shape}, not (n_poses, {k})"
    if status != "failed" and g["final_capacitance_pF"].shape[0] != g["poses"].shape[0]:
        return f"{g['final_capacitance_pF'].shape[0]} rows of final_capacitance_pF for {g['poses'].shape[0]} poses"
    lengths = {g["history"][n].shape for n in g["history"]}
    if len(lengths) > 1 or any(len(shape) != 1 for shape in lengths):
        return f"history columns of different shapes {sorted(lengths)}"
    return None


def damaged_runs(store: h5py.File, deep: bool = True) -> dict[str, str]:
    """``{run id: problem}`` of the stored runs that do not read back whole (:func:`run_problem`)."""
    ids = sorted(n for n in store["runs"] if not n.startswith(TEMP_PREFIX))
    problems = {rid: run_problem(store, rid, deep) for rid in ids}
    return {rid: problem for rid, problem in problems.items() if problem is not None}


def check_store(store: h5py.File, path=None, deep: bool = False) -> None:
    """Check an open results file before anything reads it: its root attributes, its
    schema version, its stored scene text and every run (:func:`run_problem`, ``deep``
    or not).

    Raises
    ------
    StoreError
        Naming the file and the first damaged record.
    """
    path = path or store.filename
    try:
        missing = [n for n in REQUIRED_ROOT_ATTRS if n not in store.attrs]
        if missing:
            raise StoreError(f"{path}: damaged: no root attribute {missing[0]!r}")
        version = int(store.attrs["schema_version"])
        if version > SCHEMA_VERSION:
            raise StoreError(f"{path} has schema_version {version}, newer than this mscap's "
                             f"{SCHEMA_VERSION}: update mscap to read it")
        try:
            tomllib.loads(str(store.attrs["scene_toml"]))
        except tomllib.TOMLDecodeError as exc:
            raise StoreError(f"{path}: damaged: the stored scene (attribute scene_toml) is not TOML ({exc})") from None
        if "runs" not in store:
            raise StoreError(f"{path}: damaged: no group 'runs'")
        damaged = damaged_runs(store, deep)
    except (OSError, RuntimeError, KeyError, ValueError) as exc:
        raise StoreError(f"{path}: damaged, unreadable ({one_line(exc)})") from None
    if damaged:
        rid, problem = next(iter(damaged.items()))
        more = f" (and {len(damaged) - 1} more damaged runs)" if len(damaged) > 1 else ""
        raise StoreError(f"{path}: run {rid} is damaged: {problem}{more}; `mscap run` on this file drops and "
                         "reruns damaged runs")
