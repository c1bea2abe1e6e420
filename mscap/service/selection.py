"""Start configurations of the multi-start service and the choice of k (paper §5.1).

``configurations(scene)`` lists every (k, seed, init) the service runs; ``select`` picks
the best run per k and the number of capacitors k. Both depend on nothing but their
arguments, so any process (master, worker, ``mscap inspect``) gets the same answer.
The rule is documented in ``docs/hdf5.md`` ("Selection").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Iterable, Sequence

from mscap.scene.loader import check_multistart

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["ERROR_BOUND", "StartConfig", "RunSummary", "KSummary", "Selection", "MULTISTART_INITS", "run_id",
           "configurations", "repeated_starts", "choose_k", "run_score", "rank_key", "select", "SELECTION_RULE",
           "SELECTION_RULE_BOUND", "SELECTION_RULE_CALIBRATED", "CalibratedDesign", "by_calibration",
           "SCENE_START_INDEX", "start_index", "ranked", "design_of"]

#: The ``init`` kinds the multi-start schedules (:func:`configurations`: sensitivity-map
#: starts first, then Lloyd, then random ones, then the scene's own layout with
#: ``scene_start``); the same as :data:`mscap.design.starts.START_INITS`.
MULTISTART_INITS = ("lloyd", "random", "scene", "sensitivity")
#: The start index of the scene-layout start (``[multistart] scene_start``): never a
#: regular start's, since ``starts_per_k`` < 1000.
SCENE_START_INDEX = 999

#: One-line statement of the k rule, stored beside the choice in ``/selection``.
SELECTION_RULE = ("chosen k = smallest k with a successful run such that no larger k with a successful "
                  "run has a best metric above (1 + plateau_tol) * m(k)")
#: The rule when the runs carry a read-back bound (design poses from the calibration family).
SELECTION_RULE_BOUND = ("best run per k = smallest read-back bound b; chosen k = smallest k with a successful "
                        "run such that no larger k has a best bound below b(k) / (1 + plateau_tol)")
#: The rule when the best designs were calibrated in the run (:mod:`mscap.service.calibrated`).
SELECTION_RULE_CALIBRATED = ("best design per k = smallest calibrated read-back error e (mean over the noise "
                             "seeds) among the calibrated runs' final and initial layouts; chosen k = smallest "
                             "k such that no larger k has a best error below e(k) / (1 + plateau_tol)")


def run_id(k: int, seed: int, init: str) -> str:
    """The name of a run, e.g. ``k3_s3007_lloyd`` (also its HDF5 group name)."""
    return f"k{k}_s{seed:04d}_{init}"


@dataclass(frozen=True)
class StartConfig:
    """One start: ``k`` capacitors, initial layout from ``init`` with ``seed``."""

    k: int
    seed: int
    init: str
    #: The optimiser state this start continues from (:mod:`mscap.service.checkpoints`), or ``None``.
    resume: object = field(default=None, compare=False, repr=False)

    @property
    def id(self) -> str:
        return run_id(self.k, self.seed, self.init)


def configurations(scene: Scene) -> list[StartConfig]:
    """Every start of the scene's multi-start, ordered by k then index.

    For each k in ``k_min..k_max``, ``starts_per_k`` starts: the first
    ``ceil(sensitivity_fraction · starts_per_k)`` sensitivity-map layouts, the next
    ``ceil(lloyd_fraction · starts_per_k)`` (as many as are left) Lloyd layouts, the rest
    random ones. Start
    ``index`` of ``k`` gets ``seed = multistart.seed · 10⁶ + k · 10³ + index``: a function
    of the scene and (k, index) only — never of the rank, the number of ranks or the order
    in which runs finish. With ``scene_start``, the k of the scene's own layout (if in
    ``k_min..k_max``) gets one more start from that layout, index :data:`SCENE_START_INDEX`
    (e.g. ``k4_s4999_scene``).
    """
    ms = scene.multistart
    n = ms.starts_per_k
    check_multistart(scene.path, ms)
    # round() first: 0.2 * 25 is 5.000000000000001 in floating point and must give 5.
    n_sensitivity = min(n, math.ceil(round(ms.sensitivity_fraction * n, 9)))
    n_lloyd = min(n - n_sensitivity, math.ceil(round(ms.lloyd_fraction * n, 9)))

    def init(index: int) -> str:
        if index < n_sensitivity:
            return "sensitivity"
        return "lloyd" if index < n_sensitivity + n_lloyd else "random"

    configs = []
    for k in range(ms.k_min, ms.k_max + 1):
        configs += [StartConfig(k, ms.seed * 1_000_000 + k * 1000 + index, init(index)) for index in range(n)]
        if ms.scene_start and k == scene.layout.k:
            configs.append(StartConfig(k, ms.seed * 1_000_000 + k * 1000 + SCENE_START_INDEX, "scene"))
    return configs


def start_index(config: StartConfig) -> int:
    """A start's index within its k (``mscap run --seeds A:B`` keeps A <= index < B)."""
    return config.seed % 1000


