"""Identify scene parameters from measured capacitances: ``mscap fit``.

The problem: parameters p of a scene (its layer thicknesses, permittivity, moduli, a pose's
depth, the plates' size; :mod:`mscap.scene.edit` names them), readings y of some poses
(:mod:`mscap.calibration.measurements`), and the forward model C(p), the scene simulated
(elastic equilibrium, then capacitances) with those values. The fit minimises the sum of
squared residuals r = C(p) − y over the bounds with scipy's trust-region reflective
``least_squares``; the Jacobian is one-sided finite differences (a step of ``step`` times
each parameter's size, away from a bound), one forward per parameter, farmed to the MPI
workers. (The adjoints mscap has are for plate outlines, not for thicknesses, moduli or a
pose's depth.) With more workers than parameters the forward at a trial point and the
Jacobian's columns there are computed at once (one forward's wall time per iteration).

At the optimum, with J the Jacobian and s² = |r|² / (m − n):

- covariance s² (JᵀJ)⁻¹; with a ``run`` column, the cluster-robust ("sandwich") covariance
  (JᵀJ)⁻¹ (Σ_g J_gᵀ r_g r_gᵀ J_g) (JᵀJ)⁻¹ · G / (G − 1) over the G runs, since appendix A's
  per-run gain makes the readings of a run move together;
- standard errors, the square roots of its diagonal, and correlations;
- the parameters the readings cannot separate: a pair whose correlation exceeds
  :data:`CORRELATED` in magnitude, and any direction of (scaled) parameter space along which
  the residual does not change (a singular value of the scaled J below :data:`NULL`
  relative to the largest), whose parameters get an infinite standard error.
"""

from __future__ import annotations

import logging
import math
import time
import tomllib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from mscap.calibration.measurements import Measurements
from mscap.errors import CalibrationError
from mscap.scene.edit import Parameter, apply, format_number, parameter

__all__ = ["FitProblem", "FitResult", "CORRELATED", "NULL", "read_spec", "fit_problem", "solve", "statistics",
           "forward", "fitted_text"]

log = logging.getLogger(__name__)

#: A pair of parameters whose correlation exceeds this in magnitude is reported as one the
#: readings cannot separate (only a combination of them is determined).
CORRELATED = 0.99
#: A singular value of the scaled Jacobian below this fraction of the largest is a direction
#: the readings do not see at all.
NULL = 1e-8
#: The least-squares iteration stops when a step changes the sum of squares, or the
#: parameters (in units of their size), by less than this fraction: a forward whose mesh
#: follows the thicknesses and plates is smooth only to about 1e-3 (the noise-free test in
#: tests/calibration/test_fit.py), and below that the iteration wanders along a valley at
#: a forward per step (paper_identify.py did, 2026-12-06: RMS 0.2506 → 0.2452 pF in 14
#: forwards).
TOLERANCE = 1e-3
#: Default bounds of a positive parameter: its scene value divided and multiplied by this.
DEFAULT_RANGE = 10.0


@dataclass(frozen=True)
class FitProblem:
    """What is fitted: the scene (its file and text), the parameters with their bounds,
    the readings."""

    path: str
    source: str
    parameters: tuple[Parameter, ...]
    lower: np.ndarray
    upper: np.ndarray
    measurements: Measurements

    @property
    def start(self) -> np.ndarray:
        return np.array([p.start for p in self.parameters])

    @property
    def typical(self) -> np.ndarray:
        """Each parameter's size: its start, or 1 when that is 0 (scales the step and the
        identifiability test)."""
        return np.array([abs(p.start) or 1.0 for p in self.parameters])

    def text_at(self, values) -> str:
        return apply(self.path, self.source, list(self.parameters), values)

    def describe(self, values) -> str:
        return ", ".join(f"{p.name} = {v:.6g}" for p, v in zip(self.parameters, values))


