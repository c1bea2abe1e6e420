"""The Taylor-test harness (mscap.testing) on closed forms: exact, wrong and linear gradients."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from mscap.testing import TaylorResult, taylor_test

RNG = np.random.default_rng(0)
A = RNG.normal(size=(4, 3, 4, 3))
A = 0.5 * (A + A.transpose(2, 3, 0, 1))  # symmetric, on (4, 3) arrays
B = RNG.normal(size=(4, 3))
X0, DELTA = RNG.normal(size=(4, 3)), RNG.normal(size=(4, 3))


def quadratic(x):
    return 0.5 * np.tensordot(x, np.tensordot(A, x, 2), 2) + np.vdot(B, x) + 3.0


def quadratic_gradient(x):
    return np.tensordot(A, x, 2) + B


def test_quadratic_with_exact_gradient_has_rate_two():
    r = taylor_test(quadratic, X0, DELTA, quadratic_gradient(X0), h0=0.1, halvings=4)
    assert isinstance(r, TaylorResult)
    np.testing.assert_array_equal(r.steps, 0.1 / 2.0 ** np.arange(5))
    assert r.value == quadratic(X0)
    assert r.slope == pytest.approx(np.vdot(quadratic_gradient(X0), DELTA), rel=1e-14)
    curvature = np.vdot(DELTA, np.tensordot(A, DELTA, 2))
    # a quadratic: the second-order remainder is h²/2 δᵀAδ exactly, up to round-off
    np.testing.assert_allclose(r.second_order, 0.5 * r.steps**2 * abs(curvature), rtol=1e-9)
    np.testing.assert_allclose(r.rates, 2.0, atol=1e-6)
    np.testing.assert_allclose(r.order_rates(1), 1.0, atol=0.2)  # without the gradient
    assert r.min_rate == pytest.approx(2.0, abs=1e-6)
    assert r.fit_rate() == pytest.approx(2.0, abs=1e-6)
    assert r.resolved.all() and not r.exact
    # with the Hessian the third-order remainder is round-off: nothing left
    r3 = taylor_test(quadratic, X0, DELTA, quadratic_gradient(X0), curvature=curvature, h0=0.1)
    assert np.all(r3.third_order <= r3.roundoff)


def test_value_and_gradient_function_and_given_value():
    def value_and_gradient(x):
        return quadratic(x), quadratic_gradient(x)

    calls = []

    def J(x):
        calls.append(x.copy())
        return quadratic(x)

    r = taylor_test(J, X0, DELTA, value_and_gradient, h0=0.1, halvings=3)
    assert len(calls) == 4  # J(x0) came with the gradient
    np.testing.assert_allclose(r.rates, 2.0, atol=1e-6)
    calls.clear()
    given = taylor_test(J, X0, DELTA, quadratic_gradient(X0), value=quadratic(X0), h0=0.1, halvings=3)
    assert len(calls) == 4
    np.testing.assert_array_equal(given.second_order, r.second_order)
    calls.clear()
    taylor_test(J, X0, DELTA, quadratic_gradient(X0), h0=0.1, halvings=3)
    assert len(calls) == 5  # J(x0) evaluated too
    np.testing.assert_array_equal(calls[0], X0)


@pytest.mark.parametrize("wrong", [1.01, -1.0, 0.0], ids=["scaled", "flipped", "zero"])
def test_wrong_gradient_has_rate_one(wrong):
    r = taylor_test(quadratic, X0, DELTA, wrong * quadratic_gradient(X0), h0=1e-3, halvings=4)
    # the error (wrong − 1) h gᵀδ dominates: first order
    assert r.min_rate == pytest.approx(1.0, abs=0.05), r
    assert r.fit_rate() == pytest.approx(1.0, abs=0.05)
    assert not np.all(np.abs(r.rates - 2) < 0.2)
    assert "rate" in r.table() and str(r) == r.table()


def test_linear_function_has_second_order_remainders_at_round_off():
    def linear(x):
        return np.vdot(B, x) + 3.0

    r = taylor_test(linear, X0, DELTA, B, h0=0.1, halvings=4)
    assert r.exact and not r.resolved.any()
    assert np.all(r.second_order <= r.roundoff)
    assert r.roundoff < 1e-11 and r.second_order.max() < 1e-13
    assert r.min_rate == float("inf")
    np.testing.assert_allclose(r.order_rates(1), 1.0, atol=1e-9)
    # a wrong gradient of a linear function is resolved at every step, at rate 1
    wrong = taylor_test(linear, X0, DELTA, 1.01 * B, h0=0.1, halvings=4)
    assert not wrong.exact and wrong.min_rate == pytest.approx(1.0, abs=1e-6)


def test_central_difference_and_its_error():
    def J(x):
        return float(np.sum(np.sin(x)))

    x0 = np.linspace(0.1, 1.0, 7)
    direction = np.cos(3 * x0)
    r = taylor_test(J, x0, direction, np.cos(x0), h0=0.1, halvings=4, central_step=1e-4)
    np.testing.assert_allclose(r.rates, 2.0, atol=0.1)
    assert r.central_step == 1e-4
    assert r.central_error < 1e-7
    assert r.central == pytest.approx(np.vdot(np.cos(x0), direction), rel=1e-7)
    with pytest.raises(ValueError, match="central_step"):
        taylor_test(J, x0, direction, np.cos(x0)).central_error
    with pytest.raises(ValueError, match="order 3"):
        r.remainders(3)


def test_bad_arguments():
    g = quadratic_gradient(X0)
    with pytest.raises(ValueError, match="direction"):
        taylor_test(quadratic, X0, DELTA.ravel(), g)
    with pytest.raises(ValueError, match="gradient"):
        taylor_test(quadratic, X0, DELTA, g.ravel())
    with pytest.raises(ValueError, match="h0"):
        taylor_test(quadratic, X0, DELTA, g, h0=0.0)
    with pytest.raises(ValueError, match="halving"):
        taylor_test(quadratic, X0, DELTA, g, halvings=0)


def test_result_is_frozen_and_read_only():
    r = taylor_test(quadratic, X0, DELTA, quadratic_gradient(X0))
    with pytest.raises(AttributeError):
        r.slope = 0.0
    with pytest.raises(ValueError):
        r.second_order[0] = 0.0


def test_imports_neither_petsc_nor_fem():
    code = ("import sys, mscap.testing; bad = [m for m in sys.modules if m.startswith(('petsc4py', "
            "'mpi4py', 'scipy', 'mscap.fem', 'mscap.mesh', 'mscap.design'))]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