def repeated_starts(scene: Scene, configs: Sequence[StartConfig] | None = None) -> dict[str, str]:
    """Lloyd starts whose initial layout is that of an earlier Lloyd start of the same k,
    plate for plate: ``{id: id of the first start with that layout}``.

    Lloyd's relaxation on a grid ends in one of few centroidal tessellations, so different
    seeds often give the very same sites (8 Lloyd starts per k on
    ``jobs/joystick_quick.toml``: 2 and 4 distinct layouts at k = 2, 3). A start whose plates
    are equal, in the same order, to an earlier one's is the same run bit for bit, and the
    multi-start skips it. The same plates in another order are *not* a repeat: the
    numbering changes gmsh's mesh, and the optimisation path with it, by more than the
    mesh error (pneumatic_quick, k = 2: bounds 0.212 against 0.250 mm from one layout in two
    orders; docs/performance.md §8). This depends on the scene alone, so every array task
    of a split job agrees. Random starts are not compared: two seeds give the same layout
    with probability 0. A start whose layout cannot be made is left to the worker, which
    stores it as failed with the reason.
    """
    import numpy as np

    from mscap.errors import MscapError
    from mscap.geometry.initial import initial_layout

    configs = configurations(scene) if configs is None else configs
    seen: dict[int, list[tuple[tuple[np.ndarray, ...], str]]] = {}
    out = {}
    for c in configs:
        if c.init != "lloyd":
            continue
        try:
            plates = initial_layout(scene, c.k, c.seed, c.init).outlines
        except MscapError:
            continue
        for other, other_id in seen.setdefault(c.k, []):
            if all(map(np.array_equal, plates, other)):  # same k: as many plates
                out[c.id] = other_id
                break
        else:
            seen[c.k].append((plates, c.id))
    return out


@dataclass(frozen=True)
class RunSummary:
    """What selection needs of one stored run; ``metric`` (pF) is the final min pairwise
    L1 distance, NaN when the run failed. A pruned run is ``ok`` (it has a design) and
    ``pruned``."""

    id: str
    k: int
    ok: bool
    metric: float
    wall_s: float
    bound_mm: float = math.nan
    pruned: bool = False
    #: The metric of the run's final layout on the finer mesh (NaN: not checked).
    finer_metric: float = math.nan
    #: Its read-back bound on the finer mesh (NaN: no design family, or not checked).
    finer_bound_mm: float = math.nan


@dataclass(frozen=True)
class CalibratedDesign:
    """One design calibrated inside the multi-start (:mod:`mscap.service.calibrated`):
    ``label`` is a run id (its final layout), ``RUN:initial`` (that run's initial layout)
    or ``"scene"`` (the scene's own layout, a baseline that is reported, never chosen).
    ``error_mm`` is the calibrated read-back error, the sequence's mean point error
    averaged over the noise runs and then over the noise seeds; ``spread_mm`` its standard
    deviation over the seeds; ``bound_mm`` the objective's read-back bound of the same
    layout (NaN: none)."""

    label: str
    k: int
    error_mm: float
    spread_mm: float = math.nan
    bound_mm: float = math.nan

    @property
    def which(self) -> str:
        """``"final"``, ``"initial"`` or ``"scene"``."""
        return design_of(self.label)[1]

    @property
    def run_id(self) -> str | None:
        return design_of(self.label)[0]