@dataclass(frozen=True)
class FitResult:
    """The fitted values with their statistics, the residuals, and what it cost."""

    values: np.ndarray
    standard_error: np.ndarray
    correlation: np.ndarray
    covariance_kind: str
    unseparated: tuple[tuple[str, str, float], ...]
    undetermined: tuple[str, ...]
    model_pF: np.ndarray
    residual_pF: np.ndarray
    message: str
    iterations: int
    forwards: int
    wall_s: float
    ranks: int
    at_bound: tuple[str, ...] = field(default=())

    @property
    def rms_pF(self) -> float:
        return float(np.sqrt(np.mean(self.residual_pF ** 2)))


def read_spec(path: str, data: dict, spec: str) -> tuple[Parameter, float, float]:
    """A ``NAME`` or ``NAME=LO:HI`` of the command line: the parameter and its bounds
    (either side may be empty: unbounded). Without bounds a positive parameter may move
    within a factor :data:`DEFAULT_RANGE` of its value; a Poisson ratio stays below 0.5."""
    name, eq, bounds = spec.partition("=")
    p = parameter(path, data, name.strip())
    if eq:
        lo_text, colon, hi_text = bounds.partition(":")
        try:
            if not colon:
                raise ValueError
            lo = float(lo_text) if lo_text.strip() else -math.inf
            hi = float(hi_text) if hi_text.strip() else math.inf
        except ValueError:
            raise CalibrationError(f"--param {spec}: bounds are LO:HI (numbers; either may be empty), "
                                   f"got {bounds!r}") from None
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise CalibrationError(f"--param {spec}: the lower bound must be below the upper, got {lo:g}:{hi:g}")
    elif p.start > 0 and not p.name.endswith("]"):
        lo, hi = p.start / DEFAULT_RANGE, p.start * DEFAULT_RANGE
    else:
        lo, hi = -math.inf, math.inf
    if p.name.endswith("poisson_ratio"):
        hi = min(hi, 0.4999)
    if not lo <= p.start <= hi:
        raise CalibrationError(f"--param {spec}: the bounds [{lo:g}, {hi:g}] exclude the scene's value {p.start:g} "
                               f"(the fit starts there)")
    return p, lo, hi


def fit_problem(path: str, source: str, specs: list[str], measurements: Measurements) -> FitProblem:
    """The fit of ``specs`` (``NAME`` or ``NAME=LO:HI``) of the scene text ``source`` to
    ``measurements``."""
    if not specs:
        raise CalibrationError("nothing to fit: name at least one --param (e.g. thickness_scale, "
                               "materials.clear.relative_permittivity, poses.*.depth_mm)")
    data = tomllib.loads(source)
    read = [read_spec(path, data, s) for s in specs]
    names = [p.name for p, _, _ in read]
    if len(set(names)) < len(names):
        raise CalibrationError(f"--param {next(n for n in names if names.count(n) > 1)} given twice")
    places = [place for p, _, _ in read for place in p.places]
    if len(set(places)) < len(places):
        raise CalibrationError(f"two parameters move the same value of the scene ({', '.join(names)}): "
                               f"the readings could never separate them; fit one")
    count = len(measurements.values_pF.ravel())
    if count < len(read):
        raise CalibrationError(f"{measurements.path}: {count} numbers cannot determine {len(read)} parameters")
    return FitProblem(path=path, source=source, parameters=tuple(p for p, _, _ in read),
                      lower=np.array([lo for _, lo, _ in read]), upper=np.array([hi for _, _, hi in read]),
                      measurements=measurements)


def forward(problem: FitProblem, values) -> np.ndarray:
    """The simulated ``(len(measurements.poses), k)`` capacitances at ``values``."""
    from mscap.fem.simulate import simulate
    from mscap.scene import load_scene
    from mscap.scene.loader import select_poses

    scene = select_poses(load_scene(problem.path, source=problem.text_at(values)), list(problem.measurements.poses))
    table = simulate(scene).capacitance_pF
    if not np.all(np.isfinite(table)):
        raise CalibrationError(f"the forward at {problem.describe(values)} gave a non-finite capacitance")
    return table


