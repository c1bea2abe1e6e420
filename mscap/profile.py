"""Where the time goes: wall time per kind of work, summed over a process.

The numerical kernels mark themselves with :func:`section` (or the :func:`timed`
decorator): ``"assembly"`` (element loops: residuals, Hessians, stiffness matrices and
their derivatives for the adjoints), ``"factorisation"`` and ``"solve"`` (every PETSc
linear solve goes through :class:`mscap.fem.petsc.LinearSolver`), ``"meshing"`` (gmsh and
the extrusion). Sections do not nest: time inside a section that is already open counts
for the outer one only. Whatever a measured total leaves over is Python and numpy work
outside the kernels (bookkeeping, transfers, line-search logic), which
:func:`split` reports as ``"other"``.

    from mscap import profile
    profile.reset()
    ...                                   # anything
    print(profile.split(total_s))         # {"assembly": .., ..., "other": ..}

The counters cost two ``perf_counter`` calls per kernel call.

PETSc's ``-log_view`` shows the same kinds: once PETSc is initialised (every ``mscap``
command does so first), each section also runs a PETSc log event of its kind (class
``mscap``), and these nest freely, unlike the counters. :func:`phase` marks the larger
phases, ``"Newton"`` (an elastic pose's load path) and ``"adjoint"`` (a pose's rest
gradient), as a PETSc log stage and event of that name: ``-log_view`` then splits PETSc's
own events (``KSPSolve``, ``MatCholFctrNum``, ...) between the electrostatic main stage
and these two.
"""

from __future__ import annotations

import functools
import sys
import time
from contextlib import contextmanager

__all__ = ["KINDS", "section", "timed", "phase", "reset", "totals", "split"]

KINDS = ("meshing", "assembly", "factorisation", "solve")

_totals = dict.fromkeys(KINDS, 0.0)
_inside = False  # a section is open: inner ones count for it
_events: dict[str, object] = {}  # PETSc log events and stages by name, registered on first use
_stages: dict[str, object] = {}


def _petsc():
    """petsc4py's ``PETSc`` if something has initialised it, else ``None``: logging never
    initialises PETSc (``mscap mesh`` and the HDF5 tools run without it)."""
    return sys.modules.get("petsc4py.PETSc")


@functools.cache
def _log_class(PETSc):
    return PETSc.Log.Class("mscap")


def _event(PETSc, name: str):
    if name not in _events:
        _events[name] = PETSc.Log.Event(name, _log_class(PETSc))
    return _events[name]


@contextmanager
def section(kind: str):
    """Count the wall time of the block as ``kind`` (one of :data:`KINDS`), and log it as
    the PETSc event ``kind``."""
    global _inside
    if kind not in _totals:
        raise ValueError(f"unknown profile section {kind!r}; expected one of {', '.join(KINDS)}")
    PETSc = _petsc()
    event = None if PETSc is None else _event(PETSc, kind)
    if event is not None:
        event.begin()
    outer, _inside = not _inside, True
    start = time.perf_counter()
    try:
        yield
    finally:
        if outer:
            _totals[kind] += time.perf_counter() - start
            _inside = False
        if event is not None:
            event.end()


def timed(kind: str):
    """Decorator form of :func:`section`."""
    def wrap(function):
        @functools.wraps(function)
        def inner(*args, **kwargs):
            with section(kind):
                return function(*args, **kwargs)
        return inner
    return wrap


@contextmanager
def phase(name: str):
    """The block as the PETSc log stage and event ``name`` (no wall-time counter); also a
    decorator. Enter it outside any :func:`section`: a PETSc event must end in the stage
    it began in."""
    PETSc = _petsc()
    if PETSc is None:
        yield
        return
    if name not in _stages:
        _stages[name] = PETSc.Log.Stage(name)
    stage, event = _stages[name], _event(PETSc, name)
    stage.push()
    event.begin()
    try:
        yield
    finally:
        event.end()
        stage.pop()


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
