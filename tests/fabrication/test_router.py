"""The router: pads where the rules put them, leads that are straight where nothing is in
the way, every slot assignment distinct, and a clear error where a capacitor cannot be
reached (docs/fabrication.md)."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from mscap.errors import FabricationError
from mscap.fabrication.connector import connector_pads, slot_assignments
from mscap.fabrication.router import route
from mscap.geometry.polygons import square
from mscap.scene.settings import FabricationSettings

RULES = FabricationSettings()
SHEET = np.array([[0.0, 0.0], [60.0, 0.0], [60.0, 50.0], [0.0, 50.0]])


def grid_plates(rows, columns, size, pitch, centre=(30.0, 28.0)):
    xs = centre[0] + pitch * (np.arange(columns) - 0.5 * (columns - 1))
    ys = centre[1] + pitch * (np.arange(rows) - 0.5 * (rows - 1))
    return [square((x, y), size) for y in ys for x in xs]


@pytest.mark.parametrize("edge", ["bottom", "left", "right", "top"])
def test_pads_sit_on_their_edge_at_the_pitch_in_lead_order(edge):
    sheet = Polygon(SHEET)
    plates = [Polygon(square((30.0, 25.0), 10.0))]
    pads, masks, ends = connector_pads(sheet, plates, RULES, 5, edge)
    assert len(pads) == len(masks) == len(ends) == 5
    side = {"bottom": (1, 0.0), "top": (1, 50.0), "left": (0, 0.0), "right": (0, 60.0)}[edge]
    for pad, mask in zip(pads, masks):
        assert mask.contains(pad)
        # the pad's outer end is edge_distance_mm from its edge, exactly (the scan starts there)
        coords = np.asarray(pad.exterior.coords)[:, side[0]]
        assert np.min(np.abs(coords - side[1])) == pytest.approx(RULES.edge_distance_mm, abs=1e-9)
        assert pad.distance(plates[0]) >= RULES.clearance_mm
    centres = np.array([[p.centroid.x, p.centroid.y] for p in pads])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert steps == pytest.approx(np.full(4, RULES.pad_pitch_mm), abs=1e-9)
    # lead order runs left to right as seen from outside, facing the sheet across its edge
    outward = np.array({"bottom": (0, -1), "top": (0, 1), "left": (-1, 0), "right": (1, 0)}[edge])
    facing = -outward
    right = np.array([facing[1], -facing[0]])
    assert np.all(np.diff(centres @ right) > 0)


def test_pads_slide_past_a_plate_in_the_way():
    sheet = Polygon(SHEET)
    plate = Polygon(square((30.0, 6.0), 8.0))  # right where centred pads would go
    pads, _, _ = connector_pads(sheet, [plate], RULES, 4, "bottom")
    assert all(p.distance(plate) >= RULES.clearance_mm - 1e-9 for p in pads)
    assert min(p.bounds[1] for p in pads) == pytest.approx(RULES.edge_distance_mm)


def test_pads_that_cannot_fit_name_the_edge_and_the_width():
    narrow = Polygon([[0, 0], [8, 0], [8, 50], [0, 50]])
    with pytest.raises(FabricationError, match=r"fabrication.pad_pitch_mm: 4 pads every 2.54 mm need 8.89 mm "
                                               r"along the bottom edge; the sheet is 8 mm wide"):
        connector_pads(narrow, [], RULES, 4, "bottom")


def test_a_lone_capacitor_gets_two_straight_leads_and_no_overlap():
    # One plate right above the pads: both leads (row in the bottom layer, column in the
    # top one) run straight up, each one segment, and never lie over each other.
    plate = square((30.0, 30.0), 12.0)
    routing = route([plate], SHEET, FabricationSettings(connector_edge="bottom"))
    assert (routing.array.rows, routing.array.columns, routing.edge) == (1, 1, "bottom")
    for net in routing.nets:
        (path,) = net.paths
        assert len(path) == 2 and path[0, 0] == pytest.approx(path[1, 0], abs=1e-9)  # vertical
        assert net.pad.contains(Point(path[0])) and Polygon(plate).contains(Point(path[1]))
    assert routing.overlaps() == []


def test_slot_assignments_are_distinct_complete_and_start_with_the_readouts_default():
    rng = np.random.default_rng(1)
    centres = rng.uniform(0, 50, (4, 2))
    candidates = slot_assignments(centres, 2, 2, 100)
    assert len(candidates) == 24  # 4! assignments of 4 capacitors to a 2 x 2 array, no more
    assert len(set(candidates)) == 24
    assert candidates[0] == ((0, 0), (0, 1), (1, 0), (1, 1))
    # the second: rows as bands nested from both ends of the pad row: the farthest band is
    # R0 (leftmost pad), the nearest the last row; columns left to right
    by_y = np.argsort(centres[:, 1])
    assert {candidates[1][c][0] for c in by_y[2:]} == {0} and {candidates[1][c][0] for c in by_y[:2]} == {1}
    far = sorted(by_y[2:], key=lambda c: centres[c, 0])
    assert [candidates[1][c][1] for c in far] == [0, 1]
    assert slot_assignments(centres[:3], 2, 2, 5) == slot_assignments(centres[:3], 2, 2, 5)[:5]
    assert len(slot_assignments(centres[:3], 2, 2, 100)) == 24  # 3 capacitors in 4 slots: 4·3·2


def test_a_three_by_three_grid_routes_within_the_rules():
    plates = grid_plates(3, 3, 9.0, 14.0)
    routing = route(plates, np.array([[0, 0], [80, 0], [80, 70], [0, 70.0]]),
                    FabricationSettings(assignments=8, connector_edge="bottom"))
    assert (routing.array.rows, routing.array.columns) == (3, 3)
    for layer in ("bottom", "top"):
        nets = routing.layer(layer)
        assert len(nets) == 3
        for a in range(3):
            assert nets[a].conductor.geom_type == "Polygon"  # one conductor per net
            for c in nets[a].capacitors:
                assert nets[a].conductor.buffer(1e-6).contains(Polygon(plates[c]))
            for b in range(a + 1, 3):
                assert nets[a].conductor.distance(nets[b].conductor) >= RULES.clearance_mm - 1e-3


def test_plates_closer_than_the_clearance_are_named():
    plates = [square((20.0, 25.0), 10.0), square((30.8, 25.0), 10.0)]  # 0.8 mm apart
    with pytest.raises(FabricationError, match=r"capacitors 0 and 1 are 0.8 mm apart, less than "
                                               r"fabrication.clearance_mm = 1"):
        route(plates, SHEET, RULES)


def test_a_plate_enclosed_by_another_is_named_with_where_it_is_blocked():
    # A U-shaped plate around a small one, its mouth 2 mm wide: a lead needs 1 + 2·1 = 3 mm.
    # In the layer where the two are different nets nothing reaches the small one.
    u = np.array([[10, 10], [50, 10], [50, 45], [31, 45], [31, 43], [48, 43], [48, 12], [12, 12], [12, 43],
                  [29, 43], [29, 45], [10, 45]], dtype=float)
    inner = square((30.0, 27.0), 10.0)
    with pytest.raises(FabricationError) as error:
        route([u, inner], SHEET, FabricationSettings(connector_edge="bottom", assignments=2))
    message = str(error.value)
    assert "capacitor 1 cannot be joined to net" in message
    assert "a lead needs a channel trace_width_mm + 2 clearance_mm = 3 mm wide" in message
    assert "next to capacitor 0" in message
    x, y = map(float, message.split(" mm short of it, at (")[1].split(")")[0].split(", "))
    assert not Polygon(u).convex_hull.contains(Point(x, y))  # nothing gets into the U


@pytest.mark.parametrize("n", [4, 5])
def test_square_grids_route_their_rows_round_each_other(n):
    # The cases that shaped the router: n x n plates 8 mm apart. Before plates were joined
    # net by net first, pads kept a stub and lanes beside plates were costed, no assignment
    # of 24 routed 4 x 4; 5 x 5 routed only once the rows were nested from both ends of the
    # pad row (docs/fabrication.md).
    side = 20.0 * n + 30.0
    plates = grid_plates(n, n, 12.0, 20.0, centre=(side / 2, side / 2 + 5.0))
    sheet = np.array([[0, 0], [side, 0], [side, side], [0, side]])
    routing = route(plates, sheet, FabricationSettings(connector_edge="bottom", assignments=2))
    assert (routing.array.rows, routing.array.columns) == (n, n)
    for layer in ("bottom", "top"):
        nets = routing.layer(layer)
        for a, net in enumerate(nets):
            assert net.conductor.geom_type == "Polygon" and len(net.capacitors) == n
            for other in nets[a + 1:]:
                assert net.conductor.distance(other.conductor) >= RULES.clearance_mm - 1e-3
