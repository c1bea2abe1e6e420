"""The routing grid: pad axes on cell centres, masks of grown geometry, and Dijkstra's
distances on free cells equal to the octile distance (exact)."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Point, box

from mscap.fabrication.grid import Grid


def test_the_anchor_is_a_cell_centre_and_the_grid_covers_the_box():
    grid = Grid.covering((0.0, 0.0, 10.0, 6.0), 0.5, (3.3, 1.1))
    assert (3.3 - grid.origin[0]) / grid.h == pytest.approx(round((3.3 - grid.origin[0]) / grid.h), abs=1e-12)
    assert grid.origin[0] <= 0.0 and grid.origin[1] <= 0.0
    corner = grid.points(np.array([grid.size - 1]))[0]
    assert corner[0] >= 10.0 - grid.h and corner[1] >= 6.0 - grid.h


def test_masks_hold_the_cells_inside_the_grown_geometry():
    grid = Grid((0.0, 0.0), 1.0, 11, 11)
    inside = grid.points(np.flatnonzero(grid.mask(Point(5, 5).buffer(2.5, quad_segs=32))))
    assert len(inside) == 21  # lattice points within 2.5 of (5, 5): 1 + 4·1 + 4·1 + 4·2 + 4·1
    grown = grid.mask(box(5, 5, 5, 5).union(Point(5, 5).buffer(1e-9)), distance=1.5)
    assert grown.sum() == 9  # the 3 x 3 block: (±1, ±1) lies within 1.5, (±2, 0) does not


def test_dijkstra_distances_are_octile_and_walls_are_walked_round():
    grid = Grid((0.0, 0.0), 0.5, 21, 11)
    free = np.ones(grid.size, dtype=bool)
    graph = grid.graph(free, np.ones(grid.size))
    dist, pred = Grid.nearest(graph, np.array([0]))
    far = grid.size - 1  # (10, 5) from (0, 0): 10 straight-diagonal steps and 10 straight ones
    assert dist[far] == pytest.approx(0.5 * (10 * np.sqrt(2) + 10), rel=1e-12)
    path = grid.points(Grid.path(pred, far))
    assert np.allclose(path[0], [0, 0]) and np.allclose(path[-1], [10, 5])
    wall = grid.mask(box(4.9, -1, 5.1, 4.6))  # x = 5, y ≤ 4.5: open only at the top row
    graph = grid.graph(free & ~wall, np.ones(grid.size))
    dist, _ = Grid.nearest(graph, np.array([0]))
    target = 10  # (5, 0), just behind the wall
    assert not np.isfinite(dist[int(np.flatnonzero(wall)[0])])
    assert dist[target] > 9.0  # up, over the top row and down again, not 2.5 straight
    cost = np.ones(grid.size)
    cost[grid.mask(box(-1, -1, 11, 2.6))] = 100.0  # expensive bottom rows
    graph = grid.graph(free, cost)
    dist, pred = Grid.nearest(graph, np.array([0]))
    assert dist[20] < 100 * 10  # leaves the costly band at once instead of running along it
