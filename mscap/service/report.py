"""The tables of ``mscap inspect``: the per-k table of a multi-start results file with
the chosen k marked (or the same as JSON), every run's cost and accuracy, or one run's
history. Accuracy is the run's finer-mesh error estimate (:mod:`mscap.service.accuracy`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import h5py
import numpy as np

from mscap.scene.calibration import NoiseModel
from mscap.service.checks import float_attr
from mscap.service.store import finished_ids

__all__ = ["error_estimates", "margin_resolution", "resolution_text", "summary_json", "table", "runs_table",
           "history_text", "silent_plates", "silent_plates_text", "Reading", "reading_plates", "reading_text",
           "ReadingChoice", "reading_choice", "Cost", "cost", "cost_text"]

#: A plate whose read-out varies over the design poses by less than this fraction of the
#: per-reading offset noise (appendix A: ±2 pF uniform, σ = 1.15 pF) tells them nothing,
#: whatever the protocol: taring removes the per-run shift, not the offsets.
SILENT_FRACTION = 0.5


def error_estimates(store) -> dict[str, float]:
    """The finer-mesh error estimate of every finished run of an open results file (NaN:
    schema 1 files, failed runs)."""
    return {rid: float(store["runs"][rid].attrs.get("error_estimate", math.nan)) for rid in finished_ids(store)}


@dataclass(frozen=True)
class Cost:
    """What a results file's runs cost their workers (:mod:`mscap.service.usage`): CPU
    seconds of the runs and of their finer-mesh checks, the largest peak resident memory
    of a worker and its run, and how many runs carry these numbers (runs stored before
    mscap recorded them carry none)."""

    runs: int
    measured: int
    run_cpu_s: float
    check_cpu_s: float
    peak_rss_mb: float
    peak_run: str
    #: The in-run calibration (:mod:`mscap.service.calibrated`): its wall time and its
    #: simulations' summed wall time (worker-seconds); NaN without one.
    calibration_wall_s: float = math.nan
    calibration_simulation_s: float = math.nan

    @property
    def core_hours(self) -> float:
        return (self.run_cpu_s + self.check_cpu_s) / 3600.0

    def as_dict(self) -> dict:
        return {"runs": self.runs, "runs_measured": self.measured, "run_cpu_s": self.run_cpu_s,
                "check_cpu_s": self.check_cpu_s, "core_hours": self.core_hours,
                "peak_rss_mb": _finite_or_none(self.peak_rss_mb), "peak_run": self.peak_run or None,
                "calibration_wall_s": _finite_or_none(self.calibration_wall_s),
                "calibration_simulation_s": _finite_or_none(self.calibration_simulation_s)}


def cost(store) -> Cost:
    """The :class:`Cost` of every finished run of an open results file (attributes only)."""
    runs = store["runs"]
    rows = [(rid, runs[rid].attrs) for rid in sorted(finished_ids(store))]
    cpu = [(rid, float(a.get("cpu_s", math.nan)), float(a.get("error_estimate_cpu_s", math.nan)),
            float(a.get("peak_rss_mb", math.nan))) for rid, a in rows]
    measured = [row for row in cpu if math.isfinite(row[1])]
    peaks = [(peak, rid) for rid, _, _, peak in cpu if math.isfinite(peak)]
    peak, peak_run = max(peaks) if peaks else (math.nan, "")
    calibration = store["calibration"].attrs if isinstance(store.get("calibration"), h5py.Group) else {}
    return Cost(runs=len(rows), measured=len(measured), run_cpu_s=sum(r[1] for r in measured),
                check_cpu_s=sum(r[2] for r in measured if math.isfinite(r[2])), peak_rss_mb=peak, peak_run=peak_run,
                calibration_wall_s=_number(calibration, "wall_s"),
                calibration_simulation_s=_number(calibration, "simulation_s"))


def _number(attrs, name: str) -> float:
    """Attribute ``name`` as a number; NaN when absent or not a number (it only informs)."""
    try:
        return float_attr(attrs, name) if name in attrs else math.nan
    except ValueError:
        return math.nan


def cost_text(c: Cost) -> str:
    """One line: the core-hours of the runs that carry them, the largest worker, and the
    in-run calibration's wall time and worker-seconds."""
    if not c.runs:
        line = "cost: no run stored yet"
    elif not c.measured:
        line = f"cost: no CPU time stored ({c.runs} run{'s' * (c.runs != 1)}, written before mscap recorded it)"
    else:
        line = (f"cost: {c.core_hours:.3g} core-hours of CPU (runs {c.run_cpu_s / 3600:.3g}, finer-mesh checks "
                f"{c.check_cpu_s / 3600:.3g}) over {c.measured} run{'s' * (c.measured != 1)}")
    if c.measured < c.runs and c.measured:
        line += f" ({c.runs - c.measured} more stored before mscap recorded CPU time)"
    if math.isfinite(c.peak_rss_mb):
        line += f"; largest worker peak {c.peak_rss_mb:.0f} MB (run {c.peak_run})"
    if math.isfinite(c.calibration_wall_s):
        line += (f"; the calibration of the best designs {c.calibration_wall_s:.0f} s wall, its simulations "
                 f"{c.calibration_simulation_s:.0f} worker-s")
    return line


