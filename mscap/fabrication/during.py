"""Routing during the optimisation (``[fabrication] route_during_optimisation``): the
optimiser's capacitances are those of the sensor as it will be wired.

The leads' share of every reading,

    ΔC(pose, c) = C_wired(pose, c) − C_plates(pose, c),

is simulated on the wired mesh (:mod:`mscap.fabrication.wired`): the routed nets, and the
design's plates alone, on the very same meshes (electrostatic and elastic) and poses, so that the
difference is the wiring's alone (the leads' overlaps and fringes, the stretch of both,
and their stiffness). Between two routes the optimiser sees

    C(q) = C_plates(q) + ΔC,

its own plate capacitances on its own meshes plus that share held fixed: J and its
gradient are exact for a fixed route, and the design is routed again where the optimiser
changes its meshes (every remesh and control refinement) and at the end, so the last
evaluation is the routed sensor's. The route itself has no gradient to give: it is a path
on a grid, constant in q except where it jumps to another path or slot assignment. How
much ΔC moves between two routes is measured at every re-route (:class:`Reroute`) and
reported (docs/fabrication.md, "Routing during the optimisation").
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np

from mscap.errors import FabricationError

__all__ = ["WiringOffset", "Reroute", "wiring_offset"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WiringOffset:
    """The leads' share ``offset_pF`` ``(n_poses, k)`` of every reading of the design poses
    at one route (``None``: no route yet, the plates alone), ``summary`` of that route,
    ``time_s`` to route and simulate it."""

    offset_pF: np.ndarray | None
    summary: str
    time_s: float


@dataclass(frozen=True)
class Reroute:
    """One re-route: where (``event``, ``iteration``), how far the leads' share moved since
    the last route at the same plate capacitances (``offset_change_pF``, the largest over
    poses and capacitors, and ``J_before``/``J_after``, J with the old and the new share),
    the route and its cost."""

    event: str
    iteration: int
    offset_change_pF: float
    J_before: float
    J_after: float
    summary: str
    time_s: float


def wiring_offset(scene, sheet, outlines, progress=None, poses=None) -> WiringOffset:
    """Route ``outlines`` under ``scene``'s ``[fabrication]`` rules and simulate the leads'
    share of every reading over ``poses`` (the design poses; default the scene's) on
    ``sheet``'s mesh sizes (the run's, :func:`mscap.scene.sizing.sheet_for`).

    Raises
    ------
    FabricationError
        The outlines cannot be routed (:func:`mscap.fabrication.router.route`).
    """
    from mscap.fabrication.router import route
    from mscap.fabrication.wired import plates_only, readings, wiring_of
    from mscap.geometry.layout import Layout

    started = time.perf_counter()
    outlines = [np.asarray(o, dtype=float) for o in outlines]
    routing = route(outlines, scene.sheet_outline_mm, scene.fabrication)
    designed = replace(sheet, layout=Layout(tuple(outlines)))
    wiring = wiring_of(routing)
    wired, _ = readings(scene, designed, wiring, poses=poses)
    plates, _ = readings(scene, designed, plates_only(outlines, meshed_like=wiring), poses=poses)
    offset = wired - plates
    if not np.isfinite(offset).all():
        raise FabricationError(f"the routed design's readings are not finite ({routing.summary()})")
    summary = routing.summary()
    elapsed = time.perf_counter() - started
    if progress:
        progress(f"routed: {summary}; the leads add {offset.min():+.3g} … {offset.max():+.3g} pF ({elapsed:.1f} s)")
    return WiringOffset(offset, summary, elapsed)
