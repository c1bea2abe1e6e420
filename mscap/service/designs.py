"""Stored designs: the layouts later stages (calibration, read-out) take from a results
file (``FILE.h5[:RUN]``) or from an ``mscap optimize`` output directory.

This module owns the output directory of one ``mscap optimize`` start
(:data:`OPTIMIZE_FILES`): :func:`write_optimize_output` writes it and
:func:`read_optimize_output` reads it back.

- ``outlines.json``: ``scene``, ``min_gap_mm``, ``outlines_mm`` (the final layout, mm);
- ``capacitance.csv``: ``pose, stage, C0_pF, ...``, the initial and final capacitances;
- ``history.csv``: one row per optimiser event (``mscap.design.optimizer.HISTORY_FIELDS``);
- ``summary.json``: ``k``, ``seed``, ``init``, iterations, metrics, per-pose capacitances (and,
  routed during the optimisation, each re-route).
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np

from mscap.design.history import HISTORY_FIELDS
from mscap.outputs import split_design_spec
from mscap.service.store import StoreError, read_run, read_store, store_selection

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["StoredDesign", "split_design_spec", "check_scene", "read_design", "load_design", "OPTIMIZE_FILES",
           "OptimizeOutput", "write_optimize_output", "read_optimize_output", "design_layouts", "MAX_JSON_BYTES"]

log = logging.getLogger(__name__)

#: The files of an ``mscap optimize`` output directory (``layout.png`` beside them is the figure).
OPTIMIZE_FILES = ("outlines.json", "capacitance.csv", "history.csv", "summary.json")


# ---------------------------------------------------------------- results files
@dataclass(frozen=True, eq=False)
class StoredDesign:
    """One layout taken from a results file, for calibration and readout.

    ``label`` says where it came from (``"k3_s1_lloyd"``, ``"k3_s1_lloyd:initial"``);
    ``capacitance_pF`` is ``(n_poses, k)`` over the scene's poses ``poses``.
    """

    label: str
    run_id: str
    which: str
    outlines: tuple[np.ndarray, ...]
    poses: tuple[str, ...]
    capacitance_pF: np.ndarray


def check_scene(store: h5py.File, scene: Scene) -> None:
    """A later stage (calibration, read-out) given ``scene`` for this file: the scene's
    name must match the stored one; a changed scene text (e.g. a ``[calibration]`` added
    after the runs) is only logged.

    Raises
    ------
    StoreError
        The file holds results of a scene of another name.
    """
    stored = str(store.attrs["scene_name"])
    if stored != scene.name:
        raise StoreError(f"{store.filename} holds results of scene {stored!r} ({store.attrs['scene_path']}), "
                         f"not of {scene.path} (scene {scene.name!r})")
    if store.attrs["scene_sha256"] != scene.sha256:
        log.warning("%s: scene %s changed since the results were written (sha256 differs)",
                    store.filename, scene.path)


def read_design(store: h5py.File, rid: str | None = None, which: str = "final") -> StoredDesign:
    """The ``which`` (``"final"`` or ``"initial"``) layout of run ``rid`` of an open
    results file; ``rid=None`` takes the run the selection chose, and with ``"final"`` the
    layout it chose (the run's initial one when calibration chose that,
    :mod:`mscap.service.calibrated`).

    Raises
    ------
    StoreError
        No such run, a failed run, or no chosen run in the file.
    """
    if which not in ("final", "initial"):
        raise ValueError(f"which must be 'final' or 'initial', got {which!r}")
    if rid is None:
        selection = store_selection(store)
        rid = selection.chosen_run
        which = selection.chosen_which if which == "final" else which
        if not rid:
            raise StoreError(f"{store.filename}: no successful run to choose a design from; "
                             "name one as FILE.h5:RUN")
    record = read_run(store, rid)
    if not record.ok:
        raise StoreError(f"{store.filename}: run {rid!r} failed ({record.error}); it has no design")
    outlines = record.final_outlines if which == "final" else record.initial_outlines
    capacitance = record.final_capacitance_pF if which == "final" else record.initial_capacitance_pF
    label = rid if which == "final" else f"{rid}:initial"
    return StoredDesign(label=label, run_id=rid, which=which, outlines=outlines, poses=record.poses,
                        capacitance_pF=np.array(capacitance, dtype=float))


def load_design(scene: Scene, spec: str, which: str = "final") -> StoredDesign:
    """:func:`read_design` of the results file named by ``spec`` (``FILE.h5[:RUN]``),
    after :func:`check_scene`."""
    path, rid = split_design_spec(spec)
    with read_store(path) as store:
        check_scene(store, scene)
        return read_design(store, rid, which)


# ---------------------------------------------------------------- `mscap optimize` directories
@dataclass(frozen=True, eq=False)
class OptimizeOutput:
    """What later stages read of an ``mscap optimize`` directory: its name, the final
    outlines (mm) and ``summary.json`` (``k``, ``seed``, ``init``, ...)."""

    name: str
    outlines: tuple[np.ndarray, ...]
    summary: dict


def write_optimize_output(directory, scene: Scene, initial, result, seed: int, init: str,
                          designed=None) -> dict:
    """Write :data:`OPTIMIZE_FILES` of one start (initial layout ``initial``, an
    ``OptimizeResult``) of ``scene`` to ``directory``; returns the summary. The tables' rows
    are the design poses ``designed`` (the design's ``designed``; default the scene's,
    :func:`mscap.design.readback.design_poses`).
    With a design family the summary holds the read-back bound before and after."""
    from mscap.design.readback import design_poses, read_back_estimate
    from mscap.outputs import output_directory, replace_csv, replace_text

    out = output_directory(directory, "optimize -o")
    final = result.layout
    designed = designed or design_poses(scene)
    bound = read_back_estimate(scene, designed)
    poses = list(designed.names)
    # Each file replaced, not written through: a link planted under its name is not followed.
    replace_text(out / "outlines.json", json.dumps(
        {"scene": scene.path, "min_gap_mm": scene.min_gap_mm,
         "outlines_mm": [np.round(o, 6).tolist() for o in final.outlines]}))
    replace_csv(out / "capacitance.csv",
                [["pose", "stage"] + [f"C{j}_pF" for j in range(final.k)]]
                + [[name, stage] + [f"{c:.6f}" for c in row]
                   for stage, e in (("initial", result.initial), ("final", result.evaluation))
                   for name, row in zip(poses, e.capacitance_pF)])
    fields = result.history[0].fields if result.history else HISTORY_FIELDS
    replace_csv(out / "history.csv", [list(fields)] + [r.row() for r in result.history])
    summary = {"scene": scene.path, "k": initial.k, "seed": seed, "init": init,
               "iterations": result.iterations, "reason": result.reason, "time_s": result.time_s,
               "initial_min_l1_pF": result.initial.min_l1_pF, "final_min_l1_pF": result.evaluation.min_l1_pF,
               "initial_J": result.initial.J, "final_J": result.evaluation.J,
               "remeshes": sum(r.event == "remesh" for r in result.history),
               "revivals": sum(r.event == "revive" for r in result.history),
               **({"reroutes": [asdict(r) for r in result.reroutes]} if result.reroutes else {}),
               **({} if bound is None else {"initial_bound_mm": bound.value(result.initial.capacitance_pF),
                                            "final_bound_mm": bound.value(result.evaluation.capacitance_pF)}),
               "poses": poses,
               "capacitance_pF": {name: row.tolist()
                                  for name, row in zip(poses, result.evaluation.capacitance_pF)},
               "initial_capacitance_pF": {name: row.tolist()
                                          for name, row in zip(poses, result.initial.capacitance_pF)}}
    replace_text(out / "summary.json", json.dumps(summary, indent=1))
    return summary


#: The most of an ``mscap optimize`` JSON file that is read (an honest outlines.json of 100
#: plates of 1,300 vertices is 5 MB).
MAX_JSON_BYTES = 64 * 2**20


def read_optimize_output(directory) -> OptimizeOutput:
    """The final outlines and the summary of an ``mscap optimize`` output directory.

    Raises
    ------
    StoreError
        ``outlines.json`` or ``summary.json`` is missing or unreadable.
    """
    from mscap.infile import read_regular

    directory = Path(directory)
    try:
        outlines = json.loads(read_regular(directory / "outlines.json", MAX_JSON_BYTES, "an outlines.json"))
        outlines = outlines["outlines_mm"]
        summary = json.loads(read_regular(directory / "summary.json", MAX_JSON_BYTES, "a summary.json"))
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise StoreError(f"{directory}: not an `mscap optimize` output directory "
                         f"(outlines.json, summary.json): {exc}") from None
    return OptimizeOutput(directory.name, tuple(np.array(o, dtype=float) for o in outlines), summary)


# ---------------------------------------------------------------- a design and its baselines
def _optimize_layouts(scene: Scene, directory: Path, baselines: list[str] | None) -> list[tuple[str, tuple]]:
    """The final layout of an ``mscap optimize`` output directory and its baselines:
    ``initial`` (rebuilt from the run's k, seed and init: initial layouts are functions
    of those alone) and ``scene``."""
    from mscap.design.starts import start_layout
    from mscap.geometry.layout import Layout

    run = read_optimize_output(directory)
    layouts = [(f"{run.name} (optimised)", run.outlines)]
    for b in ["initial"] if baselines is None else baselines:
        if b == "scene":
            layouts.append(("scene layout", scene.layout.outlines))
        elif b == "initial":
            init = run.summary["init"]
            layout = scene.layout if init == "scene" else start_layout(scene, int(run.summary["k"]),
                                                                          int(run.summary["seed"]), init)
            label = "scene layout" if init == "scene" else f"{run.name}:initial"
            layouts.append((label, Layout(layout.outlines).outlines))
        else:
            raise StoreError(f"--baseline {b!r}: an `mscap optimize` directory has only the "
                             "baselines 'initial' and 'scene'; run ids need a results file")
    return layouts


def design_layouts(scene: Scene, spec: str, baselines: list[str] | None) -> list[tuple[str, tuple[np.ndarray, ...]]]:
    """``(label, outlines)`` of the design named by ``spec`` (a results file, optionally
    ``:RUN``, or an ``mscap optimize`` output directory), then of each baseline:
    ``"initial"`` (the design's initial layout; the default), ``"scene"`` (the scene's
    own layout), a run id of the results file or ``RUN:initial``."""
    if Path(spec).is_dir():
        return _optimize_layouts(scene, Path(spec), baselines)
    path, rid = split_design_spec(spec)
    with read_store(path) as store:
        check_scene(store, scene)
        main = read_design(store, rid, "final")
        layouts = [(f"{main.label} ({'optimised' if main.which == 'final' else 'chosen'})", main.outlines)]
        for b in ["initial"] if baselines is None else baselines:
            if b == "scene":
                layouts.append(("scene layout", scene.layout.outlines))
                continue
            run_id, _, which = b.partition(":")
            if run_id == "initial":
                run_id, which = main.run_id, "initial"
            d = read_design(store, run_id, which or "final")
            layouts.append((d.label, d.outlines))
    return layouts
