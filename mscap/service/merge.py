"""Join results files of the same scene (e.g. the tasks of a SLURM job array) into one
and recompute the selection (``mscap merge``)."""

from __future__ import annotations

import logging
from pathlib import Path

from mscap.service.store import StoreError, create_store, finished_ids, read_store, store_selection, write_selection

__all__ = ["merge"]

log = logging.getLogger(__name__)


#: Which copy of a run stored in several files the merge keeps: the highest.
_PREFERENCE = {"ok": 2, "pruned": 1, "failed": 0}

def merge(inputs, output, force: bool = False) -> int:
    """Merge ``inputs`` into ``output``; returns the number of runs written.

    A run present in several inputs is taken from the first input where it succeeded
    (else the first where it appears).

    Raises
    ------
    StoreError
        The inputs hold different scenes, the output is one of the inputs, or it exists
        (without ``force``).
    """
    output = Path(output)
    if any(Path(i).resolve() == output.resolve() for i in inputs):
        raise StoreError(f"{output}: the output must not be one of the inputs")
    if output.exists() and not force:
        raise StoreError(f"{output} exists; use --force to overwrite it")
    files = [read_store(p) for p in inputs]
    try:
        first = files[0]
        for path, f in zip(inputs[1:], files[1:]):
            if f.attrs["scene_sha256"] != first.attrs["scene_sha256"]:
                raise StoreError(f"cannot merge results of different scenes: {inputs[0]} has scene "
                                 f"{first.attrs['scene_path']} (sha256 {first.attrs['scene_sha256']}), "
                                 f"{path} has {f.attrs['scene_path']} (sha256 {f.attrs['scene_sha256']})")
        source = {}
        for f in files:
            for rid in sorted(finished_ids(f)):  # a complete run over a pruned one over a failed one
                rank = _PREFERENCE.get(str(f["runs"][rid].attrs["status"]), 0)
                if rid not in source or rank > source[rid][1]:
                    source[rid] = (f, rank)
        a = first.attrs
        with create_store(output, a["scene_toml"], a["scene_sha256"], a["scene_name"], a["scene_path"],
                          max(int(f.attrs["mpi_size"]) for f in files)) as out:
            out.attrs["start_time"] = min(str(f.attrs["start_time"]) for f in files)
            for rid, (f, _) in sorted(source.items()):
                f.copy(f["runs"][rid], out["runs"], name=rid)
            out.flush()
            write_selection(out, store_selection(out))
        log.info("%s: %d runs from %d files", output, len(source), len(inputs))
        return len(source)
    finally:
        for f in files:
            f.close()
