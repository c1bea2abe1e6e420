"""The routing grid: cell centres over the sheet, masks of geometry on them, and the
cheapest path through free cells (Dijkstra on the 8-connected cell graph, scipy's).

A lead's centre line runs from cell centre to cell centre. A cell is free for a net when
its centre is at least ``clearance + width/2 + margin`` from every other net of its layer;
``margin`` = h/√2 covers the segment between two diagonal neighbours, whose points lie up
to h/√2 from the nearer end. The written geometry is checked on its own
(:mod:`mscap.fabrication.check`), not through this bookkeeping.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

__all__ = ["Grid"]

# The 8 neighbours (di, dj) of a cell and their distances in cells; half of them, since
# the graph is undirected.
_STEPS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, np.sqrt(2.0)), (1, -1, np.sqrt(2.0)))


@dataclass(frozen=True)
class Grid:
    """``ny × nx`` cell centres ``origin + h · (j, i)`` (mm), row i, column j."""

    origin: tuple[float, float]
    h: float
    nx: int
    ny: int

    @classmethod
    def covering(cls, bounds, h: float, anchor: tuple[float, float]) -> "Grid":
        """The grid of cell ``h`` covering ``bounds`` (minx, miny, maxx, maxy) with a cell
        centre at ``anchor`` (a pad's axis)."""
        minx, miny, maxx, maxy = bounds
        x0 = anchor[0] - np.ceil((anchor[0] - minx) / h) * h
        y0 = anchor[1] - np.ceil((anchor[1] - miny) / h) * h
        return cls((float(x0), float(y0)), float(h), int(np.floor((maxx - x0) / h)) + 1,
                   int(np.floor((maxy - y0) / h)) + 1)

    @property
    def size(self) -> int:
        return self.nx * self.ny

    def points(self, cells: np.ndarray) -> np.ndarray:
        """The centres (n, 2) of flat cell indices ``cells``."""
        i, j = np.divmod(np.asarray(cells), self.nx)
        return np.column_stack([self.origin[0] + self.h * j, self.origin[1] + self.h * i])

    def mask(self, geometry, distance: float = 0.0) -> np.ndarray:
        """Flat boolean mask of the cells whose centre lies in ``geometry`` grown by
        ``distance`` (tested only inside its bounding box)."""
        out = np.zeros(self.size, dtype=bool)
        if geometry is None or geometry.is_empty:
            return out
        grown = geometry.buffer(distance, quad_segs=8) if distance > 0 else geometry
        minx, miny, maxx, maxy = grown.bounds
        j0 = max(int(np.floor((minx - self.origin[0]) / self.h)), 0)
        j1 = min(int(np.ceil((maxx - self.origin[0]) / self.h)), self.nx - 1)
        i0 = max(int(np.floor((miny - self.origin[1]) / self.h)), 0)
        i1 = min(int(np.ceil((maxy - self.origin[1]) / self.h)), self.ny - 1)
        if j1 < j0 or i1 < i0:
            return out
        jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
        x = self.origin[0] + self.h * jj
        y = self.origin[1] + self.h * ii
        shapely.prepare(grown)
        inside = shapely.contains_xy(grown, x, y)
        out.reshape(self.ny, self.nx)[i0:i1 + 1, j0:j1 + 1] = inside
        return out

    def graph(self, free: np.ndarray, cost: np.ndarray):
        """The undirected graph of the free cells, each edge the step's length (mm) times
        the mean cost of its two cells."""
        i, j = np.divmod(np.arange(self.size), self.nx)
        rows, cols, weights = [], [], []
        for di, dj, length in _STEPS:
            ok = (i + di < self.ny) & (j + dj >= 0) & (j + dj < self.nx)
            a = np.flatnonzero(ok)
            b = (i[ok] + di) * self.nx + j[ok] + dj
            keep = free[a] & free[b]
            a, b = a[keep], b[keep]
            rows.append(a)
            cols.append(b)
            weights.append(self.h * length * 0.5 * (cost[a] + cost[b]))
        r, c, w = (np.concatenate(x) for x in (rows, cols, weights))
        return coo_matrix((np.concatenate([w, w]), (np.concatenate([r, c]), np.concatenate([c, r]))),
                          shape=(self.size, self.size)).tocsr()

    @staticmethod
    def nearest(graph, sources: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance of every cell to the nearest of ``sources`` and the predecessors that
        lead back to it (``-9999`` at sources and unreachable cells)."""
        dist, pred, _ = dijkstra(graph, directed=False, indices=np.asarray(sources), min_only=True,
                                 return_predecessors=True)
        return dist, pred

    @staticmethod
    def path(pred: np.ndarray, end: int) -> np.ndarray:
        """The cells from a source to ``end`` along ``pred``."""
        cells = [int(end)]
        while pred[cells[-1]] >= 0:
            cells.append(int(pred[cells[-1]]))
        return np.array(cells[::-1])
