"""Routing a design's leads in the multiplexed array (paper appendix C).

The bottom plates of row i are one net, ``R{i}``, in the bottom conductive layer; the top
plates of column j are one net, ``C{j}``, in the top layer. Each net joins its plates and
its connector pad. The pads sit on one sheet edge in the read-out's lead order
(:mod:`mscap.readout.array`: rows first, then columns, left to right as seen from
outside, facing the sheet across that edge).

Within a layer a lead may cross its own net's plates and nothing else of that layer.
Across layers, wherever a row conductor lies under a column conductor outside their
capacitor's plate, the overlap adds to that reading c_ij: the router counts those areas
(each mm² weighs :data:`OVERLAP_WEIGHT_MM` of lead) and searches the slot assignment
(which capacitor sits in which row and column) and, with ``connector_edge = "auto"``, the
edge.

One layer at a time, one net at a time, on the routing grid
(:mod:`mscap.fabrication.grid`): first every net of the layer joins its own plates
(Dijkstra from the plate nearest its pad to the next nearest, until all are joined),
then each pad is joined to its net, so that a pad's lead goes round the other nets'
rows of plates instead of cutting one. Each path is pulled straight wherever the straight
lead keeps its clearance and crosses no more of the other layer
(:mod:`mscap.fabrication.leads`). A pad still waiting keeps a short stub straight inward
free, and the strip in front of it costs (:data:`RAY_WEIGHT`); lanes beside other nets'
plates cost as wide as the leads still to come need (:data:`NEAR_WEIGHT`). Leads are the
centre lines buffered by half the trace width with round joins; each net is closed by
``min_radius_mm`` where leads bend and meet (fillets).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from mscap.errors import FabricationError
from mscap.fabrication.connector import EDGE_ROTATION, connector_pads, slot_assignments
from mscap.fabrication.grid import Grid
from mscap.fabrication.leads import lead_outline, pull_straight, trim_path
from mscap.readout.array import CapacitorArray, grid_array
from mscap.scene.loader import routing_grid_mm
from mscap.scene.settings import FabricationSettings

__all__ = ["OVERLAP_WEIGHT_MM", "CROSSING_MM2", "RAY_WEIGHT", "NEAR_WEIGHT", "STUB_PITCHES", "LAYERS", "Net", "Routing", "route",
           "slot_assignments", "connector_pads"]

log = logging.getLogger(__name__)

#: One mm² of row conductor under a column conductor outside a plate costs as much as this
#: many mm of lead: 1 mm² is ~0.06 pF across a 0.4 mm, εr 2.8 dielectric, a 10 mm detour
#: ~10 mm² of trace the stencil has to hold.
OVERLAP_WEIGHT_MM = 10.0
#: Each mm of lead inside the strip straight inward of a pad of its layer that is still to
#: be routed costs this many mm more: a lead across that strip walls the pad's lead in
#: unless the pad's net can go round, so crossing one costs about 25 mm of detour.
RAY_WEIGHT = 10.0
#: A lead within ``(trace width + clearance)`` times the number of its layer's leads still
#: to come of another net's plate costs this much more per mm: the first lead round a row
#: of plates keeps to the outside and leaves the inside lanes to the later ones.
NEAR_WEIGHT = 1.0
#: Pitches straight inward of a pad that no other lead of its layer may cross before the
#: pad's own lead is routed (less where plates are nearer: a lane stays free before them).
STUB_PITCHES = 2
#: An overlap of at least this area (mm²) is a lead crossing; smaller ones are where two
#: leads' fillets meet at a plate (1e-4 pF), listed but not counted as crossings.
CROSSING_MM2 = 0.01
#: The conductive layers, bottom first: rows in the bottom one, columns in the top one.
LAYERS = ("bottom", "top")
# Slot assignments tried on every edge, at most, before the budget goes to the best one.
_FIRST_PER_EDGE = 7


@dataclass(frozen=True, eq=False)
class Net:
    """One row or column net: its plates, pad, mask and lead centre lines (mm), and the
    conductor it is in its layer (a shapely (Multi)Polygon)."""

    name: str
    layer: str
    lead: int
    capacitors: tuple[int, ...]
    pad: Polygon
    mask: Polygon
    paths: tuple[np.ndarray, ...]
    conductor: object
    #: False while only its plates are joined (the pad's lead comes next).
    pad_joined: bool = True

    @property
    def length_mm(self) -> float:
        """Length of the lead centre lines."""
        return float(sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in self.paths))


@dataclass(frozen=True, eq=False)
class Routing:
    """A routed design: the array (``slots[c] = (row, column)`` of capacitor c), the
    connector edge, the nets in lead order, the sheet and plates (shapely)."""

    array: CapacitorArray
    edge: str
    nets: tuple[Net, ...]
    sheet: Polygon
    plates: tuple[Polygon, ...]
    rules: FabricationSettings
    assignments_tried: int = 0
    time_s: float = 0.0
    rejected: tuple[str, ...] = field(default=())

    def layer(self, name: str) -> list[Net]:
        return [n for n in self.nets if n.layer == name]

    @property
    def length_mm(self) -> float:
        return sum(n.length_mm for n in self.nets)

    def overlaps(self) -> list[dict]:
        """Every place a row conductor lies under a column conductor outside the plate of
        their capacitor: ``row``, ``column``, ``area_mm2`` and ``centroid_mm`` (fresh
        dicts; measured once per routing)."""
        return [dict(o) for o in self._overlaps]

    @cached_property
    def _overlaps(self) -> tuple[dict, ...]:
        plate_of = {slot: c for c, slot in enumerate(self.array.slots)}
        out = []
        for r in self.layer("bottom"):
            for col in self.layer("top"):
                i, j = r.lead, col.lead - self.array.rows
                extra = r.conductor.intersection(col.conductor)
                if (i, j) in plate_of:
                    extra = extra.difference(self.plates[plate_of[(i, j)]].buffer(1e-6))
                for part in getattr(extra, "geoms", [extra]):
                    if part.area > 1e-6:
                        out.append({"row": i, "column": j, "area_mm2": float(part.area),
                                    "centroid_mm": [round(part.centroid.x, 4), round(part.centroid.y, 4)]})
        return tuple(out)

    @property
    def overlap_mm2(self) -> float:
        return sum(o["area_mm2"] for o in self._overlaps)

    def summary(self) -> str:
        """One line: array, connector edge, lead length and overlap."""
        return (f"{self.array.rows} x {self.array.columns} array to the {self.edge} edge, "
                f"{self.length_mm:.0f} mm of leads, {self.overlap_mm2:.2f} mm2 of overlap")

    @property
    def cost(self) -> float:
        """What the router minimises: lead length plus :data:`OVERLAP_WEIGHT_MM` per mm² of
        overlap (mm)."""
        return self.length_mm + OVERLAP_WEIGHT_MM * self.overlap_mm2


def route(outlines, sheet_outline: np.ndarray, rules: FabricationSettings, progress=None) -> Routing:
    """Route the plates ``outlines`` (k arrays, mm) on the sheet under ``rules``: the
    cheapest (:attr:`Routing.cost`) routing over the slot assignments and edges tried.

    Raises
    ------
    FabricationError
        Plates closer than the clearance, or no assignment routes (the message names the
        capacitor of the first assignment that is blocked and where).
    """
    started = time.perf_counter()
    say = progress or (lambda message: None)
    sheet = Polygon(np.asarray(sheet_outline, dtype=float))
    plates = [Polygon(np.asarray(o, dtype=float)) for o in outlines]
    _check_plates(plates, sheet, rules)
    k = len(plates)
    array = grid_array(k, rules.rows or None, rules.columns or None)
    edges = ("bottom", "left", "right", "top") if rules.connector_edge == "auto" else (rules.connector_edge,)
    best, failures, tried = None, [], 0
    queues = {}
    for edge in edges:
        try:
            pads, masks, ends = connector_pads(sheet, plates, rules, array.rows + array.columns, edge)
        except FabricationError as exc:
            failures.append(str(exc))
            continue
        centres = np.array([affinity.rotate(p.centroid, EDGE_ROTATION[edge], origin=(0, 0)).coords[0]
                            for p in plates])
        queues[edge] = (_edge_context(sheet, plates, pads, masks, ends, rules),
                        slot_assignments(centres, array.rows, array.columns, rules.assignments))

    budget = min(rules.assignments, sum(len(c) for _, c in queues.values()))

    def attempt(edge, slots):
        nonlocal best, tried
        tried += 1
        try:
            routing = _route_assignment(CapacitorArray(array.rows, array.columns, slots), edge, queues[edge][0])
        except FabricationError as exc:
            failures.append(f"{edge} edge, slots {list(slots)}: {exc}")
            say(f"route {tried}/{budget}: {edge} edge: no route ({time.perf_counter() - started:.1f} s)")
            return
        better = best is None or routing.cost < best.cost - 1e-9
        best = routing if better else best
        say(f"route {tried}/{budget}: {edge} edge: {routing.length_mm:.1f} mm of leads, "
            f"{routing.overlap_mm2:.2f} mm2 of overlap{' (best so far)' if better else ''} "
            f"({time.perf_counter() - started:.1f} s)")

    # Half the budget over the edges (the read-out's default, then the nested and banded
    # assignments, at most _FIRST_PER_EDGE each), then the rest on the best edge so far (on
    # the other edges after it, while none routes).
    first = max(1, min(_FIRST_PER_EDGE, rules.assignments // (2 * max(len(queues), 1))))  # half the budget
    for edge, (_, candidates) in queues.items():
        for slots in candidates[:first]:
            if tried < rules.assignments:
                attempt(edge, slots)
    rest = [(e, s) for e, (_, c) in queues.items() for s in c[first:]]
    rest.sort(key=lambda item: best is None or item[0] != best.edge)
    for edge, slots in rest:
        if tried >= rules.assignments:
            break
        attempt(edge, slots)
    if best is None:
        routed = [m for m in failures if " slots " in m]  # assignments that had pads and did not route
        if not routed:
            raise FabricationError(failures[0] if failures else "no connector edge holds the pads")
        raise FabricationError(f"none of the {tried} slot assignments tried routes"
                               f"{'' if len(queues) == len(edges) else ' (pads fit only on the ' + ', '.join(queues) + ' edge)'}"
                               f"; the first: {routed[0]}")
    return Routing(best.array, best.edge, best.nets, sheet, tuple(plates), rules, tried,
                   time.perf_counter() - started, tuple(failures))


def _check_plates(plates: list[Polygon], sheet: Polygon, rules: FabricationSettings) -> None:
    """Any two capacitors are different nets in at least one layer: they must keep the
    clearance; every plate keeps the edge distance."""
    for c, p in enumerate(plates):
        if not p.is_valid:
            raise FabricationError(f"capacitor {c}: its outline is not a simple polygon")
        margin = sheet.exterior.distance(p) if sheet.contains(p) else 0.0
        if margin < rules.edge_distance_mm - 1e-9:
            raise FabricationError(f"capacitor {c} is {margin:.4g} mm from the sheet edge, less than "
                                   f"fabrication.edge_distance_mm = {rules.edge_distance_mm:g}")
        for d in range(c):
            gap = p.distance(plates[d])
            if gap < rules.clearance_mm - 1e-9:
                what = "overlap" if gap == 0 and p.intersects(plates[d]) else f"are {gap:.4g} mm apart"
                raise FabricationError(f"capacitors {d} and {c} {what}, less than fabrication.clearance_mm = "
                                       f"{rules.clearance_mm:g}: in one conductive layer they are different nets")


def _edge_context(sheet: Polygon, plates: list[Polygon], pads, masks, ends, rules: FabricationSettings) -> "_Context":
    """What every slot assignment on one connector edge shares: the routing grid and the
    masks of the plates, the pads, their strips and stubs (made once per edge, not per
    assignment)."""
    f = rules
    h = routing_grid_mm(f)
    grid = Grid.covering(sheet.bounds, h, tuple(ends[0]))
    half = 0.5 * f.trace_width_mm
    margin = h / np.sqrt(2.0)
    corridor = grid.mask(sheet.buffer(-(f.edge_distance_mm + half)))
    inner = [grid.mask(p.buffer(-half - 1e-6)) for p in plates]
    keep_out = [grid.mask(p, f.clearance_mm + half + margin) for p in plates]
    pad_inner = [grid.mask(pad.buffer(-half - 1e-6)) | grid.mask(Point(e).buffer(0.25 * h)) for pad, e in zip(pads, ends)]
    pad_out = [grid.mask(pad, f.clearance_mm + half + margin) for pad in pads]
    reach = float(np.hypot(*np.ptp(np.asarray(sheet.exterior.coords), axis=0)))
    rays, stubs = [], []
    all_plates = unary_union(plates)
    for pad, end in zip(pads, ends):  # the strip straight inward from each pad, one pitch wide
        inward = np.asarray(end) - np.asarray(pad.centroid.coords[0])
        inward /= np.linalg.norm(inward)
        side = 0.5 * f.pad_pitch_mm * np.array([-inward[1], inward[0]])
        ray = Polygon([end - side, end + side, end + side + reach * inward, end - side + reach * inward])
        rays.append((ray, grid.mask(ray)))
        # While its net waits, a pad keeps the first STUB_PITCHES pitches straight inward
        # for its own lead: a neighbour turning off across it would wall it in.
        # It stops short of the plates by a lane, so that leads can still pass in front of it.
        depth = min(STUB_PITCHES * f.pad_pitch_mm,
                    all_plates.distance(Point(end)) - 2 * (f.clearance_mm + half + margin) - 2 * h)
        stub = (LineString([end, end + depth * inward]).buffer(0.5 * f.pad_width_mm, cap_style="flat")
                if depth > 0 else Polygon())
        stubs.append(grid.mask(unary_union([pad, stub]), f.clearance_mm + half + margin))
    return _Context(grid, corridor, inner, keep_out, pad_inner, pad_out, rays, stubs, plates, pads, masks, sheet,
                    sheet.buffer(-f.edge_distance_mm), f, {}, {})


def _route_assignment(array: CapacitorArray, edge: str, shared: "_Context") -> Routing:
    """Route every net of one slot assignment on the ``edge`` whose :func:`_edge_context`
    is ``shared``: the bottom layer, then the top one (whose leads avoid the bottom's), then
    the bottom again against the top's leads."""
    members = {name: [c for c, (i, j) in enumerate(array.slots) if (i if layer == "bottom" else j) == int(name[1:])]
               for name, layer, _ in _nets(array)}
    context = replace(shared, members=members, lead_of={name: lead for name, _, lead in _nets(array)})
    order = list(_nets(array))
    error = None
    for attempt in _orders(order):  # within a layer, an earlier lead can wall a later one in
        nets = {name: None for name, _, _ in order}
        try:
            for layer in dict.fromkeys(n[1] for n in attempt):
                group = [n for n in attempt if n[1] == layer]
                # Every net's plates joined first: a pad's lead then goes round the other
                # nets' rows of plates instead of between two plates another net must join.
                for name, layer_, lead in group:
                    nets[name] = _route_net(context, name, layer_, lead, nets, "plates")
                for name, layer_, lead in group:
                    nets[name] = _route_net(context, name, layer_, lead, nets, "pad")
            break
        except FabricationError as exc:
            error = error or exc
    else:
        raise error
    for name, layer, lead in attempt:  # the bottom again, now costing the top's leads
        if layer == "bottom":
            try:  # everything else stays as it is, so either route is valid: keep the old one if need be
                partial = _route_net(context, name, layer, lead, {**nets, name: None}, "plates")
                nets[name] = _route_net(context, name, layer, lead, {**nets, name: partial}, "pad")
            except FabricationError:
                pass
    return Routing(array, edge, tuple(nets[name] for name, _, _ in order), context.sheet, tuple(context.plates),
                   context.rules)


def _orders(order: list) -> list[list]:
    """The orders to route the nets in: lead order, then each layer's nets reversed, then
    the top layer before the bottom."""
    bottom = [n for n in order if n[1] == "bottom"]
    top = [n for n in order if n[1] == "top"]
    return [bottom + top, bottom[::-1] + top[::-1], top + bottom, top[::-1] + bottom[::-1]]


def _nets(array: CapacitorArray):
    """(name, layer, lead) in lead order."""
    return ([(f"R{i}", "bottom", i) for i in range(array.rows)]
            + [(f"C{j}", "top", array.rows + j) for j in range(array.columns)])


@dataclass
class _Context:
    grid: Grid
    corridor: np.ndarray
    inner: list
    keep_out: list
    pad_inner: list
    pad_out: list
    rays: list
    stubs: list
    plates: list
    pads: list
    masks: list
    sheet: Polygon
    allowed: Polygon  # the sheet less the edge distance
    rules: FabricationSettings
    members: dict  # per assignment: each net's capacitors
    lead_of: dict  # per assignment: each net's lead (pad) index


def _route_net(ctx: _Context, name: str, layer: str, lead: int, nets: dict, stage: str) -> Net:
    """Route net ``name`` on the grid with the other nets of its layer (plates, pads and
    leads so far) kept out and the other layer's leads and pads costed
    (:data:`OVERLAP_WEIGHT_MM` per mm² of overlap): ``stage = "plates"`` joins its plates
    to each other, from the one nearest its pad; ``"pad"`` joins its pad to them
    (``nets[name]`` holds the first stage's net)."""
    f, grid = ctx.rules, ctx.grid
    half = 0.5 * f.trace_width_mm
    margin = grid.h / np.sqrt(2.0)
    own = ctx.members[name]
    blocked = np.zeros(grid.size, dtype=bool)
    same_layer, other_layer = [], []
    for other, net in nets.items():
        if other == name:
            continue
        if _layer_of(other) != layer:
            if net is not None:
                other_layer.extend(_lead_polygons(net, f) + [net.pad])
            else:
                other_layer.append(ctx.pads[ctx.lead_of[other]])
            continue
        for c in ctx.members[other]:
            blocked |= ctx.keep_out[c]
        waiting_pad = net is None or not net.pad_joined
        blocked |= (ctx.stubs if waiting_pad else ctx.pad_out)[ctx.lead_of[other]]
        if net is not None:
            same_layer.append(net.conductor)
            for lead_polygon in _lead_polygons(net, f):
                blocked |= grid.mask(lead_polygon, f.clearance_mm + half + margin)
    free = ctx.corridor & ~blocked
    for c in own:
        free |= ctx.inner[c]
    free |= ctx.pad_inner[lead]
    other_geometry = unary_union(other_layer) if other_layer else None
    cost = np.ones(grid.size)
    if other_geometry is not None:
        cost += OVERLAP_WEIGHT_MM * f.trace_width_mm * grid.mask(other_geometry, half)
    rivals = [o for o in nets if o != name and _layer_of(o) == layer]  # the other nets of this layer
    rival_plates = unary_union([ctx.plates[c] for o in rivals for c in ctx.members[o]])
    pending = [o for o in rivals if nets[o] is None or not nets[o].pad_joined]
    costly = []  # what the grid costs, as geometry: straightening a path may not add to it
    for other in pending:  # crossing in front of a pad still to be routed can wall it in
        ray, ray_cells = ctx.rays[ctx.lead_of[other]]
        cost += RAY_WEIGHT * ray_cells
        costly.append(ray)
    if pending:  # leave room beside the other nets' plates for the leads still to come
        room = f.clearance_mm + half + margin + len(pending) * (f.trace_width_mm + f.clearance_mm)
        cost += NEAR_WEIGHT * grid.mask(rival_plates, room)
        costly.append(rival_plates.buffer(room, quad_segs=4))
    costly = unary_union(costly) if costly else None
    forbidden = unary_union(same_layer + [rival_plates] + [ctx.pads[ctx.lead_of[o]] for o in rivals])
    allowed = ctx.allowed
    pad = ctx.pads[lead]
    if stage == "plates":
        paths: list = []
        if not own:
            return Net(name, layer, lead, (), pad, ctx.masks[lead], (), Polygon(), pad_joined=False)
        first = min(own, key=lambda c: ctx.plates[c].distance(pad))
        tree = np.flatnonzero(ctx.inner[first])
        joined, waiting = [ctx.plates[first]], [c for c in own if c != first]
        targets = {c: np.flatnonzero(ctx.inner[c]) for c in waiting}
    else:
        paths = list(nets[name].paths)
        tree = np.flatnonzero(ctx.pad_inner[lead])
        joined, waiting = [pad], (["plates"] if own else [])
        targets = {"plates": np.flatnonzero(np.logical_or.reduce([ctx.inner[c] for c in own]))} if own else {}
    graph = grid.graph(free, cost) if waiting else None
    while waiting:
        dist, pred = Grid.nearest(graph, tree)
        reach = [(float(dist[targets[t]].min()) if targets[t].size else np.inf, i) for i, t in enumerate(waiting)]
        d, i = min(reach)
        t = waiting[i]
        if not np.isfinite(d):
            c = t if t != "plates" else own[0]
            raise FabricationError(_blocked_message(ctx, name, layer, c, dist, forbidden))
        end = int(targets[t][np.argmin(dist[targets[t]])])
        cells = Grid.path(pred, end)
        goal = unary_union([ctx.plates[c] for c in own]) if t == "plates" else ctx.plates[t]
        points = trim_path(grid.points(cells), unary_union(joined), goal)
        paths.append(pull_straight(points, forbidden, allowed, other_geometry, f, costly))
        joined.append(goal)
        tree = np.union1d(np.union1d(tree, cells), targets[t])
        waiting.pop(i)
    leads = [lead_outline(p, f) for p in paths if len(p) > 1]
    body = unary_union(([pad] if stage == "pad" else []) + [ctx.plates[c] for c in own] + leads)
    if f.min_radius_mm > 0 and leads:  # fillets where leads bend and meet pads and plates, not plate corners
        r = f.min_radius_mm
        closed = body.buffer(r, quad_segs=8).buffer(-r, quad_segs=8)
        body = unary_union([body, closed.intersection(unary_union(leads).buffer(2 * r))])
    if body.geom_type == "MultiPolygon":  # slivers of round-off beside the conductor
        body = unary_union([p for p in body.geoms if p.area > 1e-6])
    return Net(name, layer, lead, tuple(own), pad, ctx.masks[lead], tuple(paths), body, pad_joined=stage == "pad")


def _layer_of(name: str) -> str:
    """The conductive layer of net ``name``: rows (``R…``) below, columns (``C…``) above."""
    return "bottom" if name[0] == "R" else "top"


def _lead_polygons(net: Net, f: FabricationSettings) -> list:
    return [lead_outline(p, f) for p in net.paths if len(p) > 1]


def _blocked_message(ctx: _Context, name: str, layer: str, c: int, dist: np.ndarray, forbidden) -> str:
    """Where capacitor ``c`` is cut off: the reachable point nearest its plate and what
    of its layer stands between."""
    f = ctx.rules
    reachable = np.flatnonzero(np.isfinite(dist))
    plate = ctx.plates[c]
    slot = "row" if layer == "bottom" else "column"
    head = (f"capacitor {c} cannot be joined to net {name} ({slot} lead) in the {layer} layer: ")
    if reachable.size == 0:
        return head + "its pad has no free cell (pads closer than clearance_mm + trace_width_mm?)"
    points = ctx.grid.points(reachable)
    gaps = shapely.distance(plate, shapely.points(points))
    best = int(np.argmin(gaps))
    x, y = points[best]
    others = [d for other, cs in ctx.members.items() if other != name
              and _layer_of(other) == layer for d in cs]
    near = (f" next to capacitor {min(others, key=lambda d: Point(x, y).distance(ctx.plates[d]))}"
            if others else "")
    return (head + f"every path from its pad stops {gaps[best]:.3g} mm short of it, at ({x:.4g}, {y:.4g}) mm"
            f"{near}; a lead needs a channel trace_width_mm + 2 clearance_mm = "
            f"{f.trace_width_mm + 2 * f.clearance_mm:g} mm wide, {f.edge_distance_mm:g} mm from the sheet edge")