def design_of(label: str) -> tuple[str | None, str]:
    """A calibrated design's label as ``(run id, which layout)``: ``"k2_s2000_lloyd"`` →
    ``("k2_s2000_lloyd", "final")``, ``"k2_s2000_lloyd:initial"`` → ``(…, "initial")``,
    ``"scene"`` → ``(None, "scene")``."""
    if label == "scene":
        return None, "scene"
    run, _, which = label.partition(":")
    return run, which or "final"


@dataclass(frozen=True)
class KSummary:
    """Runs of one k: counts (``runs_ok`` includes the ``runs_pruned``), the best successful
    run (``None`` if none) and the summed wall time (s)."""

    k: int
    runs_ok: int
    runs_failed: int
    best_metric: float | None
    best_run: str | None
    wall_s: float
    best_bound_mm: float | None = None
    runs_pruned: int = 0
    #: The best calibrated design of the k (a run id or ``RUN:initial``) and its error
    #: (``None``: the runs were not calibrated).
    best_design: str | None = None
    best_error_mm: float | None = None


@dataclass(frozen=True)
class Selection:
    """Per-k summaries (ascending k), the chosen k and its best run (``None`` when no run
    succeeded), and whether a larger k was available to confirm the plateau.

    With ``calibrated`` designs (the multi-start calibrated its best runs,
    :mod:`mscap.service.calibrated`) the choice is made on their calibrated read-back
    error: ``chosen_design`` is then the chosen run's final layout or its initial one
    (``RUN:initial``), and ``objective_k``/``objective_design`` keep what the objective alone
    chooses; the finer-mesh fields speak of the objective's choice."""

    per_k: tuple[KSummary, ...]
    chosen_k: int | None
    chosen_run: str | None
    plateau_tol: float
    plateau_reached: bool
    runs_total: int
    by_bound: bool = False
    #: The k the same rule picks from the best runs' metrics (or bounds) on the finer mesh
    #: (``None`` when a best run was not checked).
    finer_chosen_k: int | None = None
    #: Largest relative difference of a best run's metric (or bound) from its finer-mesh value.
    metric_error: float = math.nan
    #: The rule's weakest decision (:func:`decisions`): the two k it compares, the relative
    #: margin by which it holds, the same decision's margin on the finer mesh and the bound
    #: on the first margin's error, :data:`ERROR_BOUND` times the difference of the two (NaN
    #: unchecked); ``None``/NaN with fewer than two k. The weakest is the one with the least
    #: margin left over its error.
    weakest: tuple[int, int] | None = None
    margin: float = math.nan
    margin_error: float = math.nan
    finer_margin: float = math.nan
    calibrated: tuple[CalibratedDesign, ...] = ()
    #: With ``calibrated``: the design chosen (``None``: the chosen run's final layout).
    design: str | None = None
    #: The k and run the objective alone chooses (``chosen_k``/``chosen_run`` unless the
    #: choice was made on calibrated error); the finer-mesh check is of this choice.
    objective_k: int | None = None
    objective_design: str | None = None

    @property
    def by_calibration(self) -> bool:
        """Was the choice made on calibrated read-back error?"""
        return bool(self.calibrated)

    @property
    def chosen_design(self) -> str | None:
        """The chosen layout: a run id (its final layout) or ``RUN:initial``."""
        return self.design or self.chosen_run

    @property
    def chosen_which(self) -> str:
        """``"final"`` or ``"initial"``: which layout of ``chosen_run`` was chosen."""
        return design_of(self.chosen_design or "")[1]

    def calibrated_of(self, label: str | None) -> CalibratedDesign | None:
        return next((d for d in self.calibrated if d.label == label), None)

    def calibration_text(self) -> str:
        """With calibrated designs, what the choice rests on, e.g. "chosen on calibrated
        read-back error (13 designs): k2_s1002001_lloyd 0.234 ± 0.0011 mm; next best
        k2_s1002000_lloyd 0.249 mm (+6.1 %); the objective alone would have chosen
        k3_s1003000_lloyd (k = 3), which calibrates at 0.321 mm (+37.1 %); the scene's own
        layout 0.425 mm" (pneumatic_quick with its family widened, docs/results.md). A lead
        over the next best of less than two standard deviations of the difference over the
        noise seeds is called a tie. Empty without calibrated designs."""
        if not self.by_calibration or self.chosen_design is None:
            return ""
        chosen = self.calibrated_of(self.chosen_design)
        parts = [f"chosen on calibrated read-back error ({len(self.calibrated)} designs): "
                 f"{chosen.label} {chosen.error_mm:.3g}"
                 + (f" ± {chosen.spread_mm:.2g}" if math.isfinite(chosen.spread_mm) else "") + " mm"]
        rivals = sorted((d for d in self.calibrated if d.which != "scene" and d.label != chosen.label
                         and math.isfinite(d.error_mm)), key=lambda d: (d.error_mm, d.label))
        if rivals:
            rival = rivals[0]
            tie = math.hypot(rival.spread_mm, chosen.spread_mm) * 2 > rival.error_mm - chosen.error_mm
            parts.append(f"next best {rival.label} {rival.error_mm:.3g} mm "
                         f"({_signed(rival.error_mm / chosen.error_mm - 1)}"
                         + (", within the noise seeds' spread: a tie" if tie else "") + ")")
        other = self.calibrated_of(self.objective_design)
        if self.objective_design != chosen.label:
            parts.append(f"the objective alone would have chosen {self.objective_design} (k = {self.objective_k})"
                         + (f", which calibrates at {other.error_mm:.3g} mm "
                            f"({_signed(other.error_mm / chosen.error_mm - 1)})" if other else ""))
        scene = self.calibrated_of("scene")
        if scene is not None and math.isfinite(scene.error_mm):
            parts.append(f"the scene's own layout {scene.error_mm:.3g} mm"
                         + (" (better than every design of the run)" if scene.error_mm < chosen.error_mm else ""))
        return "; ".join(parts)

    def advice(self) -> str:
        """At a chosen k with no larger k to confirm its plateau (the largest k that
        succeeded), what to do: how much the best design gained from the k below, and the
        k_max to try. Empty when the plateau is confirmed or nothing was chosen."""
        if self.chosen_k is None or self.plateau_reached:
            return ""
        if self.by_calibration:
            what = "precision 1 / (calibrated error)"
            best = {s.k: 1.0 / s.best_error_mm for s in self.per_k if s.best_error_mm}
        else:
            what = "precision 1 / (read-back bound)" if self.by_bound else "min L1"
            best = {s.k: (1.0 / s.best_bound_mm if self.by_bound and s.best_bound_mm else s.best_metric)
                    for s in self.per_k if (s.best_bound_mm if self.by_bound else s.best_metric)}
        below = [k for k in best if k < self.chosen_k]
        grew = "" if not below else (f"; its best {what} grew {_pct(best[self.chosen_k] / best[max(below)] - 1)} "
                                     f"from k = {max(below)}")
        return (f"the plateau is not confirmed: k = {self.chosen_k} is the largest k that succeeded{grew}. "
                f"Raise [multistart] k_max to {self.chosen_k + 2} (at least {self.chosen_k + 1}): the rule "
                f"needs a larger k that gains less than plateau_tol = {self.plateau_tol:g}")

    @property
    def resolved(self) -> bool | None:
        """Does the finer mesh pick the same k as the objective? ``None`` if it cannot tell."""
        if self.objective_k is None or self.finer_chosen_k is None:
            return None
        return self.finer_chosen_k == self.objective_k

    def verdict(self) -> str:
        """One line on whether the mesh resolves the choice, e.g. "not resolved: on the
        finer mesh the rule picks k = 2; its weakest decision, k = 2 against k = 3, holds by
        1.5 % (-10.6 % on the finer mesh, error bound 24.3 %)" (k = 3 beat k = 2 by 6.6 %,
        1.5 % past the 5 % plateau_tol, and fell 6.2 % short of it on the finer mesh).
        "marginal": the same k on the finer mesh, but a decision holds by less than its
        error bound, :data:`ERROR_BOUND` times the change of its margin between the meshes.

        The error that matters is the decision's, not each run's: both runs are read on
        meshes of the same settings, so much of their metrics' errors is common and cancels
        in the ratio that decides (jobs/quick.toml with P2 elastic elements: its k = 2 and
        k = 3 runs read 15.3 % and 10.0 % above their finer-mesh metrics, while the decision's
        margin only moves from 23.4 % to 17.7 %)."""
        if self.chosen_k is None:
            return "no k chosen"
        if self.by_calibration:
            return f"{self.calibration_text()}. The objective's own choice: {self._resolution()}"
        return self._resolution()

    def _resolution(self) -> str:
        if self.objective_k is None:
            return "no k chosen"
        if self.resolved is None:
            return ("resolution unknown: a best run has no finer-mesh check"
                    + (" of its read-back bound (files before it was stored have none)" if self.by_bound else ""))
        numbers = (f"its weakest decision, k = {self.weakest[0]} against k = {self.weakest[1]}, holds by "
                   f"{_pct(self.margin)} ({_pct(self.finer_margin)} on the finer mesh, error bound "
                   f"{_pct(self.margin_error)})" if self.weakest else "only one k")
        if not self.resolved:
            return f"not resolved: on the finer mesh the rule picks k = {self.finer_chosen_k}; {numbers}"
        if math.isfinite(self.margin) and self.margin < self.margin_error:
            return f"marginal: the finer mesh picks the same k, but {numbers}"
        return f"resolved: the finer mesh picks the same k; {numbers}"


