"""Capacitor layouts: the k plate outlines in the sheet plane (mm).

Both conductive layers carry the same outlines (paper §4.1), so a layout is just k
simple polygons inside the sheet, kept apart by a minimum gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mscap.errors import GeometryError
from mscap.geometry import polygons as geometry

__all__ = ["Layout", "grid_layout", "check_layout", "min_gap_mm", "SHAPES"]

SHAPES = ("square", "disk", "rounded_square")


@dataclass(frozen=True)
class Layout:
    """k capacitor outlines, each a counter-clockwise ``(n_j, 2)`` array in mm."""

    outlines: tuple[np.ndarray, ...]

    def __post_init__(self):
        frozen = []
        for outline in self.outlines:
            outline = geometry.ccw(outline)
            outline.setflags(write=False)
            frozen.append(outline)
        object.__setattr__(self, "outlines", tuple(frozen))

    @property
    def k(self) -> int:
        """Number of capacitors."""
        return len(self.outlines)

    def areas_mm2(self) -> np.ndarray:
        """Plate area of each capacitor (mm²)."""
        return np.array([geometry.signed_area(o) for o in self.outlines])


def grid_layout(shape: str, rows: int, columns: int, size_mm: float,
                pitch_mm: tuple[float, float], center_mm: tuple[float, float],
                spacing_mm: float, corner_radius_mm: float = 0.0) -> Layout:
    """A ``rows × columns`` array of identical plates, row 0 at the bottom.

    ``size_mm`` is the side (square shapes) or diameter (disk); curved parts get a
    vertex about every ``spacing_mm``. Capacitors are numbered row by row.
    """
    px, py = pitch_mm
    xs = center_mm[0] + px * (np.arange(columns) - 0.5 * (columns - 1))
    ys = center_mm[1] + py * (np.arange(rows) - 0.5 * (rows - 1))
    outlines = []
    for y in ys:
        for x in xs:
            if shape == "square":
                outlines.append(geometry.square((x, y), size_mm))
            elif shape == "disk":
                outlines.append(geometry.disk((x, y), size_mm, spacing_mm))
            elif shape == "rounded_square":
                outlines.append(geometry.rounded_square((x, y), size_mm, corner_radius_mm, spacing_mm))
            else:
                raise GeometryError(f"unknown shape {shape!r}; expected one of {', '.join(SHAPES)}")
    return Layout(tuple(outlines))


def check_layout(layout: Layout, sheet_outline: np.ndarray, min_gap_mm: float) -> None:
    """Raise :class:`GeometryError` unless every outline is simple, lies inside the
    sheet at least ``min_gap_mm`` from its edge, and is ``min_gap_mm`` from every other."""
    sheet_edges = geometry.edges(sheet_outline)
    for j, outline in enumerate(layout.outlines):
        if len(outline) < 3:
            raise GeometryError(f"capacitor {j} has {len(outline)} vertices; need at least 3", j)
        crossings = geometry.self_intersections(outline)
        if crossings:
            a, b = crossings[0]
            raise GeometryError(f"capacitor {j} outline intersects itself (edges {a} and {b})", j)
        if abs(geometry.signed_area(outline)) <= 0:
            raise GeometryError(f"capacitor {j} has zero area", j)
        outside = ~geometry.points_in_polygon(outline, sheet_outline)
        if outside.any() or geometry.segments_cross(geometry.edges(outline), sheet_edges).any():
            i = int(np.argmax(outside)) if outside.any() else 0
            raise GeometryError(f"capacitor {j} lies outside the sheet "
                                f"(vertex {i} at {tuple(np.round(outline[i], 6))} mm)", j)
        margin = geometry.boundary_distance(outline, sheet_outline)
        if margin < min_gap_mm:
            raise GeometryError(f"capacitor {j} is {margin:.4g} mm from the sheet edge; "
                                f"the minimum gap is {min_gap_mm:g} mm", j)
    for j in range(layout.k):
        for i in range(j):
            p, q = layout.outlines[i], layout.outlines[j]
            if geometry.polygons_intersect(p, q):
                raise GeometryError(f"capacitors {i} and {j} overlap", j)
            gap = geometry.boundary_distance(p, q)
            if gap < min_gap_mm:
                raise GeometryError(f"capacitors {i} and {j} are {gap:.4g} mm apart; "
                                    f"the minimum gap is {min_gap_mm:g} mm", j)


def min_gap_mm(outlines, sheet_outline_mm: np.ndarray) -> float:
    """Smallest distance (mm) between two different outlines, or an outline and the sheet
    edge: the gap :func:`check_layout` holds to ``min_gap_mm`` (0 if two outlines overlap
    or one holds the other)."""
    polygons = [np.asarray(o, dtype=float) for o in outlines]
    sheet = np.asarray(sheet_outline_mm, dtype=float)
    gap = min(geometry.boundary_distance(p, sheet) for p in polygons)
    for i, a in enumerate(polygons):
        for b in polygons[i + 1:]:
            if geometry.points_in_polygon(a[:1], b)[0] or geometry.points_in_polygon(b[:1], a)[0]:
                return 0.0
            gap = min(gap, geometry.boundary_distance(a, b))
    return gap