#: ``evaluate(batch)``: the forward tables of a list of value vectors, each a table or, for
#: a forward that failed, its message (a string).
Evaluate = Callable[[list[np.ndarray]], list]


def solve(problem: FitProblem, evaluate: Evaluate, ranks: int = 1, step: float = 1e-2,
          max_iterations: int = 30, say: Callable[[str], None] | None = None) -> FitResult:
    """Least squares from the scene's values; ``evaluate`` runs the forwards of a batch
    (farmed to the ``ranks − 1`` workers of an MPI job, or one after another on one rank)."""
    from scipy.optimize import least_squares

    say = say or (lambda line: None)
    meas = problem.measurements
    n, t0 = len(problem.parameters), time.perf_counter()
    workers = max(ranks - 1, 1)
    steps = step * problem.typical
    cache: dict[bytes, np.ndarray] = {}
    jacobians: dict[bytes, np.ndarray] = {}
    count = {"forwards": 0}
    speculate = workers > n

    def columns_at(x):
        """The finite-difference steps at ``x`` (away from an upper bound) and their points."""
        h = np.where(x + steps <= problem.upper, steps, -steps)
        return h, [x + h[i] * np.eye(n)[i] for i in range(n)]

    def run(batch):
        count["forwards"] += len(batch)
        return evaluate(batch)

    def residual_of(table):
        return (meas.model(table) - meas.values_pF).ravel()

    def jacobian(f0, h, tables):
        return np.stack([(residual_of(t) - f0) / h[i] for i, t in enumerate(tables)], axis=1)

    def fun(x):
        key = x.tobytes()
        if key not in cache:
            h, points = columns_at(x)
            tables = run([x] + (points if speculate else []))
            if isinstance(tables[0], str):
                if not cache:
                    raise CalibrationError(f"the forward at the scene's values failed: {tables[0]}")
                say(f"  trial point {problem.describe(x)}: the forward failed ({tables[0]}); a shorter step")
                return np.full(meas.values_pF.size, np.nan)
            cache[key] = residual_of(tables[0])
            if speculate and not any(isinstance(t, str) for t in tables[1:]):
                jacobians[key] = jacobian(cache[key], h, tables[1:])
            say(f"  forward {count['forwards']}: {problem.describe(x)}: RMS residual "
                f"{np.sqrt(np.mean(cache[key] ** 2)):.4g} pF")
        return cache[key]

    def jac(x):
        key = x.tobytes()
        if key not in jacobians:
            f0 = fun(x)
            h, points = columns_at(x)
            tables = run(points)
            for i, t in enumerate(tables):
                if isinstance(t, str):
                    raise CalibrationError(f"the forward for {problem.parameters[i].name}'s derivative at "
                                           f"{problem.describe(x)} failed: {t}")
            jacobians[key] = jacobian(f0, h, tables)
        return jacobians[key]

    x0 = np.clip(problem.start, problem.lower, problem.upper)
    say(f"fitting {n} parameter(s) to {meas.values_pF.size} numbers ({meas.values_pF.shape[0]} readings of "
        f"{len(meas.poses)} pose(s)); "
        f"{workers} worker(s){', each forward with its Jacobian columns at once' if speculate else ''}")
    result = least_squares(fun, x0, jac=jac, bounds=(problem.lower, problem.upper), x_scale=problem.typical,
                           method="trf", xtol=TOLERANCE, ftol=TOLERANCE, gtol=1e-8, max_nfev=max_iterations)
    x = result.x
    r = fun(x)  # both cached: the accepted point's residuals and Jacobian
    se, correlation, kind, unseparated, undetermined = statistics(
        jac(x), r, problem.typical, meas.runs, [p.name for p in problem.parameters],
        per_reading=meas.values_pF.shape[1])
    at_bound = tuple(p.name for p, v, lo, hi in zip(problem.parameters, x, problem.lower, problem.upper)
                     if np.isclose(v, lo, rtol=1e-6, atol=0) or np.isclose(v, hi, rtol=1e-6, atol=0))
    residual = r.reshape(meas.values_pF.shape)
    return FitResult(values=x, standard_error=se, correlation=correlation, covariance_kind=kind,
                     unseparated=unseparated, undetermined=undetermined, model_pF=residual + meas.values_pF,
                     residual_pF=residual, message=result.message, iterations=int(result.nfev),
                     forwards=count["forwards"], wall_s=time.perf_counter() - t0, ranks=ranks, at_bound=at_bound)


