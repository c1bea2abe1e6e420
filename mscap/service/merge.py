"""Join results files of the same scene (e.g. the tasks of a SLURM job array) into one
and recompute the selection (``mscap merge``).

Every input is checked before anything is written (:func:`mscap.service.store.check_store`):
a damaged run stops the merge with the file and the run named. The output is written in
the current schema; runs of an older schema are converted explicitly (schema 1 → 2: the
finer-mesh check's items added as "not checked", NaN and 0 rows), never relabelled.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import h5py
import numpy as np

from mscap.service.store import (RUN_ATTRS, SCHEMA_VERSION, StoreError, WriteGuard, create_store, finished_ids,
                                 check_store, read_store, store_selection, write_selection)

__all__ = ["merge", "upgrade_run"]

log = logging.getLogger(__name__)


#: Which copy of a run stored in several files the merge keeps: the highest.
_PREFERENCE = {"ok": 2, "pruned": 1, "failed": 0}


def upgrade_run(g: h5py.Group, version: int) -> None:
    """Bring a copied run group of schema ``version`` to the current schema, in place:
    schema 1 had no finer-mesh check (and no read-back bound), so the check reads as not
    done (``finer_capacitance_pF`` with 0 rows, its attributes NaN)."""
    if version == SCHEMA_VERSION:
        return
    if version != 1:
        raise StoreError(f"no conversion from schema {version} to {SCHEMA_VERSION}")
    if "finer_capacitance_pF" not in g:
        g.create_dataset("finer_capacitance_pF", data=np.zeros((0, int(g.attrs["k"]))))
    for name, (kind, _) in RUN_ATTRS.items():
        if name not in g.attrs and kind == "float":
            g.attrs[name] = math.nan


def merge(inputs, output, force: bool = False) -> int:
    """Merge ``inputs`` into ``output``; returns the number of runs written.

    A run present in several inputs is taken from the first input where it succeeded
    (else the first where it appears). On any failure the partly written output is
    deleted.

    Raises
    ------
    StoreError
        The inputs hold different scenes or a damaged run, the output is one of the
        inputs, a link, held by another process, or exists (without ``force``).
    """
    output = Path(output)
    if any(Path(i).resolve() == output.resolve() for i in inputs):
        raise StoreError(f"{output}: the output must not be one of the inputs")
    if output.exists() and not output.is_symlink() and not force:
        raise StoreError(f"{output} exists; use --force to overwrite it")
    files = []
    try:
        for path in inputs:
            files.append(read_store(path))
            check_store(files[-1], path, deep=True)  # every dataset: the copy must read back
        first = files[0]
        for path, f in zip(inputs[1:], files[1:]):
            if f.attrs["scene_sha256"] != first.attrs["scene_sha256"]:
                raise StoreError(f"cannot merge results of different scenes: {inputs[0]} has scene "
                                 f"{first.attrs.get('scene_path', '?')} (sha256 {first.attrs['scene_sha256']}), "
                                 f"{path} has {f.attrs.get('scene_path', '?')} (sha256 {f.attrs['scene_sha256']})")
        source = {}
        for f in files:
            for rid in sorted(finished_ids(f)):  # a complete run over a pruned one over a failed one
                rank = _PREFERENCE.get(str(f["runs"][rid].attrs["status"]), 0)
                if rid not in source or rank > source[rid][1]:
                    source[rid] = (f, rank)
        a = first.attrs
        out = create_store(output, str(a["scene_toml"]), str(a["scene_sha256"]), str(a["scene_name"]),
                           str(a.get("scene_path", "")), max(int(f.attrs.get("mpi_size", 1)) for f in files),
                           force=force)
        try:
            converted = _copy_runs(out, source)
            out.attrs["start_time"] = min(str(f.attrs.get("start_time", "")) for f in files)
            write_selection(out, store_selection(out))
        except BaseException:
            out.discard()
            raise
        out.close()
    finally:
        for f in files:
            f.close()
    if converted:
        log.warning("%s: %d runs of schema 1 converted to schema %d (no finer-mesh check: NaN)", output, converted,
                    SCHEMA_VERSION)
    log.info("%s: %d runs from %d files", output, len(source), len(inputs))
    return len(source)


def _copy_runs(out, source: dict) -> int:
    """Copy each run of ``source`` (``{id: (file, preference)}``) into ``out``, room
    reserved first; returns how many were converted from an older schema."""
    converted = 0
    for rid, (f, _) in sorted(source.items()):
        g = f["runs"][rid]
        out.make_room(2 * _stored_bytes(g) + 64 * 1024)
        version = int(f.attrs["schema_version"])
        with WriteGuard(out, f"run {rid} (from {f.filename})"):
            f.copy(g, out["runs"], name=rid)
            upgrade_run(out["runs"][rid], version)
        converted += version != SCHEMA_VERSION
    with WriteGuard(out, "the runs"):
        out.commit()
    return converted


def _stored_bytes(g: h5py.Group) -> int:
    """Bytes of the datasets under ``g`` as stored."""
    sizes = []
    g.visititems(lambda name, item: sizes.append(item.id.get_storage_size()) if isinstance(item, h5py.Dataset)
                 else None)
    return sum(sizes)