def _error(errors: dict | None, rid) -> float:
    """The finer-mesh error estimate of run ``rid`` (NaN if unknown)."""
    return (errors or {}).get(rid, math.nan)


def _finite_or_none(x: float):
    return x if math.isfinite(x) else None


def summary_json(selection, errors: dict | None = None, readings: dict | None = None) -> dict:
    """The ``--json`` document of a ``Selection``; ``errors`` maps run ids to their
    finer-mesh error estimates, ``readings`` the per-k best runs to their :class:`Reading`."""
    return {"per_k": [{"k": s.k, "runs_ok": s.runs_ok, "runs_pruned": s.runs_pruned, "runs_failed": s.runs_failed,
                       "best_metric": s.best_metric, "best_run": s.best_run, "wall_s": s.wall_s,
                       "best_error_estimate": _finite_or_none(_error(errors, s.best_run)),
                       "best_bound_mm": s.best_bound_mm,
                       "best_reading_plates": None if s.best_run not in (readings or {})
                       else readings[s.best_run].plates,
                       "best_design": s.best_design, "best_calibrated_error_mm": s.best_error_mm}
                      for s in selection.per_k],
            "by_bound": selection.by_bound, "by_calibration": selection.by_calibration,
            "calibrated": [{"design": d.label, "k": d.k, "error_mm": _finite_or_none(d.error_mm),
                            "spread_mm": _finite_or_none(d.spread_mm), "bound_mm": _finite_or_none(d.bound_mm)}
                           for d in selection.calibrated],
            "objective_chosen_k": selection.objective_k,
            "chosen_k": selection.chosen_k, "chosen_run": selection.chosen_run,
            "chosen_design": selection.chosen_design,
            "plateau_tol": selection.plateau_tol, "plateau_reached": selection.plateau_reached,
            "runs_total": selection.runs_total, "finer_chosen_k": selection.finer_chosen_k,
            "resolved": selection.resolved, "metric_error": _finite_or_none(selection.metric_error),
            "weakest_decision": None if selection.weakest is None else list(selection.weakest),
            "decision_margin": _finite_or_none(selection.margin),
            "decision_finer_margin": _finite_or_none(selection.finer_margin),
            "decision_error": _finite_or_none(selection.margin_error), "resolution": selection.verdict()}


def silent_plates(capacitance_pF, noise=None) -> list[tuple[int, float, float]]:
    """Plates of a design whose read-out (``(n_poses, k)`` capacitances over its design
    poses) varies by less than :data:`SILENT_FRACTION` of the per-reading noise σ: as
    ``(plate, mean pF, standard deviation pF)``. The optimiser cannot revive such a plate:
    with no sensitivity to the poses it gets no gradient from either objective."""
    sigma = (noise or NoiseModel()).additive_std_pF
    c = np.asarray(capacitance_pF, dtype=float)
    if c.ndim != 2 or len(c) < 2 or not np.isfinite(c).all():
        return []
    spread = c.std(axis=0)
    return [(int(j), float(c[:, j].mean()), float(spread[j])) for j in np.flatnonzero(spread < SILENT_FRACTION * sigma)]


