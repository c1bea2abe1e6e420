"""The quality every 2D mesh of mscap meets, and how to measure it (numpy only).

A P1 or prism field on a triangle is as good as the triangle's shape and its size
relative to its neighbours: the +52 % capacitance of a 6 mm plate 3 mm from the sheet
edge came from a fan of 0.07 × 3 mm needles (minimum angle 0.96°, neighbours 8.7× apart
in size) that cannot carry the fringe field across the plate edge. mscap's meshes are
set up to avoid that (:mod:`mscap.mesh.triangulate`) and checked after every
triangulation against two numbers:

- :data:`MIN_ANGLE_DEG`: no angle of any triangle below it, or below half the sharpest
  vertex angle of an outline where that is smaller (a vertex of angle φ cannot be meshed
  better than φ, and the triangles that split it may share it);
- :data:`MAX_SIZE_RATIO`: two triangles that share an edge differ in size (the square
  root of their areas) by at most this factor.

Both were measured on the 16 shipped scenes, 27 plates near each other, the sheet edge
and its corners, and 40 random layouts (docs/electrostatics.md, "Mesh quality";
tests/mesh/test_shape.py): the set-up gives angles of 15.3–25.6° and ratios of 1.8–2.7
where the old size field gave 0.8–22° and ratios up to 8.7.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mscap.geometry.polygons import edges, point_segment_distance, turn_cosines

__all__ = ["MIN_ANGLE_DEG", "MAX_SIZE_RATIO", "triangle_angles_deg", "neighbour_size_ratios", "outline_angles_deg",
           "MeshQuality", "assess"]

#: The smallest triangle angle mscap's 2D meshes keep (degrees).
MIN_ANGLE_DEG = 15.0
#: The largest size ratio between two triangles sharing an edge.
MAX_SIZE_RATIO = 3.0


def triangle_angles_deg(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``(m, 3)`` interior angles of each triangle, degrees."""
    p = points[triangles]
    angles = []
    for i in range(3):
        u = p[:, (i + 1) % 3] - p[:, i]
        v = p[:, (i + 2) % 3] - p[:, i]
        cos = np.einsum("ij,ij->i", u, v) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
        angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(angles, axis=1)


def neighbour_size_ratios(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every edge shared by two triangles, ``(ratio, pair)``: the size ratio √(A₁/A₂)
    ≥ 1 of the two triangles and their ``(e, 2)`` indices."""
    p = points[triangles]
    area = 0.5 * np.abs(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))
    pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(len(triangles)), 3)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    pairs, owner = pairs[order], owner[order]
    shared = np.flatnonzero(np.all(pairs[1:] == pairs[:-1], axis=1))
    both = np.stack([owner[shared], owner[shared + 1]], axis=1)
    ratio = np.sqrt(area[both[:, 0]] / np.maximum(area[both[:, 1]], 1e-300))
    return np.maximum(ratio, 1.0 / np.maximum(ratio, 1e-300)), both


def outline_angles_deg(polygon: np.ndarray) -> np.ndarray:
    """The angle at each vertex of a closed polygon on its sharper side (degrees, ≤ 180):
    a triangle at that vertex, inside or outside, has an angle no larger."""
    return np.degrees(np.arccos(np.clip(-turn_cosines(polygon), -1.0, 1.0)))


@dataclass(frozen=True)
class MeshQuality:
    """How a 2D mesh measures against :data:`MIN_ANGLE_DEG` and :data:`MAX_SIZE_RATIO`.

    ``allowed_angle_deg`` is what the outlines allow (the smaller of :data:`MIN_ANGLE_DEG`
    and half their sharpest vertex angle); ``worst_xy_mm`` and ``worst_near`` locate the worst
    triangle (``"outline j"`` or ``"the sheet edge"``); ``repaired`` says the mesh was
    made again with a gentler size field to get here."""

    min_angle_deg: float
    max_size_ratio: float
    allowed_angle_deg: float
    worst_xy_mm: tuple[float, float]
    worst_near: str
    repaired: bool = False

    @property
    def meets(self) -> bool:
        return self.min_angle_deg >= self.allowed_angle_deg - 1e-9 and self.max_size_ratio <= MAX_SIZE_RATIO

    def describe(self) -> str:
        x, y = self.worst_xy_mm
        return (f"min angle {self.min_angle_deg:.2f} deg (kept: {self.allowed_angle_deg:.3g}), neighbour size "
                f"ratio {self.max_size_ratio:.2f} (kept: {MAX_SIZE_RATIO:g}); worst triangle at "
                f"({x:.3f}, {y:.3f}) mm near {self.worst_near}")


def assess(points: np.ndarray, triangles: np.ndarray, outlines: Sequence[np.ndarray],
           sheet_outline_mm: np.ndarray, repaired: bool = False) -> MeshQuality:
    """Measure a triangulation of the sheet with ``outlines`` embedded."""
    angles = triangle_angles_deg(points, triangles).min(axis=1)
    ratios, pairs = neighbour_size_ratios(points, triangles)
    sharpest = min((float(outline_angles_deg(np.asarray(o, float)).min()) for o in outlines), default=180.0)
    allowed = min(MIN_ANGLE_DEG, 0.5 * sharpest)
    # the worst: the smallest angle measured against what is kept, or the largest ratio
    angle_badness = allowed / np.maximum(angles, 1e-9)
    ratio_badness = np.zeros(len(triangles))
    if len(ratios):
        np.maximum.at(ratio_badness, pairs[:, 0], ratios / MAX_SIZE_RATIO)
        np.maximum.at(ratio_badness, pairs[:, 1], ratios / MAX_SIZE_RATIO)
    worst = int(np.argmax(np.maximum(angle_badness, ratio_badness)))
    centre = points[triangles[worst]].mean(axis=0)
    curves = [("the sheet edge", sheet_outline_mm)] + [(f"outline {j}", o) for j, o in enumerate(outlines)]
    near = min(curves, key=lambda c: float(point_segment_distance(centre[None], edges(np.asarray(c[1], float))).min()))
    return MeshQuality(float(angles.min()), float(ratios.max()) if len(ratios) else 1.0, allowed,
                       (float(centre[0]), float(centre[1])), near[0], repaired)
