"""Stencil files of a routed design (paper appendix B): one per conductive layer, as DXF
and SVG in millimetres, seen from above (the top stencil is not mirrored).

Each file holds, as closed outlines: the sheet (layer/group ``SHEET``), every net of the
layer (``NET_R0``, ``NET_C1``, ...; a region with holes is its outer ring and its inner
rings, even-odd), the masks over that layer's pads (``MASK``) and three registration
crosses outside the sheet at the same place in both files (``REGISTRATION``; three, at
three corners, so the stencils cannot be laid turned). :func:`read_stencil` reads either
format back into the same shapely regions, which :mod:`mscap.fabrication.check` checks.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import ezdxf
import numpy as np
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from mscap.errors import FabricationError
from mscap.fabrication.router import Routing

__all__ = ["REGISTRATION_OFFSET_MM", "registration_marks", "layer_regions", "write_dxf", "write_svg",
           "read_stencil", "regions", "MAX_STENCIL_BYTES"]

#: The registration crosses sit this far outside the sheet's bounding box, 6 mm long and
#: 0.6 mm wide (a cutter makes them; a pin or a printed cross lines them up).
REGISTRATION_OFFSET_MM = 5.0
_CROSS_MM = (6.0, 0.6)
_SVG_NS = "http://www.w3.org/2000/svg"


def registration_marks(sheet: Polygon) -> list[Polygon]:
    """Three crosses (one closed outline each) at three corners of the sheet's box."""
    minx, miny, maxx, maxy = sheet.bounds
    d = REGISTRATION_OFFSET_MM
    arm, width = _CROSS_MM
    marks = []
    for x, y in ((minx - d, miny - d), (maxx + d, miny - d), (minx - d, maxy + d)):
        cross = unary_union([box(x - arm / 2, y - width / 2, x + arm / 2, y + width / 2),
                             box(x - width / 2, y - arm / 2, x + width / 2, y + arm / 2)])
        marks.append(cross)
    return marks


def layer_regions(routing: Routing, layer: str) -> dict[str, list[Polygon]]:
    """What a stencil of ``layer`` holds, by group: ``SHEET``, ``NET_<name>`` per net,
    ``MASK``, ``REGISTRATION`` (polygons, mm)."""
    groups = {"SHEET": [routing.sheet]}
    for net in routing.layer(layer):
        groups[f"NET_{net.name}"] = list(getattr(net.conductor, "geoms", [net.conductor]))
    groups["MASK"] = [net.mask for net in routing.layer(layer)]
    groups["REGISTRATION"] = registration_marks(routing.sheet)
    return groups


def _rings(polygon: Polygon) -> list[np.ndarray]:
    rings = [np.asarray(polygon.exterior.coords)[:-1]]
    rings += [np.asarray(r.coords)[:-1] for r in polygon.interiors]
    return rings


def write_dxf(path: Path, groups: dict[str, list[Polygon]]) -> None:
    """A DXF (R2010, $INSUNITS millimetres) with one layer per group, each ring a closed
    LWPOLYLINE."""
    doc = ezdxf.new("R2010", setup=False)
    doc.units = ezdxf.units.MM
    msp = doc.modelspace()
    for color, (name, polygons) in enumerate(groups.items(), start=1):
        doc.layers.add(name, color=color % 7 + 1)
        for polygon in polygons:
            for ring in _rings(polygon):
                msp.add_lwpolyline(np.round(ring, 6).tolist(), close=True, dxfattribs={"layer": name})
    doc.saveas(path)


def write_svg(path: Path, groups: dict[str, list[Polygon]], bounds) -> None:
    """An SVG whose user unit is 1 mm (width and height in mm, the viewBox in mm) and
    whose point (x, −y) is the sheet's (x, y) (SVG's y axis points down), one ``<g id>``
    per group and one even-odd ``<path>`` per polygon."""
    minx, miny, maxx, maxy = bounds
    width, height = maxx - minx, maxy - miny
    svg = ET.Element("svg", xmlns=_SVG_NS, version="1.1", width=f"{width:.4f}mm", height=f"{height:.4f}mm",
                     viewBox=f"{minx:.4f} {-maxy:.4f} {width:.4f} {height:.4f}")
    for name, polygons in groups.items():
        g = ET.SubElement(svg, "g", id=name, fill="none", stroke="black", **{"stroke-width": "0.1"})
        for polygon in polygons:
            d = []
            for ring in _rings(polygon):
                xy = np.column_stack([ring[:, 0], -ring[:, 1]])
                d.append("M " + " L ".join(f"{x:.6f} {y:.6f}" for x, y in xy) + " Z")
            ET.SubElement(g, "path", d=" ".join(d), **{"fill-rule": "evenodd"})
    ET.ElementTree(svg).write(path, encoding="utf-8", xml_declaration=True)


#: The largest stencil file read back (one of 100 nets of 5,000 vertices each is ~20 MB).
MAX_STENCIL_BYTES = 64 * 2**20


def read_stencil(path: Path) -> dict[str, list]:
    """The groups of a stencil file (DXF or SVG) as lists of rings ((n, 2) arrays, mm,
    sheet coordinates).

    Raises
    ------
    FabricationError
        Not a stencil file mscap can read (an open polyline, a path that is not closed).
    """
    from mscap.infile import check_regular

    path = Path(path)
    try:  # ezdxf and ElementTree would wait on a FIFO for ever and read a device until memory ends
        check_regular(path, "a stencil file", MAX_STENCIL_BYTES)
    except (OSError, ValueError) as exc:
        raise FabricationError(f"{path}: {exc}") from None
    rings: dict[str, list] = {}
    if path.suffix == ".dxf":
        try:
            doc = ezdxf.readfile(path)
        except (OSError, ezdxf.DXFError) as exc:
            raise FabricationError(f"{path}: not a readable DXF file ({exc})") from None
        for entity in doc.modelspace():
            if entity.dxftype() != "LWPOLYLINE":
                continue
            if not entity.closed:
                raise FabricationError(f"{path}: layer {entity.dxf.layer}: an open polyline")
            rings.setdefault(entity.dxf.layer, []).append(np.array([p[:2] for p in entity.get_points()]))
        return rings
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise FabricationError(f"{path}: not a readable SVG file ({exc})") from None
    for g in root.iter(f"{{{_SVG_NS}}}g"):
        for element in g.iter(f"{{{_SVG_NS}}}path"):
            for sub in re.findall(r"M([^MZ]*)Z", element.get("d")):
                xy = np.array([float(v) for v in re.findall(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", sub)]).reshape(-1, 2)
                rings.setdefault(g.get("id"), []).append(np.column_stack([xy[:, 0], -xy[:, 1]]))
            if not element.get("d").rstrip().endswith("Z"):
                raise FabricationError(f"{path}: group {g.get('id')}: a path that is not closed")
    return rings


def regions(rings: list[np.ndarray]):
    """The even-odd region of closed rings (their symmetric difference)."""
    region = Polygon()
    for ring in rings:
        region = region.symmetric_difference(Polygon(ring).buffer(0))
    return region