@dataclass(frozen=True)
class Reading:
    """Which plates of a design read its poses: the ``k`` plates less the silent ones
    (:func:`silent_plates`), and the min pairwise L1 distance over those alone (pF)."""

    k: int
    silent: tuple[int, ...]
    metric_pF: float

    @property
    def plates(self) -> int:
        return self.k - len(self.silent)


def reading_plates(capacitance_pF, noise=None) -> Reading:
    """The :class:`Reading` of a design's ``(n_poses, k)`` capacitances over its design poses."""
    from mscap.design.history import min_pairwise_l1

    c = np.asarray(capacitance_pF, dtype=float)
    silent = tuple(j for j, _, _ in silent_plates(c, noise))
    keep = [j for j in range(c.shape[1]) if j not in silent]
    metric = min_pairwise_l1(c[:, keep]) if keep and len(c) > 1 else math.nan
    return Reading(k=int(c.shape[1]), silent=silent, metric_pF=float(metric))


def _reads(reading: Reading | None) -> str:
    """``plates/k`` of a :class:`Reading`, ``-`` without one."""
    return "-" if reading is None else f"{reading.plates}/{reading.k}"


def reading_text(selection, readings: dict) -> str:
    """A line when the chosen k's best design has silent plates: as a sensor it has fewer
    plates, and its min L1 over them against the best of that smaller k (empty otherwise).
    ``readings`` maps the per-k best runs to their :class:`Reading`."""
    chosen = readings.get(selection.chosen_run)
    if chosen is None or not chosen.silent:
        return ""
    n = chosen.plates
    line = (f"  k = {selection.chosen_k}'s best design reads on {n} of its {chosen.k} plates: without plate"
            f"{'s' * (len(chosen.silent) > 1)} {', '.join(map(str, chosen.silent))} its min L1 is "
            f"{chosen.metric_pF:.4g} pF")
    smaller = next((s for s in selection.per_k if s.k == n and s.best_metric is not None), None)
    if smaller is not None:
        line += f", k = {n}'s best {smaller.best_metric:.4g} pF"
    return line + f": as a sensor it is a {n}-plate design"


@dataclass(frozen=True)
class ReadingChoice:
    """The plateau rule (:func:`~mscap.service.selection.choose_k`) on the number of plates
    that read instead of k: every finished, unpruned design counts as the sensor of its
    plates that read, scored by its min L1 over them (or its read-back bound). ``best``
    maps each number of plates to ``(score, run)``; ``plates`` and ``run`` are the choice."""

    plates: int | None
    run: str | None
    best: dict
    by_bound: bool

    def text(self, chosen_k: int | None) -> str:
        if self.plates is None:
            return ""
        unit = "mm" if self.by_bound else "pF"
        per = ", ".join(f"{n}: {score:.4g} {unit} ({rid})" for n, (score, rid) in sorted(self.best.items()))
        same = " (the rule on k agrees)" if self.plates == chosen_k else f" (the rule on k picks {chosen_k})"
        return (f"  by the plates that read: {self.plates} plates, run {self.run}{same}; best per number of "
                f"plates read: {per}")


