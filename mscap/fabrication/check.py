"""The design-rule check, on the stencil files as written (DXF and SVG read back), not
on the router's bookkeeping.

Per layer and file: every outline closed (the readers refuse open ones), each net one
piece, nets ``clearance_mm`` apart, ``edge_distance_mm`` inside the sheet, no part
thinner than the trace width outside the plates (an opening by half of it, with the
net's plates put back, leaves the net in one piece and takes off nothing larger than a
corner), bends filleted (a closing by ``min_radius_mm``
adds next to nothing), every plate of the design inside exactly one net, one mask per pad;
across files: the DXF and the SVG hold the same regions, both layers the same
registration crosses.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from shapely.geometry import Polygon
from shapely.ops import unary_union

from mscap.fabrication.stencil import read_stencil, regions
from mscap.scene.settings import FabricationSettings

__all__ = ["TOLERANCE_MM", "check_layer", "check_stencils"]

#: Lengths are written to 1e-6 mm and arcs are 32-gons: rules hold to this.
TOLERANCE_MM = 1e-3


def check_layer(groups: dict[str, list], rules: FabricationSettings, plates: list[Polygon]) -> dict:
    """Measure one layer's rules on its groups of rings (:func:`read_stencil`):
    ``min_clearance_mm``, ``min_edge_distance_mm``, ``max_thin_piece_mm2`` (the largest
    piece an opening by half the trace width takes off), ``max_fillet_gap_mm2`` (the area
    a closing by ``min_radius_mm`` adds to a net), ``violations`` (one line each)."""
    f = rules
    sheet = regions(groups.get("SHEET", []))
    nets = {name[4:]: regions(rings) for name, rings in groups.items() if name.startswith("NET_")}
    masks = [Polygon(r) for r in groups.get("MASK", [])]
    violations = []
    report = {"nets": sorted(nets), "min_clearance_mm": np.inf, "min_edge_distance_mm": np.inf,
              "max_thin_piece_mm2": 0.0, "max_fillet_gap_mm2": 0.0}
    names = sorted(nets)
    for a, name in enumerate(names):
        net = nets[name]
        if net.geom_type != "Polygon":
            violations.append(f"net {name} is {len(getattr(net, 'geoms', []))} pieces, not one conductor")
        for other in names[a + 1:]:
            gap = net.distance(nets[other])
            report["min_clearance_mm"] = min(report["min_clearance_mm"], gap)
            if gap < f.clearance_mm - TOLERANCE_MM:
                violations.append(f"nets {name} and {other} are {gap:.4g} mm apart (clearance_mm {f.clearance_mm:g})")
        edge = sheet.exterior.distance(net) if sheet.contains(net) else 0.0
        report["min_edge_distance_mm"] = min(report["min_edge_distance_mm"], edge)
        if edge < f.edge_distance_mm - TOLERANCE_MM:
            violations.append(f"net {name} is {edge:.4g} mm from the sheet edge (edge_distance_mm "
                              f"{f.edge_distance_mm:g})")
        a_half = 0.5 * f.trace_width_mm - TOLERANCE_MM
        own = unary_union([p for p in plates if net.buffer(TOLERANCE_MM).contains(p)])
        opened = unary_union([net.buffer(-a_half, quad_segs=16).buffer(a_half, quad_segs=16), own])
        pieces = net.difference(opened.buffer(TOLERANCE_MM))
        largest = max((p.area for p in getattr(pieces, "geoms", [pieces])), default=0.0)
        report["max_thin_piece_mm2"] = max(report["max_thin_piece_mm2"], largest)
        if opened.geom_type != "Polygon" or largest > a_half ** 2:
            violations.append(f"net {name} has a part thinner than trace_width_mm {f.trace_width_mm:g} "
                              f"(an opening by half of it leaves {len(getattr(opened, 'geoms', [opened]))} "
                              f"pieces and takes off {largest:.3g} mm2)")
        if f.min_radius_mm > 0:
            r = f.min_radius_mm - TOLERANCE_MM
            gap = net.buffer(r, quad_segs=16).buffer(-r, quad_segs=16).difference(net).area
            report["max_fillet_gap_mm2"] = max(report["max_fillet_gap_mm2"], gap)
            if gap > 0.01:
                violations.append(f"net {name} has corners sharper than min_radius_mm {f.min_radius_mm:g} "
                                  f"(a closing adds {gap:.3g} mm2)")
        holding = [m for m in masks if m.intersects(net)]
        if len(holding) != 1:
            violations.append(f"net {name} is under {len(holding)} masks, not one")
    for c, plate in enumerate(plates):
        inside = [name for name, net in nets.items() if net.buffer(TOLERANCE_MM).contains(plate)]
        if len(inside) != 1:
            violations.append(f"capacitor {c}'s plate lies in {len(inside)} nets of the layer, not one")
    report["violations"] = violations
    return report


def check_stencils(directory: Path, rules: FabricationSettings, plates: list[Polygon],
                   layers=("bottom", "top")) -> dict:
    """:func:`check_layer` of every layer's DXF and SVG in ``directory``, and the
    agreements across files; ``{"layers": {layer: report}, "violations": [...]}``."""
    directory = Path(directory)
    out = {"layers": {}, "violations": []}
    marks = {}
    for layer in layers:
        dxf = read_stencil(directory / f"{layer}.dxf")
        svg = read_stencil(directory / f"{layer}.svg")
        report = check_layer(dxf, rules, plates)
        out["layers"][layer] = report
        out["violations"] += [f"{layer}: {v}" for v in report["violations"]]
        if sorted(dxf) != sorted(svg):
            out["violations"].append(f"{layer}: the DXF has groups {sorted(dxf)}, the SVG {sorted(svg)}")
        for name in set(dxf) & set(svg):
            differ = regions(dxf[name]).symmetric_difference(regions(svg[name])).area
            if differ > TOLERANCE_MM ** 2:
                out["violations"].append(f"{layer}: {name} differs between the DXF and the SVG by {differ:.3g} mm2")
        marks[layer] = regions(dxf.get("REGISTRATION", []))
    if len(marks) == 2 and marks[layers[0]].symmetric_difference(marks[layers[1]]).area > TOLERANCE_MM ** 2:
        out["violations"].append("the two stencils' registration crosses differ")
    return out
