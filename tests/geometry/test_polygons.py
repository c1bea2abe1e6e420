"""The planar kernels every module shares: point–segment projection, the gap between two
outlines and the minimum gap of a layout (exact answers, and both code paths agreeing)."""

from __future__ import annotations

import numpy as np
import pytest

from mscap.geometry import polygons as geometry
from mscap.geometry.layout import min_gap_mm


def test_segment_projection_exact():
    a, b = np.array([[0.0, 0.0]] * 4), np.array([[4.0, 0.0]] * 3 + [[0.0, 0.0]])
    points = np.array([[1.0, 3.0], [-3.0, 4.0], [7.0, -4.0], [3.0, 4.0]])  # last: a point segment
    distance, t, offset = geometry.segment_projection(points, a, b)
    np.testing.assert_array_equal(distance, [3.0, 5.0, 5.0, 5.0])
    np.testing.assert_array_equal(t, [0.25, 0.0, 1.0, 0.0])
    np.testing.assert_array_equal(offset, [[0.0, 3.0], [-3.0, 4.0], [3.0, -4.0], [3.0, 4.0]])


def test_all_pairs_is_the_broadcast_projection():
    rng = np.random.default_rng(0)
    points, segments = rng.random((7, 2)), rng.random((5, 2, 2))
    distance = geometry.point_segment_distance(points, segments)
    paired, _, _ = geometry.segment_projection(points[:, None], segments[None, :, 0], segments[None, :, 1])
    assert distance.shape == (7, 5)
    np.testing.assert_array_equal(distance, paired)


def test_boundary_distance_exact_and_zero_when_crossing():
    p, q = geometry.square((0.0, 0.0), 2.0), geometry.square((3.5, 0.25), 2.0)
    assert geometry.boundary_distance(p, q) == pytest.approx(1.5, abs=1e-15)
    assert geometry.boundary_distance(p, geometry.square((1.5, 0.0), 2.0)) == 0.0
    corner = geometry.square((3.0, 4.0), 2.0)  # nearest points: corners (1, 1) and (2, 3)
    assert geometry.boundary_distance(p, corner) == pytest.approx(np.sqrt(5.0), abs=1e-15)


def test_boundary_distance_candidates_agree_with_all_pairs(monkeypatch):
    """Above ``_ALL_PAIRS`` vertex–edge pairs only nearby edges are tried: the same number."""
    rng = np.random.default_rng(1)
    cases = []
    for _ in range(20):
        n, m = rng.integers(60, 300, 2)
        p = geometry.disk((0.0, 0.0), 20.0, 20 * np.pi / n) * (1 + 0.1 * rng.random((1, 1)))
        q = geometry.disk((rng.uniform(15.0, 30.0), rng.uniform(-8.0, 8.0)), 14.0, 14 * np.pi / m)
        cases.append((p, q))
    near = [geometry.boundary_distance(p, q) for p, q in cases]
    assert all(len(p) * len(q) > geometry._ALL_PAIRS for p, q in cases)
    monkeypatch.setattr(geometry, "_ALL_PAIRS", np.inf)
    assert near == [geometry.boundary_distance(p, q) for p, q in cases]
    assert any(d == 0.0 for d in near) and any(d > 0.0 for d in near)


def test_min_gap_of_a_layout():
    sheet = geometry.square((10.0, 5.0), 20.0)  # x in [0, 20], y in [-5, 15]
    left, right = geometry.square((5.0, 5.0), 4.0), geometry.square((12.0, 5.0), 4.0)
    assert min_gap_mm([left, right], sheet) == pytest.approx(3.0, abs=1e-14)   # 7 − 4 apart
    assert min_gap_mm([left, geometry.square((17.0, 5.0), 4.0)], sheet) == pytest.approx(1.0, abs=1e-14)
    inner = geometry.square((5.0, 5.0), 1.0)  # inside ``left``: no boundary crosses, yet overlap
    assert min_gap_mm([left, inner], sheet) == 0.0


def _densified(polygon, spacing):
    """``polygon`` with every edge cut into pieces at most ``spacing`` long."""
    out = []
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
        n = int(np.ceil(np.linalg.norm(b - a) / spacing))
        out.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.vstack(out)


def test_coarsened_keeps_corners_and_drops_collinear_vertices():
    square = geometry.square((10.0, 10.0), 18.0)
    np.testing.assert_array_equal(geometry.coarsened(square, 2.5), square)  # nothing to drop
    dense = _densified(square, 0.075)  # an optimised outline: every electrostatic outline vertex
    coarse = geometry.coarsened(dense, 2.5)
    assert len(dense) == 960 and 29 <= len(coarse) <= 33  # 72 mm perimeter / 2.5 mm, plus corners
    for corner in square:  # corners survive exactly, and every kept vertex is one of the originals
        assert np.any(np.all(coarse == corner, axis=1))
    assert np.all(np.any(np.all(coarse[:, None] == dense[None], axis=2), axis=1))
    assert abs(geometry.signed_area(coarse) - 18.0 ** 2) < 1e-9  # collinear vertices: area exact


def test_coarsened_circle_deviates_by_the_sagitta():
    # A circle of radius R sampled 0.075 mm apart, coarsened to 2.5 mm: the chords cut
    # inside by at most s² / 8R (s the longest chord).
    r, spacing = 9.0, 2.5
    dense = geometry.disk((0.0, 0.0), 2 * r, 0.075)
    coarse = geometry.coarsened(dense, spacing)
    chord = np.linalg.norm(np.roll(coarse, -1, axis=0) - coarse, axis=1)
    assert len(coarse) == int(np.ceil(2 * np.pi * r / spacing)) and chord.max() < 1.05 * spacing
    apothem = np.sqrt(r ** 2 - (chord / 2) ** 2)
    assert r - apothem.min() <= 1.01 * chord.max() ** 2 / (8 * r)  # 0.085 mm
    area = abs(geometry.signed_area(coarse))
    # An inscribed polygon of chord angles θ_i = s_i / R loses a fraction ≈ θ² / 6 of the area.
    assert 0 < 1 - area / abs(geometry.signed_area(dense)) <= 1.01 * (chord.max() / r) ** 2 / 6  # 1.2 %
