"""Taylor tests of gradients: one harness for every gradient test of mscap.

A gradient ``g`` of a value function ``J`` at ``x`` is checked along a direction ``δ``
by the Taylor remainders over a sequence of halving steps ``h``:

- first order, ``|J(x + hδ) − J(x)|``, falls like ``h`` (rate 1) whatever ``g`` is;
- second order, ``|J(x + hδ) − J(x) − h gᵀδ|``, falls like ``h²`` (rate 2) only if
  ``gᵀδ`` is the directional derivative; a wrong gradient leaves rate 1;
- third order, given the curvature ``δᵀHδ`` of a Hessian ``H``,
  ``|J(x + hδ) − J(x) − h gᵀδ − h²/2 δᵀHδ|`` falls like ``h³``.

The observed rate between two successive steps is ``log2`` of the ratio of their
remainders (the steps halve). This is pyadjoint's ``verification.taylor_test``
(Farrell et al.), here for functions of numpy arrays of any shape, returning every
remainder rather than the smallest rate only. Remainders at or below round-off (``rtol``
times the size of ``J``) carry no rate: :attr:`TaylorResult.min_rate` leaves them out,
and is infinite when every second-order remainder is round-off (``J`` is linear along
``δ``, or quadratic and ``h`` tiny). A central difference at a separate, small step can be
evaluated alongside, for tests that also bound the relative error of the slope.

Only numpy: the harness knows nothing of meshes or solvers; the value function does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["TaylorResult", "taylor_test"]


@dataclass(frozen=True, eq=False)
class TaylorResult:
    """Remainders of a Taylor test and the rates observed over the halving steps.

    Attributes
    ----------
    steps : numpy.ndarray
        The steps ``h0 / 2**i``, ``i = 0 … halvings``, shape ``(halvings + 1,)``.
    value : float
        ``J(x0)``.
    slope : float
        The directional derivative claimed by the gradient, ``gᵀδ``.
    changes : numpy.ndarray
        ``J(x0 + hδ) − J(x0)`` at each step.
    first_order : numpy.ndarray
        ``|J(x0 + hδ) − J(x0)|``: falls like ``h``.
    second_order : numpy.ndarray
        ``|J(x0 + hδ) − J(x0) − h gᵀδ|``: falls like ``h²`` if the gradient is right.
    third_order : numpy.ndarray or None
        ``|J(x0 + hδ) − J(x0) − h gᵀδ − h²/2 δᵀHδ|`` if a curvature was given, else None.
    curvature : float or None
        ``δᵀHδ`` as given.
    roundoff : float
        Remainders at or below this (``rtol`` times the largest ``|J|`` evaluated) are
        round-off.
    central : float or None
        ``(J(x0 + hδ) − J(x0 − hδ)) / 2h`` at ``central_step``, if one was given.
    central_step : float or None
        The step of :attr:`central`.
    """

    steps: np.ndarray
    value: float
    slope: float
    changes: np.ndarray
    first_order: np.ndarray
    second_order: np.ndarray
    third_order: np.ndarray | None
    curvature: float | None
    roundoff: float
    central: float | None
    central_step: float | None

    def remainders(self, order: int = 2) -> np.ndarray:
        """The remainders of the given order (1, 2, or 3 if a curvature was given).

        Parameters
        ----------
        order : int, optional
            1: without the gradient, 2: with it, 3: with the curvature too.

        Returns
        -------
        numpy.ndarray
            One remainder per step.
        """
        if order == 1:
            return self.first_order
        if order == 2:
            return self.second_order
        if order == 3 and self.third_order is not None:
            return self.third_order
        raise ValueError(f"no remainders of order {order}" + (" (no curvature given)" if order == 3 else ""))

    def order_rates(self, order: int = 2) -> np.ndarray:
        """Observed rates ``log2(r_i / r_{i+1})`` of the remainders of an order.

        Parameters
        ----------
        order : int, optional
            As in :meth:`remainders`.

        Returns
        -------
        numpy.ndarray
            One rate per halving, shape ``(halvings,)``; round-off remainders included
            (their rates are noise, possibly ``inf`` or ``nan``).
        """
        r = self.remainders(order)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log2(r[:-1] / r[1:])

    @property
    def rates(self) -> np.ndarray:
        """Observed rates of the second-order remainders, one per halving (≈ 2 if right)."""
        return self.order_rates(2)

    @property
    def resolved(self) -> np.ndarray:
        """Per halving: True where both second-order remainders lie above round-off."""
        above = self.second_order > self.roundoff
        return above[:-1] & above[1:]

    @property
    def exact(self) -> bool:
        """True if every second-order remainder is round-off (nothing left to converge)."""
        return bool(np.all(self.second_order <= self.roundoff))

    @property
    def min_rate(self) -> float:
        """The smallest second-order rate over halvings resolved above round-off.

        ``inf`` if no halving is resolved (:attr:`exact`, or at most one remainder above
        round-off): the gradient is then exact to round-off along the direction.
        """
        rates = self.rates[self.resolved]
        return float(rates.min()) if rates.size else float("inf")

    def fit_rate(self, order: int = 2) -> float:
        """Slope of a least-squares line through ``(log h, log r)`` over all steps.

        Parameters
        ----------
        order : int, optional
            As in :meth:`remainders`.

        Returns
        -------
        float
            The fitted rate: less sensitive to one noisy step than :attr:`min_rate`.
        """
        return float(np.polyfit(np.log(self.steps), np.log(self.remainders(order)), 1)[0])

    @property
    def central_error(self) -> float:
        """``|central − slope| / |slope|``, the relative error of the claimed slope."""
        if self.central is None:
            raise ValueError("no central difference: pass central_step to taylor_test")
        return abs(self.central - self.slope) / abs(self.slope)

    def table(self) -> str:
        """The steps, remainders and rates as text, one line per step (for messages)."""
        lines = [f"slope {self.slope:.6e}, round-off {self.roundoff:.1e}",
                 f"{'h':>11} {'|dJ|':>11} {'|dJ-hg.d|':>11} {'rate':>6}"
                 + (f" {'3rd order':>11} {'rate':>6}" if self.third_order is not None else "")]
        rates = np.concatenate([[np.nan], self.rates])
        rates3 = np.concatenate([[np.nan], self.order_rates(3)]) if self.third_order is not None else None
        for i, h in enumerate(self.steps):
            line = f"{h:11.4e} {self.first_order[i]:11.4e} {self.second_order[i]:11.4e} {rates[i]:6.3f}"
            if rates3 is not None:
                line += f" {self.third_order[i]:11.4e} {rates3[i]:6.3f}"
            lines.append(line)
        if self.central is not None:
            lines.append(f"central difference at h = {self.central_step:.1e}: {self.central:.6e} "
                         f"(relative error {self.central_error:.1e})")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.table()


def taylor_test(J: Callable[[np.ndarray], float], x0: np.ndarray, direction: np.ndarray,
                gradient: np.ndarray | Callable[[np.ndarray], tuple[float, np.ndarray]], *,
                h0: float = 1e-2, halvings: int = 4, value: float | None = None,
                curvature: float | None = None, central_step: float | None = None,
                rtol: float = 1e-13) -> TaylorResult:
    """Taylor test of a gradient: remainders at steps ``h0 / 2**i`` along ``direction``.

    Parameters
    ----------
    J : callable
        The value function, ``J(x) -> float`` for ``x`` of the shape of ``x0``.
    x0 : numpy.ndarray
        The point of the test, any shape.
    direction : numpy.ndarray
        ``δ``, the shape of ``x0``.
    gradient : numpy.ndarray or callable
        ``∇J(x0)`` (the shape of ``x0``), or a function ``x -> (J(x), ∇J(x))`` called once
        at ``x0`` (its value is used unless ``value`` is given).
    h0 : float, optional
        The first step.
    halvings : int, optional
        How many times the step is halved: ``halvings + 1`` steps, ``halvings`` rates.
    value : float, optional
        ``J(x0)`` if already known (e.g. from the solve that gave the gradient); else it
        is evaluated.
    curvature : float, optional
        ``δᵀ ∇²J(x0) δ``: adds the third-order remainders.
    central_step : float, optional
        If given, ``J(x0 ± central_step δ)`` are evaluated (after the Taylor steps) for
        the central difference :attr:`TaylorResult.central`.
    rtol : float, optional
        Remainders at or below ``rtol`` times the largest ``|J|`` evaluated at the steps
        count as round-off (left out of :attr:`TaylorResult.min_rate`).

    Returns
    -------
    TaylorResult
        Steps, remainders of each order and the observed rates.

    Raises
    ------
    ValueError
        If the shapes disagree, ``h0`` is not positive or ``halvings < 1``.

    Examples
    --------
    >>> import numpy as np
    >>> A = np.array([[2.0, 1.0], [1.0, 3.0]])
    >>> r = taylor_test(lambda x: 0.5 * x @ A @ x, np.ones(2), np.array([1.0, -0.5]), A @ np.ones(2))
    >>> bool(np.allclose(r.rates, 2.0))
    True
    """
    x0 = np.asarray(x0, dtype=float)
    direction = np.asarray(direction, dtype=float)
    if direction.shape != x0.shape:
        raise ValueError(f"direction has shape {direction.shape}, x0 has {x0.shape}")
    if not h0 > 0:
        raise ValueError(f"h0 must be positive, got {h0}")
    if halvings < 1:
        raise ValueError(f"at least one halving is needed for a rate, got {halvings}")
    if callable(gradient):
        j0, gradient = gradient(x0)
        value = j0 if value is None else value
    gradient = np.asarray(gradient, dtype=float)
    if gradient.shape != x0.shape:
        raise ValueError(f"gradient has shape {gradient.shape}, x0 has {x0.shape}")
    value = float(J(x0)) if value is None else float(value)
    slope = float(np.vdot(gradient, direction))

    steps = h0 / 2.0 ** np.arange(halvings + 1)
    values = np.array([float(J(x0 + h * direction)) for h in steps])
    changes = values - value
    first = np.abs(changes)
    linear = changes - steps * slope
    second = np.abs(linear)
    third = None if curvature is None else np.abs(linear - 0.5 * steps * steps * curvature)
    central = None
    if central_step is not None:
        central = (float(J(x0 + central_step * direction)) - float(J(x0 - central_step * direction))) / (2 * central_step)
    roundoff = rtol * max(abs(value), float(np.abs(values).max()))
    for a in (steps, changes, first, second, third):
        if a is not None:
            a.flags.writeable = False
    return TaylorResult(steps=steps, value=value, slope=slope, changes=changes, first_order=first,
                        second_order=second, third_order=third,
                        curvature=None if curvature is None else float(curvature), roundoff=roundoff,
                        central=central, central_step=None if central_step is None else float(central_step))
