"""The multi-start's choice made on the read-back a user gets, not on the objective alone.

The objective ranks designs by a local bound on the read-back error
(:mod:`mscap.design.readback`) or by the paper's min L1 distance; neither sees the
reconstruction map's own error between training poses or poses that read alike far apart,
and across a wider pose family the bound can rank designs the wrong way
(``jobs/pneumatic_quick.toml`` with its training family widened 25 %: the bound's choice
calibrates at 0.321 mm, another run's design at 0.236 mm; docs/results.md). So in a scene
with ``[calibration]`` the multi-start ends by calibrating its candidates with the protocol
of ``mscap calibrate``:

- the candidates (:func:`candidates`): the best ``[multistart] calibrate_best`` runs of each
  k by the objective (finished, not pruned), their initial layouts (``calibrate_initial``),
  and the scene's own layout (``calibrate_scene``: a baseline, reported, never chosen);
- every rank simulates their training and sequence poses
  (:func:`mscap.calibration.service.simulate_family`, farmed like the starts) into the cache
  beside the results file (``<results>_calibration.h5``, the one ``mscap calibrate`` uses),
  which keeps what finished when a job is stopped;
- the master fits and scores each design under ``calibrate_seeds`` noise seeds, writes
  ``/calibration`` and rewrites ``/selection``: the best design of each k is its calibrated
  design of least error, and k is chosen by the plateau rule on 1/error
  (:func:`mscap.service.selection.by_calibration`).

Storing a new run deletes ``/calibration`` (a new run may be better), so a resumed job
calibrates again at its end; simulations already cached cost nothing then. A calibration
that cannot be made (a stop, a family that cannot be simulated) leaves the objective's
selection, says why, and never touches the runs. A job restricted to some k or seeds (a
part of an array, ``mscap run --k-min/--k-max/--seeds``) does not calibrate; ``mscap run``
on the merged file does (every run is stored: only the calibration is left to do).
"""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING, Callable

import numpy as np

from mscap.errors import MscapError
from mscap.scene.settings import MAX_SEED
from mscap.service.selection import CalibratedDesign, Selection, ranked

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["wanted", "cache_path", "candidates", "noise_seeds", "score_designs", "calibrate_selection"]

log = logging.getLogger(__name__)


def wanted(scene: Scene) -> bool:
    """Does the scene's multi-start end with a calibration of its candidates?"""
    return scene.calibration is not None and scene.multistart.calibrate_best > 0


def cache_path(results_path):
    """The simulation cache beside the results file, the one ``mscap calibrate`` uses."""
    from mscap.calibration.report import default_paths

    return default_paths(str(results_path))[0]


def candidates(scene: Scene, store) -> tuple[list, dict[str, float]]:
    """The designs to calibrate from an open results file, as
    :class:`~mscap.calibration.service.Candidate` s, and each one's read-back bound (NaN: none):
    per k the best ``calibrate_best`` runs by the objective (the order of
    :func:`~mscap.service.selection.ranked`), then their initial layouts, then the scene's."""
    from mscap.calibration.service import Candidate
    from mscap.service.store import read_run, run_summaries

    ms = scene.multistart
    _, contenders = ranked(run_summaries(store))
    designs, bounds = [], {}
    records = [read_run(store, r.id) for k in sorted(contenders) for r in contenders[k][:ms.calibrate_best]]
    for record in records:
        designs.append(Candidate(record.id, tuple(record.final_outlines)))
        bounds[record.id] = record.bound_mm
    if ms.calibrate_initial:
        for record in records:
            designs.append(Candidate(f"{record.id}:initial", tuple(record.initial_outlines)))
            bounds[f"{record.id}:initial"] = record.initial_bound_mm
    if ms.calibrate_scene and scene.layout.outlines:
        designs.append(Candidate("scene", tuple(scene.layout.outlines)))
        bounds["scene"] = math.nan
    return designs, bounds


def noise_seeds(scene: Scene) -> list[int]:
    """The ``calibrate_seeds`` noise seeds: the scene's ``[calibration.noise] seed`` onwards."""
    first = scene.calibration.noise.seed
    return [(first + i) % (MAX_SEED + 1) for i in range(scene.multistart.calibrate_seeds)]


