"""The one point locator (mscap.geometry.locate), used by the mesh transfer and the glue
interpolant: exact barycentric coordinates, round-off on the boundary, holes."""

from __future__ import annotations

import numpy as np

from mscap.geometry.locate import TriangleLocator
from tests.conftest import grid_trimesh


def test_barycentric_coordinates_reproduce_the_points():
    mesh = grid_trimesh(6, 4, 6.0, 4.0, lambda c: np.zeros(len(c)), jitter=0.3, seed=2)
    rng = np.random.default_rng(0)
    xy = rng.random((500, 2)) * [6.0, 4.0]
    triangle, bary = TriangleLocator(mesh.points, mesh.triangles).locate(xy)
    assert (triangle >= 0).all() and (bary >= -1e-12).all()
    corners = mesh.points[mesh.triangles[triangle]]
    np.testing.assert_allclose(np.einsum("pk,pkd->pd", bary, corners), xy, rtol=0, atol=1e-13)


def test_outside_round_off_and_holes():
    """An L-shaped sheet (a 2 × 2 grid of unit cells less the top-right one): the notch is
    outside, points a hair outside a boundary edge count as on it: by the barycentric
    tolerance (1e-12 outside) or by the distance to a boundary edge (1.5e-9 outside: a
    barycentric coordinate of -1.5e-9, but within 1e-9 of the sheet's size 2)."""
    mesh = grid_trimesh(2, 2, 2.0, 2.0, lambda c: np.zeros(len(c)))
    cells = mesh.points[mesh.triangles].mean(axis=1)
    keep = ~((cells[:, 0] > 1) & (cells[:, 1] > 1))
    locator = TriangleLocator(mesh.points, mesh.triangles[keep])
    xy = np.array([[1.5, 1.5], [-1e-12, 0.5], [2.0 + 1.5e-9, 0.5], [-0.1, 0.5], [0.5, 0.5], [1.0, 1.0]])
    triangle, bary = locator.locate(xy)
    np.testing.assert_array_equal(triangle < 0, [True, False, False, True, False, False])
    np.testing.assert_array_equal(bary[triangle < 0], 0.0)
    np.testing.assert_allclose(bary[triangle >= 0].sum(axis=1), 1.0, rtol=0, atol=1e-14)
