"""The least-squares fit (``mscap.calibration.identify.solve``) on models with closed-form
answers: a linear model, whose fit and standard errors are ordinary least squares', and
models whose parameters the readings cannot tell apart."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from mscap.calibration.identify import CORRELATED, FitProblem, solve, statistics
from mscap.calibration.measurements import Measurements
from mscap.errors import CalibrationError
from mscap.scene.edit import parameter

SOURCE = "[m]\na = 1.0\nb = 2.0\nc = 0.5\n"


def linear_problem(design: np.ndarray, readings: np.ndarray, runs=None, names=("m.a", "m.b")) -> FitProblem:
    """Readings of one pose's ``k`` capacitors, one row per reading; ``design`` maps the
    parameters to the ``k`` capacitances."""
    data = tomllib.loads(SOURCE)
    params = tuple(parameter("s", data, n) for n in names)
    meas = Measurements(path="m.csv", poses=("rest",), pose_of_reading=np.zeros(len(readings), int),
                        capacitors=tuple(range(design.shape[0])), values_pF=readings, runs=runs,
                        lines=tuple(range(2, 2 + len(readings))))
    return FitProblem(path="s", source=SOURCE, parameters=params, lower=np.full(len(params), -np.inf),
                      upper=np.full(len(params), np.inf), measurements=meas)


def evaluator(design, offset=10.0):
    def evaluate(batch):
        return [(design @ x + offset)[None, :] for x in batch]
    return evaluate


@pytest.fixture
def linear():
    rng = np.random.default_rng(5)
    design = np.array([[3.0, 1.0], [1.0, 2.0], [0.5, -1.0], [2.0, 2.5]])
    truth = np.array([1.7, 2.6])
    readings = (design @ truth + 10.0)[None, :] + rng.normal(0, 0.3, (6, 4))
    return design, truth, readings


def test_a_linear_model_gets_ordinary_least_squares_and_its_standard_errors(linear):
    design, truth, readings = linear
    result = solve(linear_problem(design, readings), evaluator(design), step=1e-2)
    X = np.tile(design, (len(readings), 1))
    y = (readings - 10.0).ravel()
    ols, rss, *_ = np.linalg.lstsq(X, y, rcond=None)
    s2 = rss[0] / (len(y) - 2)
    se = np.sqrt(np.diag(s2 * np.linalg.inv(X.T @ X)))
    assert result.values == pytest.approx(ols, rel=1e-7)
    assert result.standard_error == pytest.approx(se, rel=1e-6)
    cov = s2 * np.linalg.inv(X.T @ X)
    assert result.correlation[0, 1] == pytest.approx(cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1]), rel=1e-6)
    assert np.all(np.abs(result.values - truth) < 3 * result.standard_error)
    assert result.residual_pF == pytest.approx((design @ result.values + 10.0)[None, :] - readings, abs=1e-9)
    assert not result.unseparated and not result.undetermined


def test_with_runs_the_errors_are_cluster_robust(linear):
    design, _, readings = linear
    runs = ("1", "1", "2", "2", "3", "3")
    result = solve(linear_problem(design, readings, runs=runs), evaluator(design))
    X = np.tile(design, (len(readings), 1))
    r = ((design @ result.values + 10.0)[None, :] - readings).ravel()
    bread = np.linalg.inv(X.T @ X)
    meat = sum(np.outer(X[g].T @ r[g], X[g].T @ r[g]) for g in (slice(0, 8), slice(8, 16), slice(16, 24)))
    cov = 3 / 2 * bread @ meat @ bread
    assert result.standard_error == pytest.approx(np.sqrt(np.diag(cov)), rel=1e-6)
    assert result.covariance_kind == "cluster-robust over 3 runs"


def test_parameters_that_only_enter_as_a_sum_are_reported_undetermined():
    design = np.array([[1.0, 1.0], [2.0, 2.0], [1.5, 1.5]])
    readings = (design @ np.array([1.2, 2.3]) + 10.0)[None, :] + np.random.default_rng(1).normal(0, 0.1, (4, 3))
    result = solve(linear_problem(design, readings), evaluator(design))
    assert result.undetermined == ("m.a", "m.b")
    assert np.all(np.isinf(result.standard_error))
    assert result.values.sum() == pytest.approx(3.5, abs=0.2)  # the sum is determined


def test_a_nearly_confounded_pair_is_reported_with_its_correlation():
    design = np.array([[1.0, 1.0], [2.0, 2.002], [1.5, 1.5]])
    readings = (design @ np.array([1.2, 2.3]) + 10.0)[None, :] + np.random.default_rng(1).normal(0, 0.1, (4, 3))
    result = solve(linear_problem(design, readings), evaluator(design))
    assert not result.undetermined
    (a, b, c), = result.unseparated
    assert (a, b) == ("m.a", "m.b") and c < -CORRELATED


def test_a_failed_forward_at_a_trial_point_shortens_the_step():
    design, truth = np.array([[3.0, 1.0], [1.0, 2.0], [0.5, -1.0]]), np.array([1.7, 2.6])
    readings = (design @ truth + 10.0)[None, :]
    calls, plain = [], evaluator(design)
    lines = []

    def evaluate(batch):
        calls.append(batch)
        if len(calls) == 3:  # the first trial point after the start's value and Jacobian
            return ["elastic: pose poke_0, load step 2: Newton diverged (residual 3e+02)"]
        return plain(batch)

    result = solve(linear_problem(design, readings), evaluate, say=lines.append)
    assert result.values == pytest.approx(truth, rel=1e-6)
    assert any("the forward failed (elastic: pose poke_0" in line and "a shorter step" in line for line in lines)


def test_a_failed_forward_at_the_start_is_an_error():
    design = np.eye(2)
    with pytest.raises(CalibrationError, match="the forward at the scene's values failed: mesh: no room"):
        solve(linear_problem(design, np.ones((1, 2))), lambda batch: ["mesh: no room"] * len(batch))


def test_with_more_workers_than_parameters_the_columns_come_with_the_forward(linear):
    design, _, readings = linear
    sizes = []

    def evaluate(batch):
        sizes.append(len(batch))
        return evaluator(design)(batch)

    serial = solve(linear_problem(design, readings), evaluator(design))
    result = solve(linear_problem(design, readings), evaluate, ranks=4)
    assert set(sizes) == {3}  # each trial point with its two columns, never a batch of its own
    assert np.array_equal(result.values, serial.values)


def test_statistics_of_a_zero_jacobian_determine_nothing():
    se, corr, kind, pairs, undetermined = statistics(np.zeros((4, 2)), np.ones(4), np.ones(2), None, ["a", "b"])
    assert undetermined == ("a", "b") and np.all(np.isinf(se))
