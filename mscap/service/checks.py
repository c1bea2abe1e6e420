"""Checks of a results file before anything reads or resumes it: root attributes, schema
version, the stored scene text, every run's attributes and datasets (docs/hdf5.md). A
damaged record becomes a :class:`~mscap.errors.StoreError` naming the file and the record
(readers) or is dropped and run again (the resume, :func:`mscap.service.store.open_store`)."""

from __future__ import annotations

import re
import tomllib

import h5py
import numpy as np

from mscap.errors import StoreError
from mscap.infile import dataset_problem, one_line
from mscap.scene.settings import MAX_CAPACITORS, MAX_SCENE_BYTES
from mscap.service.schema import (HISTORY_COLUMNS, OPTIONAL_HISTORY, RUN_ATTRS, RUN_DATASETS, SCHEMA_VERSION,
                                  TEMP_PREFIX)

__all__ = ["REQUIRED_RUN_ATTRS", "REQUIRED_ROOT_ATTRS", "MAX_TEXT", "RUN_NAME", "text_attr", "int_attr", "float_attr",
           "run_problem", "damaged_runs", "check_store"]


#: Run attributes every schema has; the others read as NaN when absent (schema 1).
REQUIRED_RUN_ATTRS = ("k", "seed", "init", "status", "error", "reason", "wall_s", "iterations", "rank", "metric_pF")
#: Root attributes the readers need.
REQUIRED_ROOT_ATTRS = ("format", "schema_version", "scene_name", "scene_toml", "scene_sha256")
_STATUSES = ("ok", "pruned", "failed")


#: What an honest file holds at most; a file that declares more is refused before it is
#: read. Texts: characters (the writer cuts a longer error or reason to fit). A dataset: its
#: declared bytes (:data:`mscap.infile.MAX_DATASET_BYTES`).
MAX_TEXT = {"format": 64, "mscap_version": 64, "scene_name": 1000, "scene_path": 4096,
            "scene_toml": MAX_SCENE_BYTES, "scene_sha256": 64, "start_time": 64, "last_open_time": 64,
            "init": 64, "status": 16, "error": 20_000, "reason": 20_000}
#: A run's group name: what :func:`mscap.service.selection.run_id` makes (``k3_s3007_lloyd``).
RUN_NAME = re.compile(r"k[0-9]{1,6}_s[0-9]{1,19}_[a-z]{1,32}")
_RUN_INTS = {"k": (1, MAX_CAPACITORS), "seed": (0, 2**63 - 1), "iterations": (0, 2**31), "rank": (0, 2**31)}


def _declared(type_text: str) -> tuple[str, int]:
    """``(dtype kinds, dimensions)`` of a ``RUN_DATASETS`` type, e.g. ``"float64 (n, 2)"`` →
    ``("f", 2)``, ``"int64 (k + 1,)"`` → ``("iu", 1)``, ``"str (n_poses,)"`` → ``("str", 1)``."""
    dtype, _, shape = type_text.partition(" ")
    kind = "str" if dtype == "str" else "iu" if np.dtype(dtype).kind in "iu" else np.dtype(dtype).kind
    return kind, shape.strip("()").rstrip(",").count(",") + 1


#: Run datasets: (dtype kinds, dimensions), from the schema's one declaration.
_RUN_SHAPES = {name: _declared(kind) for name, (kind, _) in RUN_DATASETS.items() if "/" not in name}


def text_attr(attrs, name: str) -> str:
    """Attribute ``name`` as text: a scalar string of at most :data:`MAX_TEXT` characters,
    else a ``ValueError`` saying what it is instead."""
    value = attrs[name]
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if not isinstance(value, str):
        raise ValueError(f"attribute {name!r} is {_what(value)}, not text")
    if len(value) > MAX_TEXT.get(name, 1000):
        raise ValueError(f"attribute {name!r} has {len(value)} characters; at most {MAX_TEXT.get(name, 1000)}")
    return value


def int_attr(attrs, name: str, lo: int, hi: int) -> int:
    """Attribute ``name`` as an integer scalar in ``[lo, hi]``, else a ``ValueError``."""
    value = attrs[name]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"attribute {name!r} is {_what(value)}, not an integer")
    if not lo <= int(value) <= hi:
        raise ValueError(f"attribute {name!r} is {int(value)}, outside [{lo}, {hi}]")
    return int(value)


def float_attr(attrs, name: str) -> float:
    """Attribute ``name`` as a real scalar (NaN allowed), else a ``ValueError``."""
    value = attrs[name]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"attribute {name!r} is {_what(value)}, not a number")
    return float(value)


def _what(value) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    return f"{type(value).__name__} {str(value)[:40]!r}"