#: A decision's margin error bound over the change of its margin from the run's mesh to the
#: finer one: for a quantity converging like h^p the error on the coarser mesh is the change
#: times 2^p / (2^p − 1), at most 2 for p ≥ 1. So a decision is resolved when the finer
#: mesh keeps its margin within half to one and a half times the run mesh's.
ERROR_BOUND = 2.0


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %" if math.isfinite(x) else "-"


def _signed(x: float) -> str:
    return f"{100 * x:+.1f} %" if math.isfinite(x) else "-"


def decisions(ks: Sequence[int], metrics: Sequence[float], plateau_tol: float) -> list[tuple[int, int, float]]:
    """The comparisons behind :func:`choose_k`'s answer, each as ``(k, k', margin)``: the
    relative change of the ratio of the two metrics that would flip it. The chosen k holds
    against every larger k' by (1 + tol)·m(k)/m(k') − 1; each smaller k is left because a
    larger k' (the best one) beats it by m(k')/((1 + tol)·m(k)) − 1. Empty with fewer than
    two valid k."""
    pairs = sorted((k, m) for k, m in zip(ks, metrics) if m is not None and math.isfinite(m) and m > 0)
    chosen = choose_k([k for k, _ in pairs], [m for _, m in pairs], plateau_tol)
    if chosen is None or len(pairs) < 2:
        return []
    metric = dict(pairs)
    out = [(chosen, k, _margin(chosen, k, metric, chosen, plateau_tol)) for k, _ in pairs if k > chosen]
    for k, _ in pairs:
        if k < chosen:
            best = max((pair for pair in pairs if pair[0] > k), key=lambda pair: pair[1])[0]
            out.append((k, best, _margin(k, best, metric, chosen, plateau_tol)))
    return out


