"""Newton's method with load stepping for one pose: the elastic equilibrium.

Each load step moves the pose's load fraction ``t`` towards 1 (grip stretch, ball depth,
glued surface). A step starts from the first feasible of a few predictors (secant
extrapolation of the last two steps, the pose's own guess, the linearised response to
the new boundary data, the last state), with the Dirichlet values of the new ``t`` and
nodes pushed out of the ball, then runs Newton on the total energy:

* the Hessian is factorised as it is (``hessian="exact"``), made positive semi-definite
  element by element (``"projected"``), or first as it is and projected only when the
  factorisation fails, the step is not a descent direction, or the previous step was
  damped below 1/2 (``"auto"``, the default);
* a backtracking line search accepts the first step length with sufficient energy
  decrease; a trial with an inverted element (J ≤ 0) has infinite energy, and the step
  length is bounded so that every node keeps at least a tenth of its gap to the ball;
* convergence is ``max |g_i| / s_i ≤ tol`` over free dofs, with ``s`` the node's force
  scale ``Σ μ vol^(2/3)``: the residual stress in units of μ.

Intermediate load steps stop at ``step_tolerance`` (they only carry the path); the last
one meets ``tolerance``. When Newton stalls (line search fails, or too many iterations)
the load step is halved, and grows back after each success; after ``max_cuts`` halvings
the pose fails with an :class:`~mscap.fem.elastic.problem.ElasticError` that names the
pose, the load step and the residual. Nothing non-finite is ever accepted.

Dirichlet dofs are kept in the matrix as identity rows and columns, so the CSR pattern —
and PETSc's symbolic factorisation — is the same for every pose of a mesh.

A warm start at a nearby design (an optimiser's next trial) may bring that pose's
factorised exact Hessian from the previous design's equilibrium (``stale``): Newton then
first runs as modified Newton on it — a gradient assembly and one back-substitution per
iteration instead of a Hessian assembly and a factorisation — while each iteration
contracts the residual at least :data:`STALE_CONTRACTION`-fold, and goes on as above from
wherever that stops. The equilibrium meets the same tolerance either way.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp

from mscap.errors import LinearSolveError
from mscap.fem.elastic.contact import Ball
from mscap.fem.elastic.problem import ElasticError, ElasticProblem, assemble, total_energy
from mscap.fem.petsc import Operator
from mscap.profile import phase, timed
from mscap.scene.settings import HESSIAN_MODES, ElasticSettings

__all__ = ["Loading", "NewtonSettings", "ElasticState", "solve_pose", "factorise_equilibrium", "HESSIAN_MODES"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Loading:
    """What a pose does to one problem (built by :mod:`mscap.fem.elastic.loading`).

    Attributes
    ----------
    pose
        Pose name (for messages).
    fixed
        ``(n_nodes, 3)`` Dirichlet mask.
    targets
        ``t ↦ (n_nodes, 3)`` positions whose fixed entries are the Dirichlet values at
        load fraction ``t`` (1 is the pose).
    ball
        ``t ↦ Ball`` for a poke, else ``None``.
    load_steps
        Initial number of load steps.
    guess
        Optional ``(x, t) ↦ x`` first guess for a load step from ``x`` (e.g. the glued
        sheet extruded along the surface normal).
    """

    pose: str
    fixed: np.ndarray
    targets: Callable[[float], np.ndarray]
    ball: Callable[[float], Ball] | None = None
    load_steps: int = 1
    guess: Callable[[np.ndarray, float], np.ndarray] | None = None
    column_push: Callable[[np.ndarray, Ball], np.ndarray] | None = None


#: Newton and load-stepping parameters are the scene's ``[elastic]`` table.
NewtonSettings = ElasticSettings


@dataclass(frozen=True)
class ElasticState:
    """The equilibrium of one pose.

    Attributes
    ----------
    pose
        Pose name.
    nodes
        ``(n_nodes, 3)`` equilibrium node positions (mm); the first ``n_vertices`` rows
        are the mesh vertices.
    load_steps, newton_iterations, step_cuts
        Accepted load steps, Newton iterations over all of them, halvings of a step.
    residual
        Final scaled residual (see module docstring).
    min_j
        Smallest J over all quadrature points.
    energy_mJ
        Total energy (elastic plus contact).
    min_gap_mm
        Smallest node–ball gap (poke), else ``None``.
    projected
        Newton iterations that used the projected Hessian (all of them in
        ``"projected"`` mode, the fallbacks in ``"auto"`` mode).
    times
        Seconds spent in ``assembly``, ``factorisation``, ``solve``, ``line_search``.
    operator
        The factorised Hessian at the equilibrium (only with ``keep_factorisation``).
    stale_iterations
        Modified-Newton iterations on a previous design's factorised Hessian (``stale``).
    """

    pose: str
    nodes: np.ndarray
    load_steps: int
    newton_iterations: int
    step_cuts: int
    residual: float
    min_j: float
    energy_mJ: float
    min_gap_mm: float | None
    projected: int
    times: dict
    operator: "Operator | None" = field(default=None, repr=False)
    stale_iterations: int = 0

    def vertices(self, n_vertices: int) -> np.ndarray:
        """``(n_vertices, 3)`` vertex positions (mm)."""
        return self.nodes[:n_vertices]


class _Stall(Exception):
    def __init__(self, residual: float, why: str):
        super().__init__(why)
        self.residual, self.why = residual, why


#: Modified Newton on a stale Hessian (module docstring) stops when an iteration leaves more
#: than this fraction of the residual, or after :data:`STALE_ITERATIONS` iterations (a
#: stale iteration costs about a fifteenth of a Newton one on P2). On poking_quick's P2, a
#: design step of 0.1 mm: 0.5 stopped every pose after 2 iterations (contraction 0.06, then
#: 0.6), 4 Newton iterations followed; 0.8 converged in 9 and no Newton iteration, the
#: warm evaluation 3.4× cheaper in CPU, J the same to 1e-10.
STALE_CONTRACTION = 0.8
STALE_ITERATIONS = 30


class _Pose:
    """Newton's method for one loading; keeps the counters."""

    def __init__(self, problem: ElasticProblem, loading: Loading, settings: NewtonSettings, operator: Operator,
                 stale: Operator | None = None):
        self.problem, self.loading, self.settings, self.op = problem, loading, settings, operator
        self.stale, self.stale_iterations = stale, 0
        fixed = loading.fixed.ravel()
        self.fixed = loading.fixed
        rows = np.repeat(np.arange(problem.n_dofs), np.diff(problem.indptr))
        self.clear = np.flatnonzero(fixed[rows] | fixed[problem.indices])
        diag = problem.csr_of_block.reshape(-1, 3, 3)[problem.diag_block][:, [0, 1, 2], [0, 1, 2]]
        self.fixed_diag = diag.ravel()[fixed]
        self.diag_blocks = problem.csr_of_block.reshape(-1, 9)[problem.diag_block]
        self.iterations = self.projected = 0
        self.times = {"assembly": 0.0, "factorisation": 0.0, "solve": 0.0, "line_search": 0.0}
        self.final_hessian: np.ndarray | None = None  # exact Hessian at the last converged state
        self.ball: Ball | None = None

    # -- energy and derivatives ------------------------------------------------------
    def energy(self, x: np.ndarray) -> float:
        if self.ball is not None and (self.ball.distances(x) <= 0).any():
            return np.inf
        e, _ = total_energy(self.problem, x)
        return e + (self.ball.energy(x) if self.ball is not None and np.isfinite(e) else 0.0)

    @timed("assembly")
    def gradient_and_hessian(self, x: np.ndarray, hessian: bool, project: bool):
        start = time.perf_counter()
        a = assemble(self.problem, x, hessian=hessian, project=project)
        if not np.isfinite(a.energy):
            raise _Stall(np.inf, f"an element is inverted (min J {a.min_j:.3g})")
        g = a.gradient.copy()
        energy = a.energy
        if self.ball is not None:
            energy += self.ball.energy(x)
            nodes, bg, bh = self.ball.terms(x, project=project)
            np.add.at(g, nodes, bg)
            if hessian:
                np.add.at(a.hessian, self.diag_blocks[nodes].ravel(), bh.reshape(len(nodes), 9).ravel())
        g[self.fixed] = 0.0
        self.times["assembly"] += time.perf_counter() - start
        return energy, g, a.hessian, a.min_j

    def residual(self, g: np.ndarray) -> float:
        return float(np.max(np.abs(g) / self.problem.force_scale[:, None])) if g.size else 0.0

    def factorise(self, data: np.ndarray) -> None:
        start = time.perf_counter()
        scale = float(np.mean(np.abs(data[self.diag_blocks[:, 0]])))
        data[self.clear] = 0.0
        data[self.fixed_diag] = scale
        try:
            self.op.factorise(data)
        finally:
            self.times["factorisation"] += time.perf_counter() - start

    def direction(self, g: np.ndarray) -> np.ndarray:
        start = time.perf_counter()
        p = self.op.solve(-g.ravel()).reshape(-1, 3)
        self.times["solve"] += time.perf_counter() - start
        p[self.fixed] = 0.0
        return p

    # -- Newton ----------------------------------------------------------------------
    def newton(self, x: np.ndarray, tolerance: float) -> tuple[np.ndarray, float]:
        mode = self.settings.hessian
        e0 = self.energy(x)
        if not np.isfinite(e0):
            raise _Stall(np.inf, "the start is infeasible")
        if self.stale is not None:
            x, r, converged = self.stale_newton(x, tolerance)
            self.stale = None  # once: a retried load step runs Newton
            if converged:
                self.final_hessian = None
                return x, r
        damped = False
        for it in range(self.settings.max_iterations + 1):
            # auto: after a step the line search cut below 1/2, Newton is far from the
            # solution, where the exact Hessian's negative directions (a clamped sheet's
            # lateral compression, the flat sheet under a ball) lead nowhere: one projected
            # iteration there. Clamped λ = 2 stretch of grid3x3: 53 → 32 iterations.
            project = mode == "projected" or (mode == "auto" and damped)
            energy, g, h, _ = self.gradient_and_hessian(x, hessian=True, project=project)
            r = self.residual(g)
            if not np.isfinite(r):
                raise _Stall(r, "the residual is not finite")
            if r <= tolerance:
                self.final_hessian = None if project else h
                return x, r
            if it == self.settings.max_iterations:
                raise _Stall(r, f"no convergence in {it} Newton iterations")
            self.iterations += 1
            self.projected += project
            p = None
            try:
                self.factorise(h)
                h = None  # factorised (the operator holds its values): not alive through the next assembly
                p = self.direction(g)
                if not np.vdot(g, p) < 0 or not np.isfinite(p).all():
                    p = None
            except LinearSolveError:
                if mode != "auto":
                    raise
            if p is None:
                if mode != "auto":
                    raise _Stall(r, "the Newton direction is not a descent direction")
                self.projected += 1
                project = True
                _, g, h, _ = self.gradient_and_hessian(x, hessian=True, project=True)
                self.factorise(h)
                p = self.direction(g)
            x, alpha = self.line_search(x, energy, g, p, r)
            damped = alpha < 0.5
            log.debug("pose %s: Newton %d, residual %.3e, energy %.10g, step %.3g%s", self.loading.pose,
                      self.iterations, r, energy, alpha, " (projected)" if project else "")
        raise AssertionError("unreachable")

    def stale_newton(self, x: np.ndarray, tolerance: float) -> tuple[np.ndarray, float, bool]:
        """Modified Newton on ``self.stale`` (module docstring) from ``x``: the state it
        reached, its residual and whether that meets ``tolerance``."""
        energy, g, _, _ = self.gradient_and_hessian(x, hessian=False, project=False)
        r = self.residual(g)
        for _ in range(STALE_ITERATIONS):
            if r <= tolerance:
                break
            start = time.perf_counter()
            p = self.stale.solve(-g.ravel()).reshape(-1, 3)
            self.times["solve"] += time.perf_counter() - start
            p[self.fixed] = 0.0
            if not np.isfinite(p).all() or not np.vdot(g, p) < 0:
                break
            try:
                trial, _ = self.line_search(x, energy, g, p, r)
                e_trial, g_trial, _, _ = self.gradient_and_hessian(trial, hessian=False, project=False)
            except _Stall:
                break
            self.stale_iterations += 1
            r_trial = self.residual(g_trial)
            x, energy, g, contraction, r = trial, e_trial, g_trial, r_trial / r, r_trial
            if contraction > STALE_CONTRACTION:
                break
        return x, r, r <= tolerance

    def line_search(self, x, energy, g, p, r) -> np.ndarray:
        start = time.perf_counter()
        slope = float(np.vdot(g, p))
        alpha = 1.0 if self.ball is None else self.ball.max_step(x, p)
        while alpha > 1e-12:
            trial = x + alpha * p
            e = self.energy(trial)
            if e <= energy + 1e-4 * alpha * slope:
                break
            # Near convergence energy differences drown in round-off: accept a step that
            # keeps the energy within round-off and reduces the residual.
            if np.isfinite(e) and abs(e - energy) <= 1e-12 * abs(energy) + 1e-300:
                _, g1, _, _ = self.gradient_and_hessian(trial, hessian=False, project=False)
                if self.residual(g1) < r:
                    break
            alpha *= 0.5
        self.times["line_search"] += time.perf_counter() - start
        if alpha <= 1e-12:
            raise _Stall(r, "the line search found no decrease")
        return trial, alpha

    # -- predictors ------------------------------------------------------------------
    def feasible(self, x: np.ndarray, t: float) -> np.ndarray | None:
        """``x`` with the Dirichlet values of ``t`` and pushed out of the ball, if valid."""
        x = x.copy()
        x[self.fixed] = self.loading.targets(t)[self.fixed]
        if self.ball is not None and self.loading.column_push is not None:
            x = self.loading.column_push(x, self.ball)
        return x if np.isfinite(self.energy(x)) else None

    def lift(self, x: np.ndarray, t: float) -> np.ndarray | None:
        """Linearised elastic response to the change of Dirichlet values."""
        delta = np.zeros_like(x)
        delta[self.fixed] = self.loading.targets(t)[self.fixed] - x[self.fixed]
        if not delta.any():
            return None
        raw = self.final_hessian  # assembled at x by the convergence check of the last step
        if raw is None or self.ball is not None:
            ball, self.ball = self.ball, None  # x may lie inside the next step's ball
            try:
                _, _, raw, _ = self.gradient_and_hessian(x, hessian=True,
                                                         project=self.settings.hessian == "projected")
            except _Stall:
                return None
            finally:
                self.ball = ball
        full = sp.csr_matrix((raw, self.problem.indices, self.problem.indptr), shape=(self.problem.n_dofs,) * 2)
        rhs = -(full @ delta.ravel()).reshape(-1, 3)
        # Factorised in place: the Hessian is not needed again (a retry reassembles), and
        # holding it through the next step's Newton iterations cost 55 MB on biaxial's check.
        self.final_hessian = None
        try:
            self.factorise(raw)
        except LinearSolveError:
            return None
        rhs[self.fixed] = 0.0
        start = time.perf_counter()
        step = self.op.solve(rhs.ravel()).reshape(-1, 3)
        self.times["solve"] += time.perf_counter() - start
        step[self.fixed] = delta[self.fixed]
        return x + step


