"""Lead centre lines: trimmed to where they leave and reach a conductor, pulled straight
where the rules allow, and buffered into the lead's outline.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import LineString

from mscap.scene.settings import FabricationSettings

__all__ = ["trim_path", "pull_straight", "lead_outline"]


def lead_outline(path: np.ndarray, f: FabricationSettings):
    """The lead along centre line ``path``: buffered by half the trace width, round joins."""
    return LineString(path).buffer(0.5 * f.trace_width_mm, quad_segs=8)


def trim_path(points: np.ndarray, start, end) -> np.ndarray:
    """Drop the leading points inside the conductor a path leaves (but its last one there)
    and the trailing points inside the plate it reaches (but its first one there)."""
    inside_start = shapely.contains_xy(start, points[:, 0], points[:, 1])
    inside_end = shapely.contains_xy(end, points[:, 0], points[:, 1])
    first = 0
    while first + 1 < len(points) and inside_start[first + 1]:
        first += 1
    last = len(points) - 1
    while last - 1 > first and inside_end[last - 1]:
        last -= 1
    return points[first:last + 1]


def pull_straight(points: np.ndarray, forbidden, allowed, other, f: FabricationSettings,
                  costly=None) -> np.ndarray:
    """The path with every run of points replaced by a straight lead where that lead
    keeps ``clearance_mm`` from ``forbidden``, stays in ``allowed`` and lies over no more
    of ``other`` (the other layer) nor of ``costly`` (what the grid search paid extra for:
    a straight lead across it would undo the search's detour) than the run it replaces."""
    half = 0.5 * f.trace_width_mm + 1e-3
    keep_out = forbidden.buffer(f.clearance_mm, quad_segs=8) if not forbidden.is_empty else None
    if keep_out is not None:
        shapely.prepare(keep_out)
    shapely.prepare(allowed)
    weighed = [g for g in (other, costly) if g is not None and not g.is_empty]
    for g in weighed:
        shapely.prepare(g)

    def clear(a, b):
        lead = LineString(points[[a, b]]).buffer(half, quad_segs=4)
        if not allowed.contains(lead) or (keep_out is not None and keep_out.intersects(lead)):
            return False
        run = None
        for g in weighed:
            if not g.intersects(lead):
                continue
            run = run if run is not None else LineString(points[a:b + 1]).buffer(half, quad_segs=4)
            if lead.intersection(g).area > run.intersection(g).area + 1e-6:
                return False
        return True

    out = [0]
    a = 0
    while a < len(points) - 1:
        b = a + 1
        while b + 1 < len(points) and clear(a, b + 1):
            b += 1
        out.append(b)
        a = b
    return points[out]