def _margin(k: int, other: int, metric: dict, chosen: int, plateau_tol: float) -> float:
    """The margin of :func:`decisions`' decision between ``k`` and ``other`` on the metrics
    ``metric`` (``{k: m}``): the chosen k held against a larger one, or a smaller k left
    for a larger one."""
    if k == chosen:
        return (1 + plateau_tol) * metric[k] / metric[other] - 1
    return metric[other] / ((1 + plateau_tol) * metric[k]) - 1


def decision_margin(ks: Sequence[int], metrics: Sequence[float], plateau_tol: float) -> float:
    """The smallest margin of :func:`decisions` (NaN with fewer than two valid k)."""
    margins = [margin for _, _, margin in decisions(ks, metrics, plateau_tol)]
    return float(min(margins)) if margins else math.nan


def choose_k(ks: Sequence[int], metrics: Sequence[float], plateau_tol: float) -> int | None:
    """The smallest k beyond which the metric no longer grows by more than ``plateau_tol``.

    Among the k whose metric is finite (k without a successful run are skipped), returns
    the smallest k such that every larger k' has ``m(k') ≤ (1 + plateau_tol) · m(k)``.
    Comparing with *every* larger k, not only the next, keeps a flat step in a rising
    curve from stopping the search early; looking only for gains makes drops after the
    plateau (more capacitors, each smaller, noisier optimisation) harmless. The largest
    valid k always qualifies, so the result is ``None`` only if no metric is finite.
    """
    pairs = sorted((k, m) for k, m in zip(ks, metrics) if m is not None and math.isfinite(m))
    for i, (k, m) in enumerate(pairs):
        if all(later <= (1.0 + plateau_tol) * m for _, later in pairs[i + 1:]):
            return k
    return None


