"""Feasibility of an optimiser step: how far the controls may move along a direction
before an outline comes too close to another or to the sheet edge, or a triangle of
either 2D mesh loses most of its area (paper §5.1: accepted layouts never overlap, leave
the sheet or invert a triangle)."""

from __future__ import annotations

import numpy as np

from mscap.design.pipeline import Design

__all__ = ["feasible_step", "max_step_triangles"]


def max_step_triangles(points: np.ndarray, triangles: np.ndarray, directions: np.ndarray,
                       keep: float = 0.1) -> float:
    """Largest α ∈ [0, 1] such that along ``points + α directions`` every triangle keeps
    at least ``keep`` of its (positive) signed area. The area is ``A0 + α A1 + α² A2``; the
    bound is the smallest positive root of ``A(α) = keep A0`` (exact, vectorised)."""
    p, v = points[triangles], directions[triangles]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    f1, f2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    cross = lambda a, b: a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]  # noqa: E731
    a0 = cross(e1, e2)
    a1 = cross(e1, f2) + cross(f1, e2)
    a2 = cross(f1, f2)
    c = (1.0 - keep) * a0  # solve a2 α² + a1 α + c = 0 for the first α > 0
    alpha = np.full(len(a0), np.inf)
    linear = np.abs(a2) <= 1e-14 * (np.abs(a1) + np.abs(a0))
    shrinking = linear & (a1 < 0)
    alpha[shrinking] = c[shrinking] / -a1[shrinking]
    quad = ~linear
    disc = a1[quad] ** 2 - 4 * a2[quad] * c[quad]
    roots = np.full(quad.sum(), np.inf)
    real = disc >= 0
    sq = np.sqrt(np.where(real, disc, 0.0))
    r1 = (-a1[quad] - sq) / (2 * a2[quad])
    r2 = (-a1[quad] + sq) / (2 * a2[quad])
    for r in (r1, r2):
        ok = real & (r > 0)
        roots[ok] = np.minimum(roots[ok], r[ok])
    alpha[quad] = roots
    return float(min(1.0, alpha.min(initial=np.inf)))


def feasible_step(design: Design, q, p, alpha: float = 1.0, keep: float = 0.1) -> float:
    """Largest ``α' ≤ alpha`` along ``q + α' p`` that keeps every outline gap (capacitor to
    capacitor, capacitor to sheet, within an outline) above ``keep`` of its current
    excess over the minimum and every triangle of both 2D meshes above ``keep`` of its
    area: no overlap, no outline leaving the sheet, no inverted triangle."""
    deformer = design.deformer
    barrier = design.objective.separation
    v = alpha * deformer.displacement2d(p)
    alpha *= barrier.max_step(deformer.outlines(q), [v[chain] for chain in deformer.outline_vertices], keep)
    v = alpha * deformer.displacement2d(p)
    alpha *= max_step_triangles(deformer.points2d(q), deformer.mesh2d.triangles, v, keep)
    if design.elastic_weights is not None:
        m = design.base.elastic.mesh.mesh2d
        el = m.points + design.elastic_weights @ deformer._q(q)
        alpha *= max_step_triangles(el, m.triangles, alpha * (design.elastic_weights @ deformer._q(p)), keep)
    return alpha