def reading_choice(runs, readings: dict, plateau_tol: float) -> ReadingChoice:
    """:class:`ReadingChoice` of ``runs`` (``RunSummary``-like: ``id``, ``ok``, ``pruned``,
    ``metric``, ``bound_mm``) with ``readings`` (run id → :class:`Reading`). A silent
    plate adds nothing to a read-back bound, so bound scenes keep each run's bound."""
    from mscap.service.selection import choose_k

    good = [r for r in runs if r.ok and not r.pruned and r.id in readings and math.isfinite(r.metric)]
    by_bound = bool(good) and all(math.isfinite(r.bound_mm) and r.bound_mm > 0 for r in good)
    best = {}
    for r in sorted(good, key=lambda r: r.id):  # ties to the smaller id, as select()
        n, value = readings[r.id].plates, r.bound_mm if by_bound else readings[r.id].metric_pF
        if n not in best or (value < best[n][0] if by_bound else value > best[n][0]):
            best[n] = (value, r.id)
    ns = sorted(best)
    n = choose_k(ns, [1.0 / best[i][0] if by_bound else best[i][0] for i in ns], plateau_tol)
    return ReadingChoice(plates=n, run=None if n is None else best[n][1], best=best, by_bound=by_bound)


def silent_plates_text(run_id: str, plates, noise=None) -> str:
    """One line per silent plate of the chosen run (empty when there is none)."""
    additive = (noise or NoiseModel()).additive_pF
    return "\n".join(f"  warning: plate {j} of {run_id} reads {mean:.2f} ± {std:.2g} pF at every design pose, "
                     f"less than {SILENT_FRACTION:g} of the read-out noise (±{additive:g} pF): it tells the poses "
                     f"nothing" for j, mean, std in plates)


def narrow_necks(outlines, scene_toml: str) -> tuple[float, list[tuple[int, float]]]:
    """Plates of a design with a neck or slot narrower than the scene's feature size —
    ``[optimizer] min_feature_mm``, or half ``[capacitors] min_gap_mm`` when it sets none —
    as ``(plate, width mm)``, and that feature size. Two points of an outline count when
    they are farther apart along it than :data:`~mscap.design.objective.NECK_ARC` feature
    sizes (docs/optimize.md, "Necks")."""
    import tomllib

    from mscap.design.objective import NECK_ARC
    from mscap.geometry.polygons import narrowest_neck
    from mscap.scene.settings import DEFAULT_MIN_GAP_MM, OptimizerSettings

    try:
        data = tomllib.loads(scene_toml)
        feature = float(data.get("optimizer", {}).get("min_feature_mm", OptimizerSettings.min_feature_mm)) \
            or 0.5 * float(data.get("capacitors", {}).get("min_gap_mm", DEFAULT_MIN_GAP_MM))
    except (tomllib.TOMLDecodeError, TypeError, ValueError, AttributeError):
        return math.nan, []
    if not feature > 0:
        return feature, []
    widths = [narrowest_neck(o, NECK_ARC * feature, feature) for o in outlines]
    return feature, [(j, w) for j, w in enumerate(widths) if w < feature]


def narrow_necks_text(run_id: str, necks, feature: float) -> str:
    """One line per plate of the chosen run with a neck narrower than ``feature``."""
    return "\n".join(f"  warning: plate {j} of {run_id} has a neck or slot {width:.3g} mm wide, narrower than "
                     f"{feature:g} mm: a stencil may not cut it (set [optimizer] min_feature_mm; docs/optimize.md, "
                     f"\"Necks\")" for j, width in necks)


def margin_resolution(record) -> tuple[float, float, float]:
    """A run's final min pairwise L1 (pF), its estimated discretisation bias (pF; the last
    history row's ``margin_error_pF``, :mod:`mscap.design.resolution`; NaN in files
    written before 2026-12-05) and its remesh noise: the largest change of min L1 at a
    remesh, the same design on a fresh mesh (pF; 0 without a remesh)."""
    history = record.history
    errors = np.asarray(history.get("margin_error_pF", []), dtype=float)
    l1 = np.asarray(history.get("min_l1_pF", []), dtype=float)
    at = [i for i, event in enumerate(history.get("event", [])) if event == "remesh" and i > 0]
    noise = float(np.abs(l1[at] - l1[np.array(at) - 1]).max()) if at else 0.0
    return float(record.metric), float(errors[-1]) if len(errors) else math.nan, noise