def run_score(run, by_bound: bool) -> float:
    """What select() ranks a k's runs by, larger is better: the precision 1/bound (read-back
    scenes) or the min L1 distance; NaN without one."""
    if not by_bound:
        return run.metric
    return 1.0 / run.bound_mm if run.bound_mm > 0 else math.nan


def rank_key(run, by_bound: bool) -> tuple[float, str]:
    """select()'s order of a k's runs, best first: the larger :func:`run_score`, ties to the
    smaller id."""
    return -run_score(run, by_bound), run.id


def ranked(runs: Iterable[RunSummary]) -> tuple[bool, dict[int, list[RunSummary]]]:
    """Whether the runs are ranked by their read-back bound (every one that can be a k's
    best carries a finite one) and, per k, those runs best first (:func:`rank_key`): the
    successful runs with a finite metric. A pruned run has a design but was stopped as
    dominated, unfinished and unchecked: it never is the best of its k."""
    good = [r for r in runs if r.ok and not r.pruned and math.isfinite(r.metric)]
    by_bound = bool(good) and all(math.isfinite(r.bound_mm) and r.bound_mm > 0 for r in good)
    contenders: dict[int, list[RunSummary]] = {}
    for r in sorted(good, key=lambda r: rank_key(r, by_bound)):
        contenders.setdefault(r.k, []).append(r)
    return by_bound, contenders