@phase("Newton")
def solve_pose(problem: ElasticProblem, loading: Loading, settings: NewtonSettings | None = None,
               operator: Operator | None = None, keep_factorisation: bool = False,
               progress: Callable[[str], None] | None = None, stale: Operator | None = None) -> ElasticState:
    """Equilibrium of one pose by load stepping and Newton.

    Parameters
    ----------
    problem
        From :func:`mscap.fem.elastic.problem.build_problem`.
    loading
        The pose's boundary data.
    settings
        Newton parameters.
    operator
        An :class:`Operator` of this problem to reuse (its symbolic factorisation).
    keep_factorisation
        Factorise the exact Hessian at the equilibrium and return it in the state (for
        adjoint solves); this uses a fresh operator.
    progress
        Called with a one-line message after every load step.
    stale
        This pose's factorised exact Hessian at a nearby configuration of the same mesh
        and loading (a previous design's ``operator``; read only): the first load step
        starts as modified Newton on it (module docstring).

    Raises
    ------
    ElasticError
        When a load step cannot be completed after ``max_cuts`` halvings.
    """
    settings = settings or NewtonSettings()
    if settings.hessian not in HESSIAN_MODES:
        raise ElasticError(f"hessian mode must be one of {', '.join(HESSIAN_MODES)}, got {settings.hessian!r}")
    own = operator is None  # ours to destroy (petsc4py frees native memory only then)
    run = _Pose(problem, loading, settings, Operator(problem) if own else operator, stale)
    try:
        return _follow_load_path(problem, loading, settings, run, keep_factorisation, progress)
    finally:
        if own:
            run.op.destroy()


