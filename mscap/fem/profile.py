"""Where the time goes: wall time per kind of work, summed over a process.

The numerical kernels mark themselves with :func:`section` (or the :func:`timed`
decorator): ``"assembly"`` (element loops: residuals, Hessians, stiffness matrices and
their derivatives for the adjoints), ``"factorisation"`` and ``"solve"`` (every PETSc
linear solve goes through :class:`mscap.fem.petsc.LinearSolver`), ``"meshing"`` (gmsh and
the extrusion). Sections do not nest: time inside a section that is already open counts
for the outer one only. Whatever a measured total leaves over is Python and numpy work
outside the kernels (bookkeeping, transfers, line-search logic), which
:func:`split` reports as ``"other"``.

    from mscap.fem import profile
    profile.reset()
    ...                                   # anything
    print(profile.split(total_s))         # {"assembly": .., ..., "other": ..}

The counters cost two ``perf_counter`` calls per kernel call.
"""

from __future__ import annotations

import functools
import time
from contextlib import contextmanager

__all__ = ["KINDS", "section", "timed", "reset", "totals", "split"]

KINDS = ("meshing", "assembly", "factorisation", "solve")

_totals = dict.fromkeys(KINDS, 0.0)
_inside = False  # a section is open: inner ones count for it


@contextmanager
def section(kind: str):
    """Count the wall time of the block as ``kind`` (one of :data:`KINDS`)."""
    global _inside
    if kind not in _totals:
        raise ValueError(f"unknown profile section {kind!r}; expected one of {', '.join(KINDS)}")
    if _inside:
        yield
        return
    _inside = True
    start = time.perf_counter()
    try:
        yield
    finally:
        _totals[kind] += time.perf_counter() - start
        _inside = False


def timed(kind: str):
    """Decorator form of :func:`section`."""
    def wrap(function):
        @functools.wraps(function)
        def inner(*args, **kwargs):
            with section(kind):
                return function(*args, **kwargs)
        return inner
    return wrap


def reset() -> None:
    """Zero every counter."""
    for kind in _totals:
        _totals[kind] = 0.0


def totals() -> dict[str, float]:
    """Seconds per kind since the last :func:`reset`."""
    return dict(_totals)


def split(total_s: float) -> dict[str, float]:
    """:func:`totals` plus ``"other"`` = ``total_s`` minus their sum, and ``"total"``."""
    out = totals()
    out["other"] = total_s - sum(out.values())
    out["total"] = total_s
    return out
