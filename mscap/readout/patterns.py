"""Which lead patterns to read (paper appendix C): the default set and a set chosen for
the condition number of the measurement matrix (:mod:`mscap.readout.array` has the model).

An overdetermined, well-conditioned set keeps the least-squares recovery from
amplifying reading noise; ``docs/readout.md`` has the measured condition numbers.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from mscap.readout.array import (MAX_DEFAULT_ALL_LEADS, MAX_ENUMERATED_CANDIDATE_LEADS, MAX_RANDOM_CANDIDATES,
                      CapacitorArray, ReadoutError, _checked_patterns, _inseparable, _rows, all_patterns,
                      measurement_matrix, random_patterns)

__all__ = ["PatternChoice", "optimise_patterns", "default_patterns", "MAX_OPTIMISED_PATTERNS"]

log = logging.getLogger(__name__)

#: The most readings an optimised set may have: four times every pattern of the largest
#: array read whole by default (2**MAX_DEFAULT_ALL_LEADS); the greedy start and each
#: exchange sweep cost readings x candidates.
MAX_OPTIMISED_PATTERNS = 4 * 2**MAX_DEFAULT_ALL_LEADS


@dataclass(frozen=True, eq=False)
class PatternChoice:
    """An optimised pattern set (may repeat a pattern: a repeated reading averages noise).

    ``start_condition_number`` is that of the greedy start, ``condition_number`` that
    after the exchange sweeps.
    """

    patterns: np.ndarray
    condition_number: float
    start_condition_number: float
    candidates: int
    sweeps: int


def _cond_of_gram(gram: np.ndarray) -> float:
    """cond(M) from the eigenvalues of its Gram matrix MᵀM."""
    lam = np.linalg.eigvalsh(gram)
    return math.sqrt(lam[-1] / lam[0]) if lam[0] > lam[-1] * 1e-13 else math.inf


def _cond_with_row(gram: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """cond(M) after appending each of ``rows`` to M, given ``gram = MᵀM``.

    The extreme eigenvalues of ``gram + x xᵀ`` are roots of the secular equation
    ``1 + Σ z_i² / (μ_i − λ) = 0`` (μ, V the eigenpairs of gram, z = Vᵀx) and interlace:
    λ_min in [μ_1, μ_2], λ_max in [μ_u, μ_u + |z|²]. Bisection there costs O(u) per
    candidate instead of an O(u³) eigensolve.
    """
    mu, v = np.linalg.eigh(gram)
    z2 = (rows @ v) ** 2

    def root(lo, hi):
        for _ in range(40):       # f increases between poles: bisect on its sign
            mid = (lo + hi) / 2
            with np.errstate(divide="ignore", invalid="ignore"):
                f = 1 + (z2 / (mu - mid[:, None])).sum(axis=1)
            lo, hi = np.where(f > 0, lo, mid), np.where(f > 0, mid, hi)
        return (lo + hi) / 2

    ones = np.ones(len(rows))
    low = root(mu[0] * ones, mu[1] * ones)
    high = root(mu[-1] * ones, mu[-1] + z2.sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(low > high * 1e-13, np.sqrt(high / low), np.inf)


def _exchange(x: np.ndarray, chosen: list[int], max_sweeps: int) -> tuple[list[int], float, int]:
    """Exchange sweeps on the rows ``x[chosen]``: each chosen row in turn is replaced by
    the candidate that lowers cond(M) most, until a sweep changes nothing."""
    chosen = list(chosen)
    gram = x[chosen].T @ x[chosen]
    current = _cond_of_gram(gram)
    sweeps = 0
    for sweeps in range(1, max_sweeps + 1):
        changed = False
        for position in range(len(chosen)):
            old = x[chosen[position]]
            rest = gram - np.outer(old, old)
            best = int(np.argmin(_cond_with_row(rest, x)))
            trial = rest + np.outer(x[best], x[best])
            cond = _cond_of_gram(trial)     # exact, so that bisection round-off never accepts a worse set
            if cond < current * (1 - 1e-9):
                chosen[position], current, gram, changed = best, cond, trial, True
        if not changed:
            break
    return chosen, current, sweeps


def optimise_patterns(array: CapacitorArray, size: int | None = None, candidates=None, seed: int = 0,
                      starts: int = 4, max_sweeps: int = 50) -> PatternChoice:
    """``size`` patterns (default 2 × unknowns) minimising cond(M).

    Candidates: ``candidates`` if given, else every pattern when there are at most
    ``MAX_ENUMERATED_CANDIDATE_LEADS`` leads, else ``MAX_RANDOM_CANDIDATES`` random ones
    drawn with ``seed``. Exchange sweeps (see ``_exchange``) improve ``starts`` start
    sets: a greedy D-optimal one (each step adds the candidate of largest leverage
    xᵀ(MᵀM + εI)⁻¹x), then random draws of distinct candidates (``seed``); the best
    result wins. Exchange is a local search: one start can stall (2 × 2, 12 readings:
    7.04 from the greedy start, 6.43 from the best of four).

    Raises
    ------
    ReadoutError
        ``size`` below the number of unknowns, or candidates that cannot reach full rank.
    """
    u = array.n_unknowns
    size = 2 * u if size is None else int(size)
    if size < u:
        raise ReadoutError(f"optimised patterns: {size} readings cannot determine {u} unknowns")
    if size > MAX_OPTIMISED_PATTERNS:
        raise ReadoutError(f"optimised patterns: {size} readings; at most {MAX_OPTIMISED_PATTERNS} (every exchange "
                           f"sweep costs readings x candidates, and beyond the 2^leads distinct patterns a set "
                           f"only repeats readings)")
    rng = np.random.default_rng(seed)
    if candidates is None:
        candidates = (all_patterns(array) if array.n_leads <= MAX_ENUMERATED_CANDIDATE_LEADS
                      else random_patterns(array, MAX_RANDOM_CANDIDATES, seed))
    bits = _checked_patterns(array, candidates)
    x = _rows(array, bits)

    greedy, inverse = [], np.eye(u) / 1e-6      # (MᵀM + εI)⁻¹ of the empty set, ε = 1e-6
    for _ in range(size):
        leverage = np.einsum("ci,ij,cj->c", x, inverse, x)
        best = int(np.argmax(leverage))
        greedy.append(best)
        w = inverse @ x[best]
        inverse -= np.outer(w, w) / (1 + leverage[best])
    start = _cond_of_gram(x[greedy].T @ x[greedy])
    if not math.isfinite(start):
        raise ReadoutError(f"optimised patterns: the {len(bits)} candidate patterns cannot separate all "
                           f"{u} unknowns; " + "; ".join(_inseparable(measurement_matrix(array, bits))))
    firsts = [greedy] + [list(rng.choice(len(bits), size, replace=size > len(bits))) for _ in range(starts - 1)]
    chosen, final, sweeps = min((_exchange(x, first, max_sweeps) for first in firsts), key=lambda r: r[1])
    log.info("optimised %d patterns of %d candidates: cond %.4g (greedy start) -> %.4g (best of %d starts)",
             size, len(bits), start, final, len(firsts))
    return PatternChoice(bits[chosen], measurement_matrix(array, bits[chosen]).condition_number, start,
                         len(bits), sweeps)


def default_patterns(array: CapacitorArray, seed: int = 0) -> np.ndarray:
    """Every pattern up to ``MAX_DEFAULT_ALL_LEADS`` leads (2**(m+n) readings), else
    the optimised set of 2 × unknowns from the greedy start alone."""
    if array.n_leads <= MAX_DEFAULT_ALL_LEADS:
        return all_patterns(array)
    # Random starts did not help at this size and cost 5x (6 x 6: cond 24.34 either way,
    # 5 s with one start, 27 s with four).
    return optimise_patterns(array, seed=seed, starts=1).patterns
