"""Objective terms as objects (after fireshape's objectives): a :class:`Term` has a value
and a gradient, terms add (``a + b`` → :class:`Sum`) and scale (``w * a`` →
:class:`Weighted`); and the soft minimum shared by the distance terms."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Term", "Weighted", "Sum", "soft_min"]


def soft_min(values: np.ndarray, tau: float) -> tuple[float, np.ndarray]:
    """−τ log Σ exp(−v/τ) (≤ min v) and its gradient (a softmax summing to 1), evaluated
    about the minimum: no overflow or underflow at any v/τ."""
    low = values.min()
    weight = np.exp(-(values - low) / tau)  # in (0, 1], the minimum gives 1
    total = weight.sum()
    return float(low - tau * np.log(total)), weight / total


def _scaled(g, w: float):
    return tuple(w * x for x in g) if isinstance(g, tuple) else w * g


def _added(g, h):
    return tuple(x + y for x, y in zip(g, h)) if isinstance(g, tuple) else g + h


class Term:
    """A term maps its input (C, or a sequence of outlines) to a float and a gradient of
    the same shape (an array, or a tuple of ``(m_i, 2)`` arrays)."""

    def value_and_gradient(self, x):
        raise NotImplementedError

    def value(self, x) -> float:
        return self.value_and_gradient(x)[0]

    def gradient(self, x):
        return self.value_and_gradient(x)[1]

    def __add__(self, other: Term) -> Sum:
        return Sum((self, other))

    def __rmul__(self, weight: float) -> Weighted:
        return Weighted(self, float(weight))


@dataclass(frozen=True)
class Weighted(Term):
    """``weight`` times a term (a zero weight gives 0 even where the term is infinite)."""

    term: Term
    weight: float

    def value(self, x) -> float:
        return 0.0 if self.weight == 0 else self.weight * self.term.value(x)

    def value_and_gradient(self, x):
        v, g = self.term.value_and_gradient(x)
        return (0.0 if self.weight == 0 else self.weight * v), _scaled(g, self.weight)


@dataclass(frozen=True)
class Sum(Term):
    """The sum of terms of the same input."""

    terms: tuple

    def value(self, x) -> float:
        return float(sum(t.value(x) for t in self.terms))

    def value_and_gradient(self, x):
        value, grad = self.terms[0].value_and_gradient(x)
        for t in self.terms[1:]:
            v, g = t.value_and_gradient(x)
            value, grad = value + v, _added(grad, g)
        return value, grad
