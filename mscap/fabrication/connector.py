"""Where the array meets the connector: the pads on one sheet edge, in the read-out's lead
order, and the slot assignments (which capacitor sits in which row and column) the
router tries. Both work in an edge frame: the sheet turned so that the connector edge is
at the bottom.
"""

from __future__ import annotations

import itertools

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Point, Polygon, box
from shapely.ops import unary_union

from mscap.errors import FabricationError
from mscap.scene.loader import routing_grid_mm
from mscap.scene.settings import FabricationSettings

__all__ = ["EDGE_ROTATION", "edge_frame", "slot_assignments", "connector_pads"]

# Edge frames: the rotation (degrees) that takes the named sheet side to the bottom.
EDGE_ROTATION = {"bottom": 0.0, "left": 90.0, "right": -90.0, "top": 180.0}


def edge_frame(geometry, edge: str):
    """``geometry`` turned so that the sheet's ``edge`` side is at the bottom."""
    return affinity.rotate(geometry, EDGE_ROTATION[edge], origin=(0, 0))


def slot_assignments(centres: np.ndarray, rows: int, columns: int, count: int, seed: int = 0) -> list[tuple]:
    """Up to ``count`` distinct slot assignments of capacitors at ``centres`` (k, 2; the
    edge frame, connector below): the read-out's default (capacitor order, row by row),
    rows as bands nested from both ends of the pad row (farthest band to R0, the next to
    the last row, ...), rows as bands along the connector (row 0 nearest, then farthest;
    columns left to right, then right to left) and each one's transpose (columns as
    bands), then seeded random ones."""
    k = len(centres)
    slots = [(i // columns, i % columns) for i in range(rows * columns)]
    out: list[tuple] = []

    def add(candidate):  # candidate[c]: the slot of capacitor c
        candidate = tuple(candidate)
        if len(set(candidate)) == k and candidate not in out:
            out.append(candidate)

    def filled(order):  # capacitor order[t] takes slot t, row by row
        candidate = [None] * k
        for t, c in enumerate(order):
            candidate[c] = slots[t]
        return candidate

    add(slots[:k])
    # Nested: rows as bands along the connector, the farthest band to the outermost row pad
    # (R0 on the left, then R(m-1) on the right, then R1, ...), the nearest to the middle
    # one: each row's lead then goes round the nearer bands outside the leads still to
    # come. Columns left to right (or back, mirrored).
    by_distance = np.argsort(-centres[:, 1], kind="stable")  # farthest first
    bands = [by_distance[b:b + columns] for b in range(0, k, columns)]
    left, right, row_of_band = 0, len(bands) - 1, []
    for n in range(len(bands)):
        row_of_band.append(left if n % 2 == 0 else right)
        left, right = (left + 1, right) if n % 2 == 0 else (left, right - 1)
    for mirrored in (False, True):
        x = -centres[:, 0] if mirrored else centres[:, 0]
        nested = [None] * k
        for band, row in zip(bands, row_of_band):
            for column, c in enumerate(sorted(band, key=lambda c: x[c])):
                nested[c] = (row, column)
        add(nested)
    # Banded: rows as bands along the connector (near to far, then far to near: the
    # outermost detour belongs to the leftmost pad), columns left to right or back; then
    # the transpose, columns as bands.
    for far_first, mirrored in ((False, False), (True, False), (False, True), (True, True)):
        y = -centres[:, 1] if far_first else centres[:, 1]
        x = -centres[:, 0] if mirrored else centres[:, 0]
        by_y = np.argsort(y, kind="stable")
        add(filled(itertools.chain.from_iterable(sorted(by_y[b:b + columns], key=lambda c: x[c])
                                                 for b in range(0, k, columns))))
        by_x = np.argsort(x, kind="stable")
        transposed = [None] * k
        for t, c in enumerate(itertools.chain.from_iterable(sorted(by_x[b:b + rows], key=lambda c: y[c])
                                                             for b in range(0, k, rows))):
            transposed[c] = (t % rows, t // rows)
        add(transposed)
    rng = np.random.default_rng(seed)
    for _ in range(20 * count):
        if len(out) >= count:
            break
        add(slots[s] for s in rng.permutation(rows * columns)[:k])
    return out[:count]


def connector_pads(sheet: Polygon, plates: list[Polygon], rules: FabricationSettings, count: int,
                   edge: str) -> tuple[list[Polygon], list[Polygon], np.ndarray]:
    """``count`` pads on the ``edge`` side of the sheet, in lead order, as close to that
    edge as the rules allow (at most a pad length further in) and as central as the plates
    allow: pads, masks and each pad's inner end (where its lead leaves it).

    Raises
    ------
    FabricationError
        No place on that side holds the pads ``edge_distance_mm`` inside the sheet and
        ``clearance_mm`` from every plate.
    """
    f = rules
    angle = EDGE_ROTATION[edge]
    turned = affinity.rotate(sheet, angle, origin=(0, 0))
    inside = turned.buffer(-f.edge_distance_mm, join_style="mitre")
    obstacles = unary_union([affinity.rotate(p, angle, origin=(0, 0)) for p in plates]).buffer(f.clearance_mm)
    minx, miny, maxx, maxy = turned.bounds
    width = (count - 1) * f.pad_pitch_mm + f.pad_width_mm
    if inside.is_empty or width > maxx - minx - 2 * f.edge_distance_mm:
        raise FabricationError(f"fabrication.pad_pitch_mm: {count} pads every {f.pad_pitch_mm:g} mm need "
                               f"{width:.4g} mm along the {edge} edge; the sheet is {maxx - minx:.4g} mm wide there")
    step = routing_grid_mm(f)
    middle = 0.5 * (minx + maxx) - 0.5 * (count - 1) * f.pad_pitch_mm
    shifts = np.arange(0.0, 0.5 * (maxx - minx) + step, step)
    shifts = np.column_stack([shifts, -shifts]).ravel()[1:]
    shapely.prepare(inside)
    shapely.prepare(obstacles)
    for y0 in np.arange(miny + f.edge_distance_mm, miny + f.edge_distance_mm + f.pad_length_mm + 1e-9, step):
        for shift in shifts:
            x0 = middle + shift
            row = box(x0 - 0.5 * f.pad_width_mm, y0, x0 + (count - 1) * f.pad_pitch_mm + 0.5 * f.pad_width_mm,
                      y0 + f.pad_length_mm)
            if inside.contains(row) and not obstacles.intersects(row):
                back = -angle
                pads, masks, ends = [], [], []
                for t in range(count):
                    x = x0 + t * f.pad_pitch_mm
                    pad = box(x - 0.5 * f.pad_width_mm, y0, x + 0.5 * f.pad_width_mm, y0 + f.pad_length_mm)
                    pads.append(affinity.rotate(pad, back, origin=(0, 0)))
                    masks.append(affinity.rotate(pad.buffer(f.mask_margin_mm, join_style="mitre")
                                                 if f.mask_margin_mm else pad, back, origin=(0, 0)))
                    end = affinity.rotate(Point(x, y0 + f.pad_length_mm - 0.5 * f.pad_width_mm), back, origin=(0, 0))
                    ends.append((end.x, end.y))
                return pads, masks, np.array(ends)
    nearest = min(range(len(plates)), key=lambda c: affinity.rotate(plates[c], angle, origin=(0, 0)).bounds[1])
    raise FabricationError(f"fabrication.connector_edge: {count} pads ({width:.4g} mm wide, "
                           f"{f.pad_length_mm:g} mm long) fit nowhere along the {edge} edge "
                           f"{f.edge_distance_mm:g}-{f.edge_distance_mm + f.pad_length_mm:g} mm inside the sheet and {f.clearance_mm:g} mm from every plate "
                           f"(capacitor {nearest} is in the way); choose another connector_edge")
