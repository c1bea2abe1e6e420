"""The single-start layout optimiser (paper §5.1): L-BFGS on J(q) with a feasible line
search, remeshing and a cascade of control refinements.

One iteration: the two-loop recursion gives a direction ``p`` (steepest descent when the
memory is empty or ``p`` is not a descent direction; the first step of a memory moves the
fastest control ``first_step_mm``); the step is capped so that no control moves more than
``max_step_mm``, no outline comes closer to another (or to the sheet edge) than allowed
(:meth:`~mscap.design.objective.SeparationBarrier.max_step`, which keeps every gap above a tenth
of its current value) and no triangle of the electrostatic or the elastic 2D mesh keeps
less than a tenth of its area (:func:`mscap.design.feasibility.max_step_triangles`, exact: the area is quadratic
in the step). Backtracking (Armijo) from that cap; a trial whose elastic or electrostatic
solve fails is halved like one that does not decrease J, and one whose outline terms
alone rise beyond what the capacitances can gain is halved without being simulated
(``screen_trials``, :data:`SCREEN_FACTOR`). Accepted iterates are therefore never
overlapping, outside the sheet or inverted.

After each accepted step the minimum 2D angle of both meshes is checked; below
``remesh_angle_deg`` or below half the freshly meshed minimum, whichever is smaller (gmsh
itself makes 9° angles on the default poking mesh, so 10° alone would remesh at every
step), the sheet is remeshed from the current
outlines (:func:`mscap.design.remesh.remesh`) and each pose's displacement is interpolated onto the new elastic
mesh for the warm start. The L-BFGS memory is kept (``keep_memory_at_remesh``): the
controls keep their number and order per outline and the design is the same, so the
curvature pairs still describe J; restarting it cost the wrist 10 % of its bound
(docs/optimize.md, "Remeshing keeps the L-BFGS memory"). On convergence (relative J
change in a step or over the last ``stall_window`` steps on one mesh, or gradient norm,
per level) the controls double (:meth:`Design.refined`) for ``cascade_levels`` more levels.

A plate that reads nothing gets no gradient; at the start and when a level converges such
a plate moves to where the design poses strain the sheet in a way the others do not read,
if J falls (``[optimizer] revive_silent``, :mod:`mscap.design.revival`; event ``revive``).

With ``[fabrication] route_during_optimisation`` the leads are routed at the start, after
every remesh and refinement, and at the end (:meth:`Design.rerouted`); the evaluation there
takes the new leads' share without a new solve (:meth:`Design.reevaluated`), and each
re-route is kept in :attr:`OptimizeResult.reroutes`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from mscap.design.feasibility import feasible_step
from mscap.design.history import Record
from mscap.design.pipeline import Design, DesignError, Evaluation, build_design
from mscap.design.remesh import control_counts, min_angle, needs_remesh, remesh, size_ratio
from mscap.design.revival import revival
from mscap.design.state import OptimizerState
from mscap.errors import GeometryError, InvertedMeshError, MeshError
from mscap.fem.elastic.problem import ElasticError
from mscap.fem.electrostatic import ElectrostaticError
from mscap.fem.petsc import LinearSolveError
from mscap.fem.simulate import release_freed_memory
from mscap.geometry.layout import Layout, min_gap_mm

__all__ = ["OptimizeResult", "optimize", "resumed_design"]

log = logging.getLogger(__name__)

#: An accepted step whose line search had this many trials fail on inverted electrostatic
#: tets was cut at least 8x by the mesh, not by J: the sheet is remeshed after it
#: (wrist_quick: steps of 0.003-0.03 mm against 0.2-0.7 mm before, docs/optimize.md).
MESH_LIMITED = 3

#: A line-search trial is rejected before it is simulated when its outline terms alone
#: (barrier, smoothing) rise by more than this many times the first-order gain of the
#: capacitance term d along the step, plus Armijo's margin: J = −d + outline terms could
#: then only fall enough if d gained more than twice its linear prediction. On a paper
#: poking start (30 steps) 20 of the 21 rejected trials had their outline terms rise by
#: 2.2–555 times the step's whole predicted decrease, the accepted ones by at most 1.2
#: times (docs/optimize.md, "Screening line-search trials"). ``[optimizer] screen_trials``.
SCREEN_FACTOR = 2.0

#: Failures of a trial design that mean "step too long", not "bug".
_TRIAL_ERRORS = (ElasticError, ElectrostaticError, GeometryError, LinearSolveError, MeshError)


@dataclass(frozen=True)
class OptimizeResult:
    """The final design and evaluation (``q`` of the last level), the first evaluation,
    the history and why it stopped."""

    design: Design
    evaluation: Evaluation
    initial: Evaluation
    history: tuple[Record, ...]
    iterations: int
    reason: str
    time_s: float
    #: Each re-route of the leads (``[fabrication] route_during_optimisation``):
    #: :class:`mscap.fabrication.during.Reroute`.
    reroutes: tuple = ()

    @property
    def layout(self) -> Layout:
        return self.design.deformer.layout(self.evaluation.q)


class _LBFGS:
    """Two-loop recursion over flattened vectors."""

    def __init__(self, size: int = 8):
        self.size, self.pairs = size, []

    def reset(self):
        self.pairs = []

    def push(self, s: np.ndarray, y: np.ndarray):
        if float(s @ y) > 1e-12 * float(np.linalg.norm(s) * np.linalg.norm(y)):
            self.pairs = (self.pairs + [(s, y)])[-self.size:]

    def direction(self, g: np.ndarray) -> np.ndarray:
        q = g.copy()
        alphas = []
        for s, y in reversed(self.pairs):
            a = (s @ q) / (y @ s)
            alphas.append(a)
            q -= a * y
        if self.pairs:
            s, y = self.pairs[-1]
            q *= (s @ y) / (y @ y)
        for (s, y), a in zip(self.pairs, reversed(alphas)):
            b = (y @ q) / (y @ s)
            q += (a - b) * s
        return -q


def optimize(design: Design, q0=None, progress: Callable[[str], None] | None = None,
             max_iterations: int | None = None, cascade_levels: int | None = None,
             checkpoint: Callable[[Record], bool] | None = None,
             keep: Callable[[Callable[[], OptimizerState]], None] | None = None,
             resume: OptimizerState | None = None) -> OptimizeResult:
    """Minimise J from ``q0`` (default 0) of ``design``; settings from the scene's
    ``[optimizer]`` (``max_iterations`` per level, ``cascade_levels`` refinements).
    After every accepted step ``checkpoint(its history record)`` may return ``False`` to
    stop here (reason ``"pruned"``, :mod:`mscap.service.pruning`).

    At the top of every iteration ``keep(state)`` is called with a function that makes the
    :class:`~mscap.design.state.OptimizerState` there (made only if called: the caller
    decides when a state is worth writing). ``resume``: go on from such a state;
    ``design`` must then be :func:`resumed_design` of it (``q0`` is ignored), and the
    other arguments those of the stopped call.

    An exception leaves with the history up to it as its ``history`` attribute (a tuple
    of records), so that a failed start keeps what it did (:func:`mscap.service.schema.failed_record`)."""
    history: list[Record] = [] if resume is None else list(resume.history)
    try:
        return _optimize(design, q0, progress, max_iterations, cascade_levels, checkpoint, history, keep, resume)
    except Exception as exc:
        exc.history = tuple(history)
        raise


def resumed_design(scene, sheet, state: OptimizerState, designed=None) -> Design:
    """The design of ``state`` rebuilt: ``sheet`` (the start's: its mesh sizes hold for the
    whole start) meshed from the state's layout with its control counts (``designed``: the
    design poses, default the scene's), then each control refinement of its cascade
    replayed. A state whose arrays do not fit that design raises ``ValueError``."""
    design = build_design(scene, sheet=replace(sheet, layout=Layout(tuple(state.outlines))), count=state.counts,
                          poses=designed)
    for q in state.cascades:
        _fits(state, "a refinement's q", q.shape, design.deformer.zeros().shape)
        design = design.refined(q)
    _fits(state, "q", state.q.shape, design.deformer.zeros().shape)
    _fits(state, "the equilibria", len(state.displacements), len(design.poses))
    nodes = None if design.base.elastic is None else design.base.elastic.rest.shape
    for u in state.displacements:
        _fits(state, "an equilibrium", None if u is None else u.shape, nodes)
    for s_, y_ in state.memory:
        _fits(state, "the L-BFGS memory", (s_.size, y_.size), (state.q.size, state.q.size))
    return design


def _fits(state, what: str, shape, expected) -> None:
    """Refuse a state that is not of the design rebuilt from it (another scene's, damaged)."""
    if shape != expected and shape is not None:
        raise ValueError(f"{what} has shape {shape}; the design rebuilt from the state has {expected}")


def _optimize(design: Design, q0, progress, max_iterations, cascade_levels, checkpoint,
              history: list[Record], keep=None, resume: OptimizerState | None = None) -> OptimizeResult:
    """:func:`optimize`, appending to ``history`` as it goes."""
    say = progress or (lambda message: None)
    settings = design.scene.optimizer
    max_iterations = settings.max_iterations if max_iterations is None else max_iterations
    cascade_levels = settings.cascade_levels if cascade_levels is None else cascade_levels
    started = time.perf_counter() - (resume.time_s if resume is not None else 0.0)
    q = design.deformer.zeros() if q0 is None else np.array(q0, dtype=float)
    level, iteration, level_iterations, reason = 0, 0, 0, ""
    routed, reroutes = design.scene.fabrication.route_during_optimisation, []
    # How the current design was made (mscap.design.state): the sheet last meshed, the control
    # counts of that build (None: the scene's spacing) and the q of each refinement since.
    lineage = (design.sheet, None, [])
    if resume is not None:
        q = resume.q
        lineage = (replace(design.sheet, layout=Layout(tuple(resume.outlines))), resume.counts,
                   list(resume.cascades))
    e = design.evaluate(q, warm=None if resume is None else list(resume.displacements))

    def reroute(event):  # the leads routed again at e.q; e re-evaluated with their share, no solve
        nonlocal design, e
        if not routed:
            return
        new = design.rerouted(e.q, say)
        if new is design:
            return
        from mscap.fabrication.during import Reroute

        before, old = e.J, e.offset_pF
        design = new
        e = design.reevaluated(e)
        change = float(np.abs(e.offset_pF - (0.0 if old is None else old)).max())
        reroutes.append(Reroute(event, iteration, change, before, e.J, design.wiring.summary, design.wiring.time_s))
        say(f"rerouted ({event}): the leads' share moved by up to {change:.3g} pF; J {before:+.6e} -> {e.J:+.6e}")

    if resume is None:
        reroute("start")
    g = _gradient(design, e)
    initial = e.detached(keep_elastic=True)
    memory = _LBFGS()
    level_gradient = float(np.linalg.norm(g))
    fresh = min_angle(design, q)
    step_length = settings.first_step_mm
    revived_at = set()  # the levels whose end has tried a revival
    if resume is not None:
        initial = replace(initial, q=resume.initial_q, J=resume.initial_J, terms=dict(resume.initial_terms),
                          capacitance_pF=resume.initial_capacitance_pF, dJ_dC=None, offset_pF=None,
                          error_J=float("nan"), margin_error_pF=float("nan"))
        memory.pairs = [(np.array(s_), np.array(y_)) for s_, y_ in resume.memory]
        level_gradient, fresh, step_length = resume.level_gradient, tuple(resume.fresh), resume.step_length
        level, iteration, level_iterations, reason = (resume.level, resume.iteration, resume.level_iterations,
                                                      resume.reason)
        revived_at = set(resume.revived_at)

    def state() -> OptimizerState:  # the optimiser here, at the top of an iteration
        sheet, counts, cascades = lineage
        return OptimizerState(
            tuple(np.array(o) for o in sheet.layout.outlines), None if counts is None else np.array(counts),
            tuple(np.array(c) for c in cascades), np.array(e.q), tuple(e.displacements()),
            tuple((np.array(s_), np.array(y_)) for s_, y_ in memory.pairs), step_length, level, iteration,
            level_iterations, reason, level_gradient, tuple(fresh), tuple(sorted(revived_at)), tuple(history),
            np.array(initial.q), initial.J, dict(initial.terms), np.array(initial.capacitance_pF),
            time.perf_counter() - started)

    def record(event, step=0.0, evaluations=1):  # evaluations of this event
        angle = min_angle(design, e.q)[0]
        r = Record(iteration, level, e.J, dict(e.terms), float(np.linalg.norm(g)), step,
                   e.min_l1_pF, event, evaluations, int(sum(e.newton_iterations)), angle,
                   min_gap_mm(design.deformer.outlines(e.q), design.scene.sheet_outline_mm),
                   time.perf_counter() - started, size_ratio(design, e.q), e.error_J, e.margin_error_pF)
        history.append(r)
        terms = " ".join(f"{name} {value:.4g}" for name, value in e.terms.items())
        say(f"it {iteration:3d} L{level} {event:<9} J {e.J:+.6e} {terms} |g| {r.grad_norm:.3e} "
            f"step {step:.3g} mm minL1 {e.min_l1_pF:.4g} pF "
            f"evals {evaluations} newton {r.newton_iterations} angle {angle:.1f} gap {r.min_gap_mm:.3g} mm "
            f"mem {len(memory.pairs)} "
            f"t {r.time_s:.1f} s")

    def remesh_here(evaluations=1):  # evaluations: the rejected trials that led here, and this one
        nonlocal design, e, g, fresh, step_length, lineage
        counts = control_counts(design)
        new, warm = remesh(design, e)
        lineage = (new.sheet, counts, [])
        e.release()
        # Free the old design's solvers, meshes and skinning weights (and the old
        # evaluation's moved meshes) before the new design's first evaluation, not after:
        # alive beside it they were the whole-start peak (biaxial, k = 6: 944 → 701 MB).
        design.close()
        design, e = new, None
        del new
        release_freed_memory()
        e = design.evaluate(design.deformer.zeros(), warm=warm)
        reroute("remesh")
        g = _gradient(design, e)
        if not settings.keep_memory_at_remesh:
            memory.reset()
            step_length = settings.first_step_mm
        fresh = min_angle(design, e.q)
        record("remesh", evaluations=evaluations)  # the plateau window restarts: J on a new mesh differs by its error

    def revive_here() -> bool:
        """Move the plates that read nothing to where they would (mscap.design.revival),
        if J falls; whether it did."""
        nonlocal design, e, g, fresh, step_length, lineage
        found = revival(design, e) if settings.revive_silent else None
        if found is None:
            return False
        moved, outlines = found
        design.close()  # its solvers: the trial design makes its own; they come back if it is refused
        new = None
        try:
            new, warm = remesh(design, e, outlines)
            trial = new.evaluate(new.deformer.zeros(), warm=warm)
        except _TRIAL_ERRORS as exc:
            if new is not None:
                new.close()
            say(f"revival of plate(s) {', '.join(map(str, moved.plates))} failed ({exc}); kept where they are")
            return False
        plates = ", ".join(f"{j} to ({o[:, 0].mean():.1f}, {o[:, 1].mean():.1f}) mm"
                           for j, o in zip(moved.plates, moved.outlines))
        if not trial.J < e.J:
            trial.release()
            new.close()
            say(f"silent plate(s) {plates} would raise J {e.J:+.6e} -> {trial.J:+.6e}; kept where they are")
            return False
        say(f"revived silent plate(s) {plates}: J {e.J:+.6e} -> {trial.J:+.6e}")
        lineage = (new.sheet, control_counts(design), [])
        e.release()
        design, e = new, trial
        reroute("revival")
        g = _gradient(design, e)
        memory.reset()
        step_length = settings.first_step_mm
        fresh = min_angle(design, e.q)
        record("revive")
        return True

    if resume is None:
        record("start")
    try:
        if resume is None:
            revive_here()
        while True:
            if keep is not None:
                keep(state)
            converged = level_iterations >= max_iterations
            reason = "max_iterations" if converged else reason
            if not converged:
                flat_g = g.ravel()
                p = memory.direction(flat_g)
                if not p @ flat_g < 0:
                    memory.reset()
                    p = -flat_g
                p = p.reshape(-1, 2)
                speed = float(np.linalg.norm(p, axis=1).max())
                if speed == 0:
                    converged, reason = True, "zero gradient"
                else:
                    if not memory.pairs:  # steepest descent: the last good step length, doubled
                        p *= step_length / speed
                        speed = step_length
                    cap = min(1.0, settings.max_step_mm / speed)
                    search = dict(screen=settings.screen_trials, resolve=settings.resolve_steps)
                    trial, alpha, tries, evaluations, inverted, unresolved = _line_search(design, e, g, p, cap,
                                                                                          **search)
                    if trial is None and memory.pairs:
                        memory.reset()
                        p = -g * (settings.first_step_mm / float(np.linalg.norm(g, axis=1).max()))
                        trial, alpha, more_tries, more, more_inverted, unresolved = _line_search(design, e, g, p,
                                                                                                 1.0, **search)
                        tries += more_tries
                        evaluations += more
                        inverted += more_inverted
                    if trial is None and inverted and history[-1].event != "remesh":
                        # The deformed electrostatic mesh, not the design, stopped every trial.
                        log.info("line search: %d of %d trials inverted the electrostatic mesh; remeshing",
                                 inverted, evaluations)
                        remesh_here(evaluations + 1)
                    elif trial is None:
                        # Every trial that lowered J raised its error bound more: the rest is unresolved.
                        converged, reason = True, "resolved" if unresolved else "stalled"
                    else:
                        # Free the current point's factorisations before the trial's gradient makes
                        # its own: one set alive, not two (poking_quick's P2 worker: see _gradient).
                        e.release()
                        g_new = _gradient(design, trial)
                        memory.push((trial.q - e.q).ravel(), (g_new - g).ravel())
                        change = e.J - trial.J
                        e, g = trial, g_new
                        iteration += 1
                        level_iterations += 1
                        step = alpha * float(np.linalg.norm(p, axis=1).max())
                        step_length = min(settings.max_step_mm, 2 * step if tries == 1 else step)
                        record("step", step, evaluations)
                        if checkpoint is not None and not checkpoint(history[-1]):
                            converged, reason = True, "pruned"
                        elif (change <= settings.relative_tolerance * max(abs(e.J), 1.0)
                                or np.linalg.norm(g) <= settings.gradient_tolerance * level_gradient
                                or _plateau(_on_this_mesh(history), e.J, settings.stall_window,
                                            settings.stall_tolerance)):
                            converged, reason = True, "converged"
                        elif inverted >= MESH_LIMITED or needs_remesh(design, e.q, fresh, settings.remesh_angle_deg):
                            trial = None  # the only other reference to e: the remesh frees it
                            remesh_here()
            if not converged:
                continue
            if reason in ("converged", "stalled", "resolved") and level not in revived_at:
                revived_at.add(level)
                if revive_here():
                    level_iterations, reason = 0, ""  # the moved plate gets the level's steps
                    continue
            if level >= cascade_levels or reason in ("zero gradient", "pruned"):
                reroute("end")
                record(reason)
                break
            lineage[2].append(np.array(e.q))
            design = design.refined(e.q)
            e.release()  # another mesh: its equilibria (kept) start the refined one, not its factorisations
            e = design.evaluate(design.deformer.zeros(), warm=e)
            reroute("cascade")
            g = _gradient(design, e)
            memory.reset()
            level += 1
            level_iterations = 0
            level_gradient = float(np.linalg.norm(g))
            fresh = min_angle(design, e.q)
            step_length = settings.first_step_mm
            record("cascade")
    except BaseException as exc:  # free the current design's solvers; a non-finite value: say where
        if e is not None:
            e.release()
        design.close()
        if isinstance(exc, DesignError):
            raise DesignError(f"iteration {iteration + 1} (level {level}): {exc}") from exc
        raise
    e.release()
    return OptimizeResult(design, e, initial, tuple(history), iteration, reason, time.perf_counter() - started,
                          tuple(reroutes))


def _on_this_mesh(history: list[Record]) -> list[float]:
    """J after each accepted step since the level's start, the last remesh or cascade
    (their records hold the J they started from)."""
    last = max(i for i, r in enumerate(history) if r.event != "step")
    return [r.J for r in history[last:]]


def _plateau(values: list[float], J: float, window: int, tolerance: float) -> bool:
    """Whether J (the last of ``values``, J after each accepted step on one mesh) has
    fallen by less than ``tolerance`` · |J| over the last ``window`` steps (``window`` 0:
    never). Relative to |J| alone, unlike the one-step rule's max(|J|, 1): a read-back
    design's J is a bound of a few tenths of a millimetre."""
    if window <= 0 or len(values) <= window:
        return False
    return values[-1 - window] - J <= tolerance * abs(J)


def _gradient(design: Design, e: Evaluation) -> np.ndarray:
    """dJ/dq at ``e``, then ``e``'s fields are released (only its values and
    displacements are used from here on) and the elastic factorisations its gradient made
    are kept: the line search's trials start from them as modified Newton
    (:meth:`Evaluation.factorisations`; 3.4× less CPU per warm evaluation on poking_quick's
    P2), until ``e`` is left. Trials factorise nothing to keep (an accepted one's gradient
    does, after ``e`` is released), so one set of factorisations is alive at a time."""
    g = design.gradient(e)
    e.release(keep_elastic=True)
    return g


def _line_search(design: Design, e: Evaluation, g: np.ndarray, p: np.ndarray, alpha: float,
                 screen: bool = False, resolve: bool = False,
                 max_trials: int = 8) -> tuple[Evaluation | None, float, int, int, int, int]:
    """Backtracking (Armijo, halving) from the largest feasible ``α ≤ alpha``; returns the
    accepted evaluation (or ``None``), α, the trials (the accepted one's number, else
    ``max_trials``), the evaluations among them, how many of those failed on inverted
    electrostatic tets and how many lowered J but not J + δJ. With ``screen``, a trial
    whose outline terms rise by more than :data:`SCREEN_FACTOR` times the first-order
    gain of d is halved without being evaluated; the α tried next is the same either way.
    With ``resolve``, the sufficient decrease is asked of J + δJ (the evaluation's
    error bound, :mod:`mscap.design.resolution`) as well as of J. (Retries at the
    minimiser of a quadratic model of J were measured and dropped: docs/optimize.md.)"""
    alpha = feasible_step(design, e.q, p, alpha)
    slope = float(np.vdot(g, p))
    if screen:
        geometry = design.objective.geometry
        before = e.J - design.objective.capacitance_value(e.terms)  # the outline terms' part of J
        # g = ∇(capacitance terms) + ∇(outline terms): the capacitance terms' first-order gain per
        # unit α is ∇(outline terms)·p − g·p.
        gain = max(float(np.vdot(design.outline_gradient(e.q), p)) - slope, 0.0)
    inverted = evaluations = unresolved = 0
    for trial in range(1, max_trials + 1):
        q = e.q + alpha * p
        if screen:
            try:
                rise = geometry.value(design.deformer.outlines(q)) - before
            except _TRIAL_ERRORS:  # the evaluation below says why, as without screening
                rise = -np.inf
            if not rise - 1e-4 * alpha * slope <= SCREEN_FACTOR * alpha * gain:
                log.info("line search: α = %.3g screened out (outline terms +%.3g, d gains ~%.3g); halving",
                         alpha, rise, alpha * gain)
                alpha *= 0.5
                continue
        evaluations += 1
        try:
            candidate = design.evaluate(q, warm=e)
        except _TRIAL_ERRORS as exc:
            log.info("line search: α = %.3g failed (%s); halving", alpha, exc)
            inverted += isinstance(exc, InvertedMeshError)
            alpha *= 0.5
            continue
        decrease = candidate.J <= e.J + 1e-4 * alpha * slope
        if decrease and resolve and not candidate.J + candidate.error_J <= e.J + e.error_J + 1e-4 * alpha * slope:
            log.info("line search: α = %.3g lowers J by %.3g but its error bound grows by %.3g; halving", alpha,
                     e.J - candidate.J, candidate.error_J - e.error_J)
            unresolved += 1
            decrease = False
        if decrease:
            return candidate, alpha, trial, evaluations, inverted, unresolved
        candidate.release()
        alpha *= 0.5
    return None, 0.0, max_trials, evaluations, inverted, unresolved