def run_problem(store: h5py.File, rid: str, deep: bool = True) -> str | None:
    """What is wrong with the stored run ``rid``, or ``None``.

    Shallow (every reader, about 2 ms a run): its name, a missing attribute or dataset,
    an attribute of the wrong type or range (every attribute of ``RUN_ATTRS`` present is
    checked against its declared type). ``deep`` (:func:`mscap.service.store.read_run`
    before it reads a run, the resume, ``mscap merge``; about 10 ms a run): also a dataset
    of the wrong type, rank or declared size (from its declaration, before a byte is read),
    outline offsets that do not cut the points, capacitance tables that do not fit its k
    and poses, history columns of different lengths."""
    try:
        if not RUN_NAME.fullmatch(rid):
            return f"its name {rid[:60]!r} is not a run id (k<k>_s<seed>_<init>)"
        g = store["runs"][rid]
        if not isinstance(g, h5py.Group):
            return f"it is a {type(g).__name__.lower()}, not a group"
        a = g.attrs
        missing = [n for n in REQUIRED_RUN_ATTRS if n not in a]
        if missing:
            return f"no attribute {missing[0]!r}"
        for name, (kind, _) in RUN_ATTRS.items():
            if name not in a:
                continue
            if kind == "int":
                int_attr(a, name, *_RUN_INTS.get(name, (-2**63, 2**63 - 1)))
            elif kind == "float":
                float_attr(a, name)
            else:
                text_attr(a, name)
        k, status = int(a["k"]), str(a["status"])
        if status not in _STATUSES:
            return f"status {status!r} (not one of {', '.join(_STATUSES)})"
        names = set(g)
        history = g["history"] if "history" in names else None
        if history is not None and not isinstance(history, h5py.Group):
            return "'history' is not a group"
        missing = [n for n in RUN_DATASETS if "/" not in n and n != "finer_capacitance_pF" and n not in names] \
            or [f"history/{n}" for n in HISTORY_COLUMNS
                if n not in OPTIONAL_HISTORY and (history is None or n not in history)]
        # finer_capacitance_pF: schema 2; OPTIONAL_HISTORY: files written before it
        if missing:
            return f"no dataset {missing[0]!r}"
        if not deep:
            return None
        for name, (kind, ndim) in _RUN_SHAPES.items():
            problem = dataset_problem(g[name], name, kind, ndim) if name in names else None
            if problem:
                return problem
        return _history_problem(history) or _shape_problem(g, k, status)
    except ValueError as exc:
        return one_line(exc)
    except (KeyError, OSError, RuntimeError, TypeError, AttributeError) as exc:
        return f"unreadable ({one_line(exc)})"


def _history_problem(history: h5py.Group) -> str | None:
    lengths = set()
    for name in history:
        if not name.isidentifier() or len(name) > 64:
            return f"history column {name[:60]!r} is not a column name"
        problem = dataset_problem(history[name], f"history/{name}", "str" if name == "event" else "biuf", 1)
        if problem:
            return problem
        lengths.add(history[name].shape[0])
    if len(lengths) > 1:
        return f"history columns of different lengths {sorted(lengths)}"
    return None


def _shape_problem(g: h5py.Group, k: int, status: str) -> str | None:
    for stage in ("initial", "final"):
        points, offsets = g[f"{stage}_outline_points_mm"], g[f"{stage}_outline_offsets"]
        if points.shape[1] != 2:
            return f"{stage} outline points have shape {points.shape}, not (n, 2)"
        if offsets.shape[0] not in (1, k + 1):
            return f"{stage} outline offsets has {offsets.shape[0]} entries, not k + 1 = {k + 1}"
        cuts = offsets[()]
        if cuts[0] != 0 or cuts[-1] != points.shape[0] or (np.diff(cuts) < 0).any():
            return (f"{stage} outline offsets {np.array2string(cuts[:8], threshold=8)} do not cut its "
                    f"{points.shape[0]} points (from 0, not decreasing, to the end)")
    for name in ("initial_capacitance_pF", "final_capacitance_pF", "finer_capacitance_pF"):
        if name in g and g[name].shape[1] != k:
            return f"dataset {name!r} has shape {g[name].shape}, not (n_poses, {k})"
    if status != "failed" and g["final_capacitance_pF"].shape[0] != g["poses"].shape[0]:
        return f"{g['final_capacitance_pF'].shape[0]} rows of final_capacitance_pF for {g['poses'].shape[0]} poses"
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
        for name in ("format", "scene_name", "scene_toml", "scene_sha256") + tuple(
                n for n in ("scene_path", "mscap_version", "start_time", "last_open_time") if n in store.attrs):
            text_attr(store.attrs, name)
        for name in (n for n in ("mpi_size", "sessions") if n in store.attrs):
            int_attr(store.attrs, name, 0, 2**31)
        version = int_attr(store.attrs, "schema_version", 1, 2**31)
        if version > SCHEMA_VERSION:
            raise StoreError(f"{path} has schema_version {version}, newer than this mscap's "
                             f"{SCHEMA_VERSION}: update mscap to read it")
        try:
            tomllib.loads(str(store.attrs["scene_toml"]))
        except tomllib.TOMLDecodeError as exc:
            raise StoreError(f"{path}: damaged: the stored scene (attribute scene_toml) is not TOML ({exc})") from None
        if not isinstance(store.get("runs"), h5py.Group):
            raise StoreError(f"{path}: damaged: no group 'runs'"
                             + ("" if "runs" not in store else " ('runs' is a dataset)"))
        damaged = damaged_runs(store, deep)
    except ValueError as exc:
        raise StoreError(f"{path}: damaged: {one_line(exc)}") from None
    except (OSError, RuntimeError, KeyError, TypeError) as exc:
        raise StoreError(f"{path}: damaged, unreadable ({one_line(exc)})") from None
    if damaged:
        rid, problem = next(iter(damaged.items()))
        more = f" (and {len(damaged) - 1} more damaged runs)" if len(damaged) > 1 else ""
        shown = rid if RUN_NAME.fullmatch(rid) else repr(rid[:60])  # a name from the file: one line, escaped
        raise StoreError(f"{path}: run {shown} is damaged: {problem}{more}; `mscap run` on this file drops and "
                         "reruns damaged runs")