def score_designs(scene: Scene, designs, bounds: dict[str, float], cache) -> tuple[list[CalibratedDesign], float]:
    """Each design's calibrated error from the cache, averaged over :func:`noise_seeds`
    (every design sees the same draws of a seed), with its spread over them, and the summed
    simulation wall time of the designs' families. A design that cannot be scored (its
    reference pose failed, say) gets NaN and a warning; the others go on. A layout under two
    labels (the scene's, and a scene start's initial layout) counts its simulations once."""
    from mscap.calibration.service import evaluate

    seeds = noise_seeds(scene)
    out, simulation_s, simulated = [], 0.0, set()
    for design in designs:
        try:
            (scored,) = evaluate(scene, [design], cache, seeds=seeds)
        except MscapError as exc:
            log.warning("calibration of %s failed (%s); it cannot be chosen", design.label, exc)
            out.append(CalibratedDesign(design.label, design.k, math.nan, math.nan, bounds.get(design.label, math.nan)))
            continue
        # the sequence's mean point error of each seed (its runs are one block of rows)
        errors = np.nanmean(scored.errors.mean.reshape(len(seeds), -1), axis=1)
        if design.key not in simulated:  # one layout under two labels was simulated once
            simulated.add(design.key)
            simulation_s += scored.simulation_s
        out.append(CalibratedDesign(design.label, design.k, float(errors.mean()),
                                    float(errors.std()) if len(errors) > 1 else math.nan,
                                    float(bounds.get(design.label, math.nan))))
    return out, simulation_s


def calibrate_selection(scene: Scene, path, comm, say: Callable[[str], None] | None = None) -> Selection | None:
    """Every rank: calibrate the candidates of the results file ``path`` and, on rank 0,
    store them (``/calibration``) and the selection made on them. Returns that selection
    on rank 0, ``None`` on the workers and when no calibration could be made (the file
    keeps the objective's)."""
    from mscap.calibration.service import simulate_family
    from mscap.service.store import open_store, read_store, run_summaries, write_calibration, write_selection, \
        store_selection

    say = say or (lambda m: None)
    rank = comm.Get_rank()
    started = time.perf_counter()
    designs, bounds = [], {}
    if rank == 0:
        try:
            with read_store(path) as store:
                designs, bounds = candidates(scene, store)
        except MscapError as exc:
            log.warning("%s: cannot list the designs to calibrate (%s); the selection stays the objective's",
                        path, exc)
    designs = comm.bcast(designs, root=0)
    if not designs:
        return None
    cache = cache_path(path)
    if rank == 0:
        say(f"calibrating {len(designs)} designs to choose on read-back error (the best "
            f"{scene.multistart.calibrate_best} runs of each k"
            + (", their initial layouts" if scene.multistart.calibrate_initial else "")
            + (", the scene's layout" if "scene" in bounds else "") + f"); cache {cache}")
    complete = simulate_family(scene, designs, cache, comm, progress=say)
    if rank != 0:
        return None
    if not complete:  # stopped: a choice among the designs that happen to be done would be no choice
        say(f"{path}: stopped before every design was calibrated; the selection stays the objective's; "
            "rerun the same command to complete the calibration (the simulations done are cached)")
        return None
    calibrated, simulation_s = score_designs(scene, designs, bounds, cache)
    if not any(math.isfinite(d.error_mm) for d in calibrated if d.which != "scene"):
        say(f"{path}: no design could be calibrated (see the warnings); the selection stays the objective's")
        return None
    noise = scene.calibration.noise
    with open_store(path, scene, new_session=False) as store:
        workers_s = float(sum(r.wall_s for r in run_summaries(store)))
        write_calibration(store, calibrated, {
            "noise_seeds": np.array(noise_seeds(scene), dtype=np.int64), "noise_runs": int(noise.runs),
            "cache": str(cache), "wall_s": time.perf_counter() - started, "simulation_s": simulation_s})
        selection = store_selection(store)
        write_selection(store, selection)
    share = f", {100 * simulation_s / workers_s:.0f} % of the starts' {workers_s:.0f} s" if workers_s > 0 else ""
    say(f"calibrated {len(calibrated)} designs under {len(noise_seeds(scene))} noise seeds × {noise.runs} runs in "
        f"{time.perf_counter() - started:.0f} s (simulations {simulation_s:.0f} worker-s{share})")
    return selection
