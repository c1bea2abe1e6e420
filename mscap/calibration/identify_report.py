"""What ``mscap fit`` prints and stores: the fitted values with their standard errors and
correlations, what the readings cannot separate, the residual of every reading, the cost."""

from __future__ import annotations

import numpy as np

from mscap.calibration.identify import CORRELATED, FitProblem, FitResult

__all__ = ["report_text", "fit_record"]


def report_text(problem: FitProblem, result: FitResult) -> str:
    """The fit as a few tables of plain text."""
    meas = problem.measurements
    width = max(len(p.name) for p in problem.parameters)
    out = [f"fit of {problem.path} to {meas.path}: {result.message}",
           f"{'parameter':<{width}}  {'start':>10}  {'fitted':>10}  {'std error':>10}  bounds"]
    for p, v, se, lo, hi in zip(problem.parameters, result.values, result.standard_error, problem.lower,
                                problem.upper):
        flag = "  (at a bound)" if p.name in result.at_bound else ""
        out.append(f"{p.name:<{width}}  {p.start:10.5g}  {v:10.5g}  {se:10.3g}  [{lo:g}, {hi:g}]{flag}")
    out.append(f"standard errors: {result.covariance_kind}")
    n = len(problem.parameters)
    if n > 1:
        out.append("correlations:")
        for i, p in enumerate(problem.parameters):
            out.append(f"  {p.name:<{width}}" + "".join(f"{result.correlation[i, j]:+8.3f}" for j in range(n)))
    for a, b, c in result.unseparated:
        out.append(f"NOT SEPARATED: {a} and {b} (correlation {c:+.4f}, above {CORRELATED}): the readings determine "
                   f"only a combination of them; fix one (leave it out of --param) or add readings that tell "
                   f"them apart")
    if result.undetermined:
        out.append(f"NOT DETERMINED: {', '.join(result.undetermined)}: the readings do not change along a "
                   f"direction that moves them (infinite standard error)")
    columns = [f"C{c}" for c in meas.capacitors]
    out.append(f"residual per reading (simulated - measured, pF; RMS {result.rms_pF:.4g} pF):")
    out.append(f"  {'line':>5}  {'pose':<16}{'run':<8}" + "".join(f"{c + ' read':>10}{'sim-read':>9}" for c in columns))
    for i, line in enumerate(meas.lines):
        pose = meas.poses[meas.pose_of_reading[i]]
        run = meas.runs[i] if meas.runs is not None else ""
        cells = "".join(f"{meas.values_pF[i, j]:10.3f}{result.residual_pF[i, j]:+9.3f}" for j in range(len(columns)))
        out.append(f"  {line:>5}  {pose:<16.16}{run:<8.8}{cells}")
    out.append(f"cost: {result.forwards} forward simulations in {result.wall_s:.1f} s on {result.ranks} rank(s) "
               f"({result.iterations} trial points)")
    return "\n".join(out)


def fit_record(problem: FitProblem, result: FitResult) -> dict:
    """The fit as one JSON-ready object (``mscap fit --json``)."""
    meas = problem.measurements

    def finite(a):
        return [None if not np.isfinite(v) else float(v) for v in np.ravel(a)]

    return {"scene": problem.path, "measurements": meas.path, "message": result.message,
            "parameters": [{"name": p.name, "start": p.start, "fitted": float(v), "standard_error": finite([se])[0],
                            "lower": finite([lo])[0], "upper": finite([hi])[0], "at_bound": p.name in result.at_bound}
                           for p, v, se, lo, hi in zip(problem.parameters, result.values, result.standard_error,
                                                       problem.lower, problem.upper)],
            "correlation": [finite(row) for row in result.correlation], "covariance": result.covariance_kind,
            "not_separated": [list(pair) for pair in result.unseparated], "not_determined": list(result.undetermined),
            "poses": list(meas.poses), "capacitors": list(meas.capacitors), "lines": list(meas.lines),
            "measured_pF": meas.values_pF.tolist(), "simulated_pF": result.model_pF.tolist(),
            "rms_pF": result.rms_pF, "forwards": result.forwards, "wall_s": result.wall_s, "ranks": result.ranks,
            "trial_points": result.iterations}
