"""The single-start layout optimiser (paper §5.1): L-BFGS on J(q) with a feasible line
search, remeshing and a cascade of control refinements.

One iteration: the two-loop recursion gives a direction ``p`` (steepest descent when the
memory is empty or ``p`` is not a descent direction; the first step of a memory moves the
fastest control ``first_step_mm``); the step is capped so that no control moves more than
``max_step_mm``, no outline comes closer to another (or to the sheet edge) than allowed
(:meth:`~mscap.design.objective.SeparationBarrier.max_step`, which keeps every gap above a tenth
of its current value) and no triangle of the electrostatic or the elastic 2D mesh keeps
less than a tenth of its area (:func:`max_step_triangles`, exact: the area is quadratic
in the step). Backtracking (Armijo) from that cap; a trial whose elastic or electrostatic
solve fails is halved like one that does not decrease J. Accepted iterates are therefore
never overlapping, outside the sheet or inverted.

After each accepted step the minimum 2D angle of both meshes is checked; below
``remesh_angle_deg`` or below half the freshly meshed minimum, whichever is smaller (gmsh
itself makes 9° angles on the default poking mesh, so 10° alone would remesh at every
step), the sheet is remeshed from the current
outlines (:func:`remesh`), each pose's displacement is interpolated onto the new elastic
mesh for the warm start, and the L-BFGS memory restarts. On convergence (relative J
change or gradient norm, per level) the controls double (:meth:`Design.refined`) for
``cascade_levels`` more levels.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from mscap.design.pipeline import Design, DesignError, Evaluation, build_design
from mscap.fem.elastic.problem import ElasticError
from mscap.fem.electrostatic import ElectrostaticError
from mscap.errors import GeometryError, MeshError
from mscap.geometry.layout import Layout, check_layout, min_gap_mm
from mscap.design.objective import layout_objective
from mscap.fem.petsc import LinearSolveError
from mscap.mesh.quality import triangle_angles_deg
from mscap.mesh.transfer import interpolation_matrix
from mscap.design.history import HISTORY_FIELDS, Record

__all__ = ["OptimizeResult", "optimize", "feasible_step", "max_step_triangles",
           "remesh", "resample_outline"]

log = logging.getLogger(__name__)

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

    @property
    def layout(self) -> Layout:
        return self.design.deformer.layout(self.evaluation.q)


def max_step_triangles(points: np.ndarray, triangles: np.ndarray, directions: np.ndarray,
                       keep: float = 0.1) -> float:
    """Largest α ∈ [0, 1] such that along ``points + α directions`` every triangle keeps
    at least ``keep`` of its (positive) signed area. The area is ``A0 + α A1 + α² A2``; the
    bound is the smallest positive root of ``A(α) = keep A0`` (exact, vectorised)."""
    p, v = points[triangles], directions[triangles]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    f1, f2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    cross = lambda a, b: a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]  # noqa: E731
    a0 = cross(e1, e2)
    a1 = cross(e1, f2) + cross(f1, e2)
    a2 = cross(f1, f2)
    c = (1.0 - keep) * a0  # solve a2 α² + a1 α + c = 0 for the first α > 0
    alpha = np.full(len(a0), np.inf)
    linear = np.abs(a2) <= 1e-14 * (np.abs(a1) + np.abs(a0))
    shrinking = linear & (a1 < 0)
    alpha[shrinking] = c[shrinking] / -a1[shrinking]
    quad = ~linear
    disc = a1[quad] ** 2 - 4 * a2[quad] * c[quad]
    roots = np.full(quad.sum(), np.inf)
    real = disc >= 0
    sq = np.sqrt(np.where(real, disc, 0.0))
    r1 = (-a1[quad] - sq) / (2 * a2[quad])
    r2 = (-a1[quad] + sq) / (2 * a2[quad])
    for r in (r1, r2):
        ok = real & (r > 0)
        roots[ok] = np.minimum(roots[ok], r[ok])
    alpha[quad] = roots
    return float(min(1.0, alpha.min(initial=np.inf)))


def _corners(polygon: np.ndarray, degrees: float) -> np.ndarray:
    before = polygon - np.roll(polygon, 1, axis=0)
    after = np.roll(polygon, -1, axis=0) - polygon
    cos = np.einsum("ij,ij->i", before, after) / (np.linalg.norm(before, axis=1) * np.linalg.norm(after, axis=1))
    return cos < np.cos(np.radians(degrees))


def resample_outline(polygon: np.ndarray, spacing_mm: float, corner_deg: float = 20.0) -> np.ndarray:
    """A closed polyline resampled at about ``spacing_mm`` along its arc, keeping the
    vertices where it turns by more than ``corner_deg`` (the plate corners)."""
    polygon = np.asarray(polygon, dtype=float)
    corner = np.flatnonzero(_corners(polygon, corner_deg))
    if not len(corner):
        corner = np.array([0])
    pieces = []
    for a, b in zip(corner, np.roll(corner, -1)):
        idx = np.arange(a, (b if b > a else b + len(polygon)) + 1) % len(polygon)
        chain = polygon[idx]
        seg = np.linalg.norm(np.diff(chain, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        n = max(1, int(np.ceil(arc[-1] / spacing_mm - 1e-9)))
        s = arc[-1] * np.arange(n) / n
        pieces.append(np.c_[np.interp(s, arc, chain[:, 0]), np.interp(s, arc, chain[:, 1])])
    return np.vstack(pieces)


def remesh(design: Design, evaluation: Evaluation) -> tuple[Design, list]:
    """A new design meshed from the outlines at ``evaluation.q`` (resampled at the
    scene's outline edge length, the same number of controls per outline) and each pose's
    displacement interpolated onto the new elastic mesh (the warm start)."""
    scene = design.scene
    # Polygon vertices about every half elastic outline edge: each vertex is also embedded
    # in the elastic mesh, so resampling at the fine outline spacing would refine the
    # elastic mesh to it (16× the elements on the poking scene). The chordal error of
    # 1.2 mm chords on a 10 mm radius is 0.02 mm. The chord is a whole number of fine
    # outline edges: gmsh splits each chord into ceil(chord / edge) pieces, and shorter
    # edges than the scene's would change the capacitance (by 4 % on a 1 mm mesh).
    elastic, edge = scene.elastic, scene.mesh.edge_length_outline_mm
    half = 0.5 * min(elastic.edge_length_outline_mm or 0.5 * elastic.edge_length_mm, elastic.edge_length_mm)
    spacing = edge * max(1, int(np.floor(half / edge + 1e-9)))
    outlines = tuple(resample_outline(o, spacing) for o in design.deformer.outlines(evaluation.q))
    layout = Layout(outlines)
    check_layout(layout, scene.sheet_outline_mm, scene.min_gap_mm)
    counts = np.bincount(design.deformer.control_outline, minlength=layout.k)
    new = build_design(scene, layout=layout, count=counts)
    warm = [None] * len(scene.poses)
    old = evaluation.sim.elastic
    if old is not None and new.base.elastic is not None:
        mapping = interpolation_matrix(old, new.base.elastic.rest)
        warm = [None if u is None else mapping @ u for u in evaluation.displacements()]
    return new, warm


def _min_angle(design: Design, q) -> tuple[float, float]:
    fine = design.deformer.points2d(q)
    angle_fine = float(triangle_angles_deg(fine, design.deformer.mesh2d.triangles).min())
    angle_el = np.inf
    if design.elastic_weights is not None:
        m = design.base.elastic.mesh.mesh2d
        el = m.points + design.elastic_weights @ design.deformer._q(q)
        angle_el = float(triangle_angles_deg(el, m.triangles).min())
    return angle_fine, angle_el


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
             max_iterations: int | None = None, cascade_levels: int | None = None) -> OptimizeResult:
    """Minimise J from ``q0`` (default 0) of ``design``; settings from the scene's
    ``[optimizer]`` (``max_iterations`` per level, ``cascade_levels`` refinements)."""
    say = progress or (lambda message: None)
    settings = design.scene.optimizer
    max_iterations = settings.max_iterations if max_iterations is None else max_iterations
    cascade_levels = settings.cascade_levels if cascade_levels is None else cascade_levels
    started = time.perf_counter()
    q = design.deformer.zeros() if q0 is None else np.array(q0, dtype=float)
    e = design.evaluate(q)
    initial = e
    g = _gradient(design, e)
    memory = _LBFGS()
    history: list[Record] = []
    level, iteration, level_iterations, reason = 0, 0, 0, ""
    level_gradient = float(np.linalg.norm(g))
    fresh = _min_angle(design, q)
    step_length = settings.first_step_mm

    def record(event, step=0.0, evaluations=1):  # evaluations of this event
        angle = _min_angle(design, e.q)[0]
        r = Record(iteration, level, e.J, e.d, e.barrier, e.smoothing, float(np.linalg.norm(g)), step,
                   e.min_l1_pF, event, evaluations, int(sum(e.newton_iterations)), angle,
                   min_gap_mm(design.deformer.outlines(e.q), design.scene.sheet_outline_mm),
                   time.perf_counter() - started)
        history.append(r)
        say(f"it {iteration:3d} L{level} {event:<9} J {e.J:+.6e} d {e.d:.5g} B {e.barrier:.3g} "
            f"S {e.smoothing:.3g} |g| {r.grad_norm:.3e} step {step:.3g} mm minL1 {e.min_l1_pF:.4g} pF "
            f"evals {evaluations} newton {r.newton_iterations} angle {angle:.1f} gap {r.min_gap_mm:.3g} mm "
            f"mem {len(memory.pairs)} "
            f"t {r.time_s:.1f} s")

    record("start")
    try:
        while True:
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
                    trial, alpha, evaluations = _line_search(design, e, g, p, cap)
                    if trial is None and memory.pairs:
                        memory.reset()
                        p = -g * (settings.first_step_mm / float(np.linalg.norm(g, axis=1).max()))
                        trial, alpha, more = _line_search(design, e, g, p, 1.0)
                        evaluations += more
                    if trial is None:
                        converged, reason = True, "stalled"
                    else:
                        g_new = _gradient(design, trial)
                        memory.push((trial.q - e.q).ravel(), (g_new - g).ravel())
                        change = e.J - trial.J
                        e, g = trial, g_new
                        iteration += 1
                        level_iterations += 1
                        step = alpha * float(np.linalg.norm(p, axis=1).max())
                        step_length = min(settings.max_step_mm, 2 * step if evaluations == 1 else step)
                        record("step", step, evaluations)
                        if (change <= settings.relative_tolerance * max(abs(e.J), 1.0)
                                or np.linalg.norm(g) <= settings.gradient_tolerance * level_gradient):
                            converged, reason = True, "converged"
                        elif _needs_remesh(design, e.q, fresh, settings.remesh_angle_deg):
                            design, warm = remesh(design, e)
                            e = design.evaluate(design.deformer.zeros(), warm=warm)
                            g = _gradient(design, e)
                            memory.reset()
                            fresh = _min_angle(design, e.q)
                            step_length = settings.first_step_mm
                            record("remesh")
            if not converged:
                continue
            if level >= cascade_levels or reason == "zero gradient":
                record(reason)
                break
            design = design.refined(e.q)
            e = design.evaluate(design.deformer.zeros(), warm=e)
            g = _gradient(design, e)
            memory.reset()
            level += 1
            level_iterations = 0
            level_gradient = float(np.linalg.norm(g))
            fresh = _min_angle(design, e.q)
            step_length = settings.first_step_mm
            record("cascade")
    except DesignError as exc:  # a non-finite value: stop, naming where
        raise DesignError(f"iteration {iteration + 1} (level {level}): {exc}") from exc
    return OptimizeResult(design, e, initial, tuple(history), iteration, reason, time.perf_counter() - started)


def _gradient(design: Design, e: Evaluation) -> np.ndarray:
    """dJ/dq at ``e``, then ``e``'s factorisations are released (only its values and
    displacements are used from here on)."""
    g = design.gradient(e)
    e.release()
    return g


def _needs_remesh(design: Design, q, fresh: tuple[float, float], limit_deg: float) -> bool:
    """Has a 2D angle of either mesh dropped below ``limit_deg``, or below half the fresh
    mesh's own minimum when that is smaller (gmsh's graded meshes start near 9°)?"""
    angle = _min_angle(design, q)
    return any(a < min(limit_deg, 0.5 * f) for a, f in zip(angle, fresh))


def feasible_step(design: Design, q, p, alpha: float = 1.0, keep: float = 0.1) -> float:
    """Largest ``α' ≤ alpha`` along ``q + α' p`` that keeps every outline gap (capacitor to
    capacitor, capacitor to sheet, within an outline) above ``keep`` of its current
    excess over the minimum and every triangle of both 2D meshes above ``keep`` of its
    area: no overlap, no outline leaving the sheet, no inverted triangle."""
    deformer = design.deformer
    barrier = layout_objective(design.scene).barrier
    v = alpha * deformer.displacement2d(p)
    alpha *= barrier.max_step(deformer.outlines(q), [v[chain] for chain in deformer.outline_vertices], keep)
    v = alpha * deformer.displacement2d(p)
    alpha *= max_step_triangles(deformer.points2d(q), deformer.mesh2d.triangles, v, keep)
    if design.elastic_weights is not None:
        m = design.base.elastic.mesh.mesh2d
        el = m.points + design.elastic_weights @ deformer._q(q)
        alpha *= max_step_triangles(el, m.triangles, alpha * (design.elastic_weights @ deformer._q(p)), keep)
    return alpha


def _line_search(design: Design, e: Evaluation, g: np.ndarray, p: np.ndarray, alpha: float,
                 max_trials: int = 8) -> tuple[Evaluation | None, float, int]:
    """Backtracking (Armijo) from the largest feasible ``α ≤ alpha``; returns the accepted
    evaluation (or ``None``), α and the number of evaluations."""
    alpha = feasible_step(design, e.q, p, alpha)
    slope = float(np.vdot(g, p))
    for trial in range(1, max_trials + 1):
        try:
            candidate = design.evaluate(e.q + alpha * p, warm=e)
        except _TRIAL_ERRORS as exc:
            log.info("line search: α = %.3g failed (%s); halving", alpha, exc)
            alpha *= 0.5
            continue
        if candidate.J <= e.J + 1e-4 * alpha * slope:
            return candidate, alpha, trial
        candidate.release()
        alpha *= 0.5
    return None, 0.0, max_trials
