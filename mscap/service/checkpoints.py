"""In-start checkpoints of a multi-start (issue 49 item 1): a busy start's optimiser state is
stored while it runs and when the job stops, and a rerun of the same command continues it.

Before, a start still running when the job stopped (a time limit, ``scancel``, a
preemption) was dropped and ran again from its beginning: two jobs of ``jobs/quick.toml``
with 4 and 6 minute limits each stored 0 of 12 runs, and a resubmission would again.

- **The worker** keeps its start's state at the top of every optimiser iteration
  (:class:`~mscap.design.state.OptimizerState`: the layout and control counts the design
  was last built from and the refinements since, ``q``, the equilibria, the L-BFGS memory,
  the history) and sends it to the master every ``[multistart] checkpoint_minutes``
  (:class:`Checkpoint`, a question the master answers at once). When the job stops, its
  next question is answered "abandon": it returns its last state (:class:`Interrupted`)
  instead of dropping the start; at most one step is lost.
- **The master** writes each state to ``<results>.checkpoints/<run id>.h5`` (written
  under a temporary name and renamed: a file there is always whole) and deletes it when
  the run is stored. A rerun hands each start with a checkpoint its state, and the worker
  rebuilds the design (:func:`~mscap.design.optimizer.resumed_design`) and goes on
  (:func:`~mscap.design.optimizer.optimize` with ``resume``): the same steps, J to 1e-7
  (tests/design/test_state.py). A checkpoint that cannot be read is said in one line and
  deleted, and its start runs from its beginning; so does one whose resume fails.
- ``mscap run --force`` deletes the directory with the file's runs.

The results file itself is unchanged (no schema change); ``mscap merge`` ignores the
checkpoints, ``mscap inspect`` lists them (:func:`kept_text`). With ``[fabrication] route_during_optimisation`` no state is kept
(the route is not part of it).
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import h5py

from mscap.design.state import STATE_FORMAT, OptimizerState, read_state, write_state
from mscap.outputs import replace_file

__all__ = ["Checkpoint", "Interrupted", "directory", "save", "load", "drop", "drop_all", "stored", "kept",
           "kept_text"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Checkpoint:
    """A worker's question to the master: store start ``id``'s ``state``."""

    id: str
    state: OptimizerState


@dataclass(frozen=True, eq=False)
class Interrupted:
    """What a worker returns for a start the stopping job abandoned: its last ``state``."""

    id: str
    state: OptimizerState


def directory(results) -> Path:
    """The checkpoints of results file ``results``: ``<results>.checkpoints/``."""
    return Path(f"{results}.checkpoints")


def _file(results, run_id: str) -> Path:
    return directory(results) / f"{run_id}.h5"


def save(results, run_id: str, state: OptimizerState) -> Path:
    """Write ``state`` as start ``run_id``'s checkpoint (replacing the last one whole)."""
    folder = directory(results)
    if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
        raise OSError(f"{folder} is not a directory mscap made")
    folder.mkdir(exist_ok=True)

    def write(temporary: Path) -> None:
        with h5py.File(temporary, "w") as f:
            write_state(f.create_group("state"), state)

    return replace_file(_file(results, run_id), write)


def load(results, run_id: str) -> OptimizerState | None:
    """Start ``run_id``'s stored state, ``None`` if there is none; a file that is not a
    whole state raises ``ValueError`` naming it."""
    path = _file(results, run_id)
    if not path.is_file() or path.is_symlink():
        return None
    try:
        with h5py.File(path, "r") as f:
            group = f["state"]
            if group.attrs.get("format") != STATE_FORMAT:
                raise ValueError(f"format {group.attrs.get('format')!r}, not {STATE_FORMAT!r}")
            return read_state(group)
    except Exception as exc:  # noqa: BLE001 — any damage: the start runs from its beginning
        raise ValueError(f"{path}: not a readable optimiser state ({type(exc).__name__}: {str(exc)[:200]})") from None


def stored(results) -> list[str]:
    """The run ids with a checkpoint file."""
    folder = directory(results)
    if not folder.is_dir() or folder.is_symlink():
        return []
    return sorted(p.stem for p in folder.glob("*.h5") if p.is_file())


def kept(results) -> list[tuple[str, int | None]]:
    """Each stored start's id and the step its state is at (``None``: unreadable), read
    from the files' attributes alone (``mscap inspect``)."""
    out = []
    for run_id in stored(results):
        try:
            with h5py.File(_file(results, run_id), "r") as f:
                out.append((run_id, int(f["state"].attrs["iteration"])))
        except Exception:  # noqa: BLE001 — said as unreadable; the rerun deletes it
            out.append((run_id, None))
    return out


def kept_text(results) -> str:
    """One line on the starts a stopped job kept mid-way, ``""`` when none."""
    starts = kept(results)
    if not starts:
        return ""
    return (f"kept mid-way in {directory(results)} (a rerun of the same command continues them): "
            + ", ".join(f"{rid} (step {step})" if step is not None else f"{rid} (unreadable: runs afresh)"
                        for rid, step in starts))


def drop(results, run_id: str) -> None:
    """Delete start ``run_id``'s checkpoint (its run is stored), and the directory once empty."""
    path = _file(results, run_id)
    if path.is_file():
        path.unlink()
    folder = directory(results)
    try:
        folder.rmdir()
    except OSError:
        pass


def drop_all(results) -> None:
    """Delete every checkpoint of ``results`` (``--force``: the file starts over)."""
    folder = directory(results)
    if folder.is_dir() and not folder.is_symlink():
        shutil.rmtree(folder, ignore_errors=True)
    elif folder.is_symlink():
        os.unlink(folder)