def statistics(J: np.ndarray, r: np.ndarray, typical: np.ndarray, runs, names: list[str], per_reading: int = 1):
    """``(standard errors, correlations, covariance kind, unseparated pairs, undetermined
    names)`` at the optimum (module docstring). ``runs``: the run label of each reading
    (``per_reading`` residuals each), or ``None``."""
    m, n = J.shape
    Js = J * typical  # columns in units of each parameter's size
    _, sv, vt = np.linalg.svd(Js, full_matrices=False)
    seen = sv > NULL * sv[0] if sv[0] > 0 else np.zeros(n, bool)
    inverse = (vt[seen].T / sv[seen] ** 2) @ vt[seen]  # (JsᵀJs)⁺ on the directions seen
    labels = None if runs is None else np.repeat(np.asarray(runs), per_reading)
    groups = None if labels is None else [np.flatnonzero(labels == g) for g in dict.fromkeys(labels)]
    if groups is not None and len(groups) > 1:
        score = np.array([Js[g].T @ r[g] for g in groups])
        cov_s = len(groups) / (len(groups) - 1) * inverse @ (score.T @ score) @ inverse
        kind = f"cluster-robust over {len(groups)} runs"
    else:
        dof = m - n
        s2 = float(r @ r) / dof if dof > 0 else math.nan
        cov_s = s2 * inverse
        kind = f"s^2 (J^T J)^-1, s = {math.sqrt(s2):.4g} pF over {dof} degrees of freedom" if dof > 0 else \
            "none: as many readings as parameters"
    se_s = np.sqrt(np.clip(np.diag(cov_s), 0, None))
    undetermined = np.zeros(n, bool)
    for v in vt[~seen]:
        undetermined |= np.abs(v) > 0.1
    se = np.where(undetermined, math.inf, se_s * typical)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_s / np.outer(se_s, se_s)
    corr[~np.isfinite(corr)] = math.nan
    np.fill_diagonal(corr, 1.0)
    pairs = tuple((names[i], names[j], float(corr[i, j])) for i in range(n) for j in range(i + 1, n)
                  if abs(corr[i, j]) > CORRELATED)
    return se, corr, kind, pairs, tuple(name for name, u in zip(names, undetermined) if u)


def fitted_text(problem: FitProblem, result: FitResult, when: str = "") -> str:
    """The scene text with the fitted values, under a comment block saying where they came
    from (values, standard errors, what the readings could not separate)."""
    meas = problem.measurements
    lines = [f"# Fitted by `mscap fit` to {meas.path} ({meas.values_pF.shape[0]} readings of "
             f"{len(meas.poses)} poses){' on ' + when if when else ''}; RMS residual {result.rms_pF:.4g} pF:"]
    for p, v, se in zip(problem.parameters, result.values, result.standard_error):
        lines.append(f"#   {p.name} = {format_number(v)} ± {se:.3g} (was {format_number(p.start)})")
    for a, b, c in result.unseparated:
        lines.append(f"#   not separated by the readings: {a} and {b} (correlation {c:+.4f})")
    if result.undetermined:
        lines.append(f"#   not determined by the readings: {', '.join(result.undetermined)}")
    return "\n".join(lines) + "\n" + problem.text_at(result.values)