def resolution_text(run_id: str, metric: float, error: float, noise: float = 0.0) -> str:
    """One line: whether the chosen design's margin exceeds its own estimated error,
    bias and remesh noise together."""
    if not np.isfinite(error) or not metric > 0:
        return ""
    verdict = ("resolved" if error + noise < metric else
               "NOT resolved: its margin is within its own error; rerun with finer [mesh] / [elastic] settings")
    return (f"  run {run_id}'s min L1 {metric:.4g} pF: estimated discretisation bias {error:.3g} pF "
            f"({100 * error / metric:.1f} %, mscap.design.resolution), remesh noise up to {noise:.2g} pF "
            f"({100 * noise / metric:.1f} %): {verdict}")


def _percent(x: float) -> str:
    return f"{100 * x:.2f} %" if math.isfinite(x) else "-"


def table(selection, title: str = "", errors: dict | None = None, readings: dict | None = None) -> str:
    """The per-k table; ``*`` marks the chosen k. ``error`` is the best run's finer-mesh
    error estimate, ``time`` the summed wall time of the k's runs, ``reads`` (with
    ``readings``, best run → :class:`Reading`) how many of the best design's plates read
    its poses."""
    lines = [title] if title else []
    readings = readings or {}
    bound = selection.by_bound  # runs designed for read-back: best = smallest bound
    calibrated = selection.by_calibration  # chosen on calibrated error: its column and design first
    pruned = any(s.runs_pruned for s in selection.per_k)  # a column only when a rule pruned
    lines.append(f"{'':1} {'k':>3} {'ok':>4} " + (f"{'pruned':>6} " if pruned else "") + f"{'failed':>6} "
                 + (f"{'calibrated (mm)':>15} {'best design':<28} " if calibrated else "")
                 + (f"{'best bound (mm)':>16} {'min L1 (pF)':>12}" if bound else f"{'best min L1 (pF)':>17}")
                 + f" {'best run' + (' by bound' if calibrated else ''):<20} {'error':>8} {'time (s)':>9}"
                 + (f" {'reads':>5}" if readings else ""))
    for s in selection.per_k:
        mark = "*" if s.k == selection.chosen_k else " "
        metric = "-" if s.best_metric is None else f"{s.best_metric:.6g}"
        score = (f"{'-' if s.best_bound_mm is None else format(s.best_bound_mm, '.4g'):>16} {metric:>12}"
                 if bound else f"{metric:>17}")
        by_error = (f"{'-' if s.best_error_mm is None else format(s.best_error_mm, '.4g'):>15} "
                    f"{s.best_design or '-':<28} " if calibrated else "")
        lines.append(f"{mark} {s.k:>3} {s.runs_ok:>4} " + (f"{s.runs_pruned:>6} " if pruned else "")
                     + f"{s.runs_failed:>6} {by_error}{score} "
                     f"{s.best_run or '-':<20} {_percent(_error(errors, s.best_run)):>8} {s.wall_s:>9.1f}"
                     + (f" {_reads(readings.get(s.best_run)):>5}" if readings else ""))
    if selection.chosen_k is None:
        lines.append("no successful run: no k chosen")
    else:
        note = "" if selection.plateau_reached else " (largest k with a successful run: plateau not confirmed)"
        what = f"design {selection.chosen_design}" if calibrated else f"run {selection.chosen_run}"
        lines.append(f"* chosen k = {selection.chosen_k}, {what}, plateau_tol "
                     f"{selection.plateau_tol:g}{note}; {selection.runs_total} runs")
        lines.append(f"  {selection.verdict()}")
        if selection.advice():
            lines.append(f"  {selection.advice()}")
        if calibrated:
            lines.append("  (calibrated: the sequence's mean point error of the `mscap calibrate` protocol, mean "
                         "over the noise seeds; docs/calibration.md, \"Choosing on calibrated error\")")
        if bound:
            lines.append("  (read-back bound: soft max over the design family of the Cramér–Rao bound on the "
                         "RMS per-vertex error, mm, ⊕ the calibration map's noise on the grid when the scene's "
                         "distance is \"readback\"; docs/optimize.md)")
    return "\n".join(lines)


