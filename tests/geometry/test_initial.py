"""Initial layouts (mscap.geometry.initial): valid, seeded, deterministic; Lloyd sites centroidal."""

from __future__ import annotations

import numpy as np
import pytest

from mscap.errors import GeometryError
from mscap.geometry.initial import Placement, initial_layout, lloyd_points, plate_size_mm, random_layout
from mscap.geometry.layout import check_layout
from mscap.scene import load_scene


@pytest.fixture(scope="module")
def scene():
    return load_scene("jobs/poking_cross.toml")  # 10 cm sheet, 18 mm plates, 2 mm gap


@pytest.mark.parametrize("init", ["random", "lloyd"])
@pytest.mark.parametrize("k", [2, 5])
def test_layouts_are_valid_with_clearance_and_seeded(scene, init, k):
    layout = initial_layout(scene, k, 7, init)
    assert layout.k == k
    # Clearance 2 × min gap: the barrier (reach d̂ = gap) starts at zero.
    check_layout(layout, scene.sheet_outline_mm, 2 * scene.min_gap_mm)
    again = initial_layout(scene, k, 7, init)
    assert all(np.array_equal(a, b) for a, b in zip(layout.outlines, again.outlines))
    other = initial_layout(scene, k, 8, init)
    assert not all(np.array_equal(a, b) for a, b in zip(layout.outlines, other.outlines))


def test_plates_take_the_scene_size(scene):
    assert plate_size_mm(scene) == pytest.approx(18.0)
    layout = initial_layout(scene, 3, 0, "random")
    np.testing.assert_allclose(np.abs(layout.areas_mm2()), 18.0 ** 2)


def test_lloyd_sites_are_centroids_of_their_cells(scene):
    sheet = scene.sheet_outline_mm
    sites = lloyd_points(sheet, 4, 1)
    # A fixed point of Lloyd's map: each site is the centroid of its Voronoi cell
    # (measured on a fine grid; the relaxation's own grid is 1 mm).
    xs, ys = np.meshgrid(np.linspace(0, 100, 401), np.linspace(0, 100, 401))
    grid = np.c_[xs.ravel(), ys.ravel()]
    owner = np.argmin(((grid[:, None, :] - sites[None]) ** 2).sum(axis=2), axis=1)
    centroids = np.array([grid[owner == j].mean(axis=0) for j in range(4)])
    np.testing.assert_allclose(centroids, sites, atol=0.5)


def test_scene_init_and_errors(scene):
    assert initial_layout(scene, None, 0, "scene") is scene.layout
    with pytest.raises(GeometryError, match="k = 3"):
        initial_layout(scene, 3, 0, "scene")
    with pytest.raises(GeometryError, match="could not place"):
        random_layout(Placement.of(scene), 400, 0, attempts=1, tries_per_shape=3)