def select(runs: Iterable[RunSummary], plateau_tol: float, k_values: Iterable[int] = (),
           calibrated: Iterable[CalibratedDesign] = ()) -> Selection:
    """Best run per k (largest metric among the finished runs, pruned ones left out; ties go
    to the smallest id) and the chosen k.

    When every successful run carries a finite read-back bound (design poses from the
    calibration family, :mod:`mscap.design.readback`), the best run per k is the one with the
    smallest bound and the plateau rule runs on its precision 1/bound: the smallest k
    that no larger k beats by more than ``plateau_tol``. ``k_values`` adds rows for k
    without any run (e.g. the scene's ``k_min..k_max``).

    With ``calibrated`` designs (:mod:`mscap.service.calibrated`) the best design of each k
    is its calibrated design of least error (final or initial layout of a stored run; the
    scene's layout is a baseline, never chosen) and the same plateau rule runs on the
    precision 1/error (:func:`by_calibration`).
    """
    runs = list(runs)
    ks = sorted(set(k_values) | {r.k for r in runs})
    by_bound, contenders = ranked(runs)
    score = lambda r: run_score(r, by_bound)  # noqa: E731
    per_k = []
    for k in ks:
        mine = [r for r in runs if r.k == k]
        best = contenders[k][0] if k in contenders else None
        done = sum(r.ok for r in mine)
        per_k.append(KSummary(k=k, runs_ok=done, runs_failed=len(mine) - done,
                              best_metric=None if best is None else best.metric,
                              best_run=None if best is None else best.id,
                              wall_s=float(sum(r.wall_s for r in mine)),
                              best_bound_mm=None if best is None or not by_bound else best.bound_mm,
                              runs_pruned=sum(r.pruned for r in mine)))
    best_of = {k: contenders[k][0] for k in ks if k in contenders}
    chosen = choose_k(list(best_of), [score(r) for r in best_of.values()], plateau_tol)
    chosen_run = next((s.best_run for s in per_k if s.k == chosen), None)
    valid = [s.k for s in per_k if s.best_run is not None]
    # The same rule on the finer mesh's metrics (or precisions 1/bound) of the same runs: is
    # the answer resolved?
    value, finer_value = ((lambda r: r.bound_mm), (lambda r: r.finer_bound_mm)) if by_bound else \
        ((lambda r: r.metric), (lambda r: r.finer_metric))
    checked = bool(best_of) and all(math.isfinite(finer_value(r)) and finer_value(r) > 0 for r in best_of.values())
    # The finer mesh's scores, as ``score`` reads the run mesh's (precision 1/bound, or the metric).
    finer = [(1.0 / finer_value(r) if by_bound else finer_value(r)) if checked else math.nan
             for r in best_of.values()]
    finer_chosen = choose_k(list(best_of), finer, plateau_tol) if checked else None
    error_of = {k: abs(value(r) - finer_value(r)) / finer_value(r) if checked else math.nan
                for k, r in best_of.items()}
    # Each decision on the finer mesh's metrics of the same runs; its change is its error.
    finer_of = dict(zip(best_of, finer))
    compared = []
    for k, other, held in decisions(list(best_of), [score(r) for r in best_of.values()], plateau_tol):
        finer_held = _margin(k, other, finer_of, chosen, plateau_tol) if checked else math.nan
        compared.append((k, other, held, finer_held, ERROR_BOUND * abs(held - finer_held)))
    # The weakest decision: the least margin left over its error (or the least margin, unchecked).
    weakest = min(compared, key=lambda d: d[2] - d[4] if checked else d[2], default=None)
    base = Selection(per_k=tuple(per_k), chosen_k=chosen, chosen_run=chosen_run, plateau_tol=plateau_tol,
                     objective_k=chosen, objective_design=chosen_run,
                     plateau_reached=chosen is not None and chosen < max(valid), runs_total=len(runs),
                     by_bound=by_bound, finer_chosen_k=finer_chosen,
                     metric_error=max(error_of.values()) if checked else math.nan,
                     weakest=None if weakest is None else weakest[:2],
                     margin=math.nan if weakest is None else weakest[2],
                     finer_margin=math.nan if weakest is None else weakest[3],
                     margin_error=math.nan if weakest is None else weakest[4])
    return by_calibration(base, calibrated, runs)


def by_calibration(base: Selection, calibrated: Iterable[CalibratedDesign], runs: Iterable[RunSummary]) -> Selection:
    """``base`` (the objective's selection) chosen again on calibrated read-back error:
    per k the calibrated design of least error among the layouts of the successful,
    unpruned ``runs`` (ties to the smaller label), and k by :func:`choose_k` on the
    precision 1/error; the selection keeps those designs and the scene layout's baseline.
    ``base`` itself when no such design has a finite error."""
    calibrated = tuple(calibrated)
    good = {r.id for r in runs if r.ok and not r.pruned}
    eligible = [d for d in calibrated if d.run_id in good and math.isfinite(d.error_mm) and d.error_mm > 0]
    if not eligible:
        return base
    best: dict[int, CalibratedDesign] = {}
    for d in sorted(eligible, key=lambda d: (d.error_mm, d.label)):
        best.setdefault(d.k, d)
    ks = sorted(best)
    chosen = choose_k(ks, [1.0 / best[k].error_mm for k in ks], base.plateau_tol)
    per_k = tuple(replace(s, best_design=best[s.k].label, best_error_mm=best[s.k].error_mm) if s.k in best else s
                  for s in base.per_k)
    baselines = tuple(d for d in calibrated if d.which == "scene")
    return replace(base, per_k=per_k, chosen_k=chosen, chosen_run=best[chosen].run_id, design=best[chosen].label,
                   plateau_reached=chosen < max(ks), calibrated=tuple(eligible) + baselines)