def runs_table(records) -> str:
    """One line per run: status, iterations, the metric and its value on the finer mesh,
    the error estimates of C and of the pose-to-pose distances, the run's wall time and
    the check's, its worker's CPU seconds (run and check) and peak memory, and how many of
    its plates read the poses."""
    lines = [f"{'run':<20} {'status':<6} {'its':>4} {'bound (mm)':>15} {'min L1 (pF)':>12} {'finer (pF)':>11} "
             f"{'error C':>8} {'signal':>8} {'time (s)':>9} {'check (s)':>9} {'CPU (s)':>9} {'peak (MB)':>9} "
             f"{'reads':>5}"]
    for r in records:
        def number(x, fmt):
            return format(x, fmt) if math.isfinite(x) else "-"
        bound = "-" if not math.isfinite(r.bound_mm) else f"{r.initial_bound_mm:.3g} → {r.bound_mm:.3g}"
        lines.append(f"{r.id:<20} {r.status:<6} {r.iterations:>4} {bound:>15} {number(r.metric, '.6g'):>12} "
                     f"{number(r.finer_metric_pF, '.6g'):>11} {_percent(r.error_estimate):>8} "
                     f"{_percent(r.signal_error):>8} {r.wall_s:>9.1f} "
                     f"{number(r.error_estimate_wall_s, '.1f'):>9} "
                     f"{number(r.cpu_s + np.nan_to_num(r.error_estimate_cpu_s), '.1f'):>9} "
                     f"{number(r.peak_rss_mb, '.0f'):>9} "
                     f"{_reads(reading_plates(r.final_capacitance_pF) if r.ok else None):>5}")
    return "\n".join(lines)


def history_text(record) -> str:
    """One run's attributes, then its history as tab-separated columns (``--run``)."""
    lines = [f"run {record.id}: k = {record.k}, seed {record.seed}, init {record.init}, status {record.status}, "
             f"rank {record.rank}, {record.wall_s:.1f} s, {record.iterations} iterations"
             + (f" ({record.reason})" if record.reason else "")]
    if math.isfinite(record.cpu_s):
        lines.append(f"cost on its worker: {record.cpu_s:.1f} CPU-s"
                     + (f" + {record.error_estimate_cpu_s:.1f} for the finer-mesh check"
                        if math.isfinite(record.error_estimate_cpu_s) else "")
                     + (f", peak resident memory {record.peak_rss_mb:.0f} MB" if math.isfinite(record.peak_rss_mb)
                        else ""))
    if not record.ok:
        lines.append(f"error: {record.error}")
    if math.isfinite(record.metric):
        lines.append(f"min pairwise L1: {record.metric:.6g} pF over {len(record.poses)} design poses: "
                     + ", ".join(record.poses))
    if math.isfinite(record.bound_mm):
        lines.append(f"read-back bound: {record.initial_bound_mm:.4g} mm initial, {record.bound_mm:.4g} mm final "
                     "(history column d is minus the bound)")
    if math.isfinite(record.error_estimate):
        lines.append(f"on a mesh one level finer: min pairwise L1 {record.finer_metric_pF:.6g} pF "
                     f"({_percent(record.metric_error)} off), capacitances within {_percent(record.error_estimate)}, "
                     f"pose-to-pose distances within {_percent(record.signal_error)} "
                     f"(check took {record.error_estimate_wall_s:.1f} s)")
    elif record.status == "ok":
        lines.append("no finer-mesh check (a finished run of its k was better, or the check failed or was off)")
    names = list(record.history)
    lines.append("\t".join(names))
    columns = [record.history[n] for n in names]
    for row in zip(*columns):
        lines.append("\t".join(v if isinstance(v, str) else f"{v:.6g}" if isinstance(v, float) else str(v)
                               for v in (x.item() if hasattr(x, "item") else x for x in row)))
    return "\n".join(lines)