def factorise_equilibrium(problem: ElasticProblem, loading: Loading, settings: NewtonSettings, x: np.ndarray,
                          hessian: np.ndarray | None = None) -> Operator:
    """The exact Hessian at ``x``, an equilibrium of ``loading`` at full load, factorised
    in a new operator (options prefix ``adjoint_``; the caller destroys it): what the
    adjoint solves with, and what a nearby design's modified Newton starts on (``stale``).
    ``hessian``: its values, when already assembled at ``x`` (read only)."""
    op = Operator(problem, "adjoint_")
    try:
        keeper = _Pose(problem, loading, settings, op)
        keeper.ball = loading.ball(1.0) if loading.ball else None
        if hessian is None:  # not kept (projected mode, or asked for later): assemble at x
            _, _, hessian, _ = keeper.gradient_and_hessian(x, hessian=True, project=False)
        keeper.factorise(hessian.copy())
    except BaseException:
        op.destroy()
        raise
    return op


def _follow_load_path(problem: ElasticProblem, loading: Loading, settings: NewtonSettings, run: "_Pose",
                      keep_factorisation: bool, progress: Callable[[str], None] | None) -> ElasticState:
    """:func:`solve_pose`'s load stepping, on ``run``'s operator."""
    x = problem.rest.copy()
    previous: tuple[np.ndarray, float] | None = None
    t, dt, steps, cuts, residual = 0.0, 1.0 / loading.load_steps, 0, 0, 0.0
    while t < 1.0:
        t_new = min(1.0, t + dt)
        if 1.0 - t_new < 1e-9:
            t_new = 1.0
        run.ball = loading.ball(t_new) if loading.ball else None
        candidates = []
        if previous is not None:
            candidates.append(lambda: x + (t_new - t) / (t - previous[1]) * (x - previous[0]))
        if loading.guess is not None:
            candidates.append(lambda: loading.guess(x, t_new))
        candidates.append(lambda: run.lift(x, t_new))
        candidates.append(lambda: x)
        start = None
        for make in candidates:
            guess = make()
            if guess is not None and (start := run.feasible(guess, t_new)) is not None:
                break
        try:
            if start is None:
                raise _Stall(np.nan, "no feasible start (every predictor inverts an element or enters the ball)")
            # Intermediate load steps only carry the path: a looser tolerance saves the
            # last quadratic iterations there; the final state meets ``tolerance``.
            solution, residual = run.newton(start, settings.tolerance if t_new == 1.0 else
                                            max(settings.tolerance, settings.step_tolerance))
        except (_Stall, LinearSolveError) as exc:
            why = exc.why if isinstance(exc, _Stall) else str(exc)
            r = exc.residual if isinstance(exc, _Stall) else np.nan
            cuts += 1
            if cuts > settings.max_cuts or dt < 1e-6:
                raise ElasticError(f"pose {loading.pose!r}: load step {steps + 1} (t = {t:.4g} → {t_new:.4g}) "
                                   f"failed after {cuts - 1} step cuts: {why}; residual "
                                   f"{f'{r:.3g}' if np.isfinite(r) else 'not computed'}") from None
            log.info("pose %s: load step t = %.4g → %.4g failed (%s); halving", loading.pose, t, t_new, why)
            dt *= 0.5
            continue
        previous, x, t = (x, t), solution, t_new
        steps += 1
        dt = min(2.0 * dt, 1.0 / loading.load_steps)  # grow back after a cut
        if progress:
            progress(f"pose {loading.pose}: load step {steps} t = {t:.3g}, {run.iterations} Newton iterations, "
                     f"residual {residual:.2e}")
    energy = run.energy(x)
    _, min_j = total_energy(problem, x)
    op = factorise_equilibrium(problem, loading, settings, x, run.final_hessian) if keep_factorisation else None
    gap = float(run.ball.distances(x).min()) if run.ball is not None else None
    state = ElasticState(loading.pose, x, steps, run.iterations, cuts, residual, min_j, energy, gap,
                         run.projected, dict(run.times), op, run.stale_iterations)
    state.nodes.setflags(write=False)
    log.info("pose %s: %d load steps, %d Newton iterations (%d projected, %d on a stale Hessian before), "
             "residual %.2e, min J %.4f", loading.pose, steps, run.iterations, run.projected,
             run.stale_iterations, residual, min_j)
    return state
