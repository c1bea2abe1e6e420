"""Initial layouts from (scene, k, seed, init) alone (paper §5.1, multi-start).

Every shape is an axis-aligned square whose side is that of the scene's mean plate
(``√ mean area``). Shapes keep ``clearance × min_gap_mm`` from each other and from the
sheet edge (default 2: the gap plus the barrier's reach d̂ = gap, so the separation
barrier starts at zero); the result always passes :func:`mscap.geometry.layout.check_layout`.

- ``random``: seeded rejection sampling: centres uniform in the sheet's box, a candidate
  kept if it clears the sheet edge and the squares already placed; a layout that gets
  stuck restarts; after ``attempts`` restarts the side shrinks by 10 %.
- ``lloyd``: centroidal Voronoi relaxation (Lloyd's algorithm, discrete: the sheet
  sampled on a grid) of k seeded points; a square at each centroid, the side shrunk
  (by 10 % steps) until the layout is valid.
- ``scene``: the scene's own layout (k must match it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mscap.errors import GeometryError
from mscap.geometry import polygons as geometry
from mscap.geometry.layout import Layout, check_layout

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["LAYOUT_INITS", "Placement", "initial_layout", "random_layout", "lloyd_layout", "lloyd_points",
           "plate_size_mm", "squares_at", "square_fits", "valid_layout"]

#: Every ``init`` :func:`initial_layout` accepts (``mscap optimize --init``); the
#: multi-start schedules the seeded ones, :data:`mscap.service.selection.MULTISTART_INITS`.
LAYOUT_INITS = ("random", "lloyd", "scene")


def plate_size_mm(scene: Scene) -> float:
    """Side of a square with the scene's mean plate area."""
    return float(np.sqrt(np.abs(scene.layout.areas_mm2()).mean()))


@dataclass(frozen=True)
class Placement:
    """What placing initial squares takes of a scene: its sheet outline, the minimum gap
    between plates (mm), the squares' side (mm; the scene's mean plate's) and its file (for
    messages)."""

    sheet_outline_mm: np.ndarray
    min_gap_mm: float
    size_mm: float
    path: str = ""

    @classmethod
    def of(cls, scene: Scene) -> "Placement":
        return cls(scene.sheet_outline_mm, scene.min_gap_mm, plate_size_mm(scene), scene.path)


def valid_layout(layout: Layout, placement: Placement, clearance: float) -> bool:
    """Does ``layout`` pass :func:`check_layout` with ``clearance × min_gap_mm``?"""
    try:
        check_layout(layout, placement.sheet_outline_mm, clearance * placement.min_gap_mm)
    except GeometryError:
        return False
    return True


def square_fits(square: np.ndarray, placed: list, sheet: np.ndarray, gap: float) -> bool:
    """Is a square inside the sheet by ``gap`` and ``gap`` away from the placed squares?"""
    if not geometry.points_in_polygon(square, sheet).all():
        return False
    if geometry.boundary_distance(square, sheet) < gap:
        return False
    for other in placed:
        if geometry.polygons_intersect(square, other) or geometry.boundary_distance(square, other) < gap:
            return False
    return True


def random_layout(placement: Placement, k: int, seed: int, clearance: float = 2.0, attempts: int = 20,
                  tries_per_shape: int = 50) -> Layout:
    """k non-overlapping squares by seeded rejection sampling."""
    rng = np.random.default_rng(seed)
    sheet = placement.sheet_outline_mm
    lo, hi = sheet.min(axis=0), sheet.max(axis=0)
    gap = clearance * placement.min_gap_mm
    size = placement.size_mm
    for _ in range(20):
        for _ in range(attempts):
            placed = []
            for _ in range(tries_per_shape):
                centre = rng.uniform(lo + 0.5 * size, hi - 0.5 * size) if (hi - lo > size).all() else None
                if centre is None:
                    break
                square = geometry.square(centre, size)
                if square_fits(square, placed, sheet, gap):
                    placed.append(square)
                    if len(placed) == k:
                        layout = Layout(tuple(placed))
                        if valid_layout(layout, placement, clearance):
                            return layout
                        break
            # stuck: restart this layout
        size *= 0.9
    raise GeometryError(f"could not place {k} squares in the sheet of {placement.path} by rejection sampling")


def lloyd_points(sheet: np.ndarray, k: int, seed: int, iterations: int = 100, samples: int = 100) -> np.ndarray:
    """k centroidal Voronoi sites of the sheet polygon (Lloyd on a ``samples``² grid)."""
    rng = np.random.default_rng(seed)
    lo, hi = sheet.min(axis=0), sheet.max(axis=0)
    xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], samples), np.linspace(lo[1], hi[1], samples))
    grid = np.c_[xs.ravel(), ys.ravel()]
    grid = grid[geometry.points_in_polygon(grid, sheet)]
    sites = grid[rng.choice(len(grid), size=k, replace=False)]
    for _ in range(iterations):
        owner = np.argmin(((grid[:, None, :] - sites[None]) ** 2).sum(axis=2), axis=1)
        counts = np.bincount(owner, minlength=k)
        sums = np.stack([np.bincount(owner, weights=grid[:, i], minlength=k) for i in range(2)], axis=1)
        new = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], sites)
        if np.abs(new - sites).max() < 1e-9 * float(np.ptp(grid)):
            sites = new
            break
        sites = new
    return sites


def lloyd_layout(placement: Placement, k: int, seed: int, clearance: float = 2.0) -> Layout:
    """Squares at the centroids of a seeded Lloyd relaxation, shrunk until valid."""
    layout = squares_at(placement, lloyd_points(placement.sheet_outline_mm, k, seed), clearance)
    if layout is None:
        raise GeometryError(f"no valid squares at the Lloyd centroids of {placement.path} for k = {k}")
    return layout


def squares_at(placement: Placement, sites: np.ndarray, clearance: float = 2.0, sizes: int = 60) -> Layout | None:
    """Squares of the placement's size centred on ``sites`` ``(k, 2)``, shrunk by 10 %
    until the layout is valid, trying at most ``sizes`` sizes (``None`` if none is)."""
    size = placement.size_mm
    for _ in range(sizes):
        layout = Layout(tuple(geometry.square(c, size) for c in sites))
        if valid_layout(layout, placement, clearance):
            return layout
        size *= 0.9
    return None


def initial_layout(scene: Scene, k: int | None, seed: int, init: str) -> Layout:
    """The initial layout of one start."""
    if init == "scene":
        if k is not None and k != scene.layout.k:
            raise GeometryError(f"--init scene uses the scene's {scene.layout.k} capacitors, not k = {k}")
        return scene.layout
    if k is None or k < 1:
        raise GeometryError(f"k must be a positive number of capacitors, got {k!r}")
    if init == "random":
        return random_layout(Placement.of(scene), k, seed)
    if init == "lloyd":
        return lloyd_layout(Placement.of(scene), k, seed)
    raise GeometryError(f"unknown init {init!r}; expected one of {', '.join(LAYOUT_INITS)}")
