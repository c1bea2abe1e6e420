"""The stencil files as written: DXF read by ezdxf, SVG by svgelements (neither by
mscap's own reader), closed outlines whose union per layer holds every plate, the design
rules measured on that geometry, and the overlaps fabrication.json reports found again in
the files. The design is pneumatic_quick's chosen one (tests/fabrication/data), routed
to the top edge with the read-out's default slots only, where a row lead has to cross a
column lead (the router's own choice, the right edge and other slots, crosses nothing)."""

from __future__ import annotations

import ezdxf
import numpy as np
import pytest
import svgelements
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from mscap.errors import FabricationError
from mscap.fabrication.check import check_layer
from mscap.fabrication.report import FABRICATION_FILES, write_fabrication
from mscap.viz.fabrication import plot_routing
from mscap.fabrication.router import route
from mscap.fabrication.stencil import read_stencil
from mscap.scene.settings import EPSILON0_PF_PER_MM, FabricationSettings
from tests.fabrication.conftest import pneumatic_design
RULES = FabricationSettings()


def even_odd(rings):
    region = Polygon()
    for ring in rings:
        region = region.symmetric_difference(Polygon(ring).buffer(0))
    return region


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fabricate")
    scene, plates = pneumatic_design(tmp)
    routing = route(plates, scene.sheet_outline_mm, scene.fabrication)
    document = write_fabrication(routing, tmp / "out", scene, "pneumatic k3", preview=plot_routing)
    return tmp / "out", [Polygon(p) for p in plates], document, scene


def dxf_layers(path):
    doc = ezdxf.readfile(path)
    assert doc.header["$INSUNITS"] == 4  # millimetres
    groups = {}
    for entity in doc.modelspace():
        assert entity.dxftype() == "LWPOLYLINE" and entity.closed
        groups.setdefault(entity.dxf.layer, []).append(np.array([p[:2] for p in entity.get_points()]))
    return groups


def test_every_file_is_written_and_nothing_else(written):
    out, _, _, _ = written
    assert sorted(p.name for p in out.iterdir()) == sorted(FABRICATION_FILES)
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".out")]  # no temporary left


@pytest.mark.parametrize("layer", ["bottom", "top"])
def test_dxf_holds_closed_outlines_whose_union_holds_every_plate(written, layer):
    out, plates, _, _ = written
    groups = dxf_layers(out / f"{layer}.dxf")
    assert {"SHEET", "MASK", "REGISTRATION"} <= set(groups)
    nets = {name: even_odd(rings) for name, rings in groups.items() if name.startswith("NET_")}
    assert sorted(nets) == ([f"NET_R{i}" for i in range(2)] if layer == "bottom" else [f"NET_C{j}" for j in range(2)])
    union = unary_union(list(nets.values()))
    for plate in plates:
        assert union.buffer(1e-6).contains(plate)


@pytest.mark.parametrize("layer", ["bottom", "top"])
def test_svg_parses_into_the_same_regions_as_the_dxf(written, layer):
    out, _, _, _ = written
    svg = svgelements.SVG.parse(str(out / f"{layer}.svg"), ppi=25.4)  # one user unit per mm
    minx, min_negy = svg.viewbox.x, svg.viewbox.y  # the file's point (x, −y) is the sheet's (x, y)
    groups = {}
    for element in svg.elements():
        if isinstance(element, svgelements.Path):
            group = element.values["id"] if "id" in element.values else None
            parent = [g for g in svg.elements() if isinstance(g, svgelements.Group) and element in list(g)]
            name = parent[-1].id if parent else group
            ring = []
            for segment in element.segments():
                if isinstance(segment, svgelements.Move):
                    if ring:
                        groups.setdefault(name, []).append(np.array(ring))
                    ring = [segment.end]
                elif isinstance(segment, svgelements.Line):
                    ring.append(segment.end)
                else:
                    assert isinstance(segment, svgelements.Close)
            groups.setdefault(name, []).append(np.array(ring))
    dxf = dxf_layers(out / f"{layer}.dxf")
    assert sorted(groups) == sorted(dxf)
    for name, rings in groups.items():
        sheet_xy = [np.column_stack([r[:, 0] + minx, -(r[:, 1] + min_negy)]) for r in rings]
        region = even_odd(dxf[name])
        # svgelements' mm unit scales by 1 ± 1e-6: a band of 1e-4 mm along the outlines
        assert even_odd(sheet_xy).symmetric_difference(region).area < 1e-4 * region.length
    assert {n: len(r) for n, r in read_stencil(out / f"{layer}.svg").items()} == {n: len(r) for n, r in dxf.items()}


@pytest.mark.parametrize("layer", ["bottom", "top"])
def test_design_rules_hold_on_the_written_geometry(written, layer):
    out, plates, _, _ = written
    groups = dxf_layers(out / f"{layer}.dxf")
    sheet = even_odd(groups["SHEET"])
    nets = {name: even_odd(rings) for name, rings in groups.items() if name.startswith("NET_")}
    names = sorted(nets)
    for a, name in enumerate(names):
        net = nets[name]
        assert net.geom_type == "Polygon"  # one conductor
        assert sheet.exterior.distance(net) >= RULES.edge_distance_mm - 1e-3 and sheet.contains(net)
        for other in names[a + 1:]:
            assert net.distance(nets[other]) >= RULES.clearance_mm - 1e-3
        leads = net.difference(unary_union(plates).buffer(1e-6))
        half = 0.5 * RULES.trace_width_mm - 1e-3
        for piece in getattr(leads, "geoms", [leads]):  # every lead at least trace_width_mm wide
            if piece.area > 1e-2:
                opened = piece.buffer(-half).buffer(half)
                assert opened.area > 0.9 * piece.area
    masks = [Polygon(r) for r in groups["MASK"]]
    assert len(masks) == len(nets) and all(sum(m.intersects(n) for m in masks) == 1 for n in nets.values())


def test_overlaps_in_the_json_are_in_the_files_at_their_parallel_plate_capacitance(written):
    out, plates, document, scene = written
    bottom = unary_union([even_odd(r) for n, r in dxf_layers(out / "bottom.dxf").items() if n.startswith("NET_")])
    top = unary_union([even_odd(r) for n, r in dxf_layers(out / "top.dxf").items() if n.startswith("NET_")])
    outside_plates = bottom.intersection(top).difference(unary_union(plates).buffer(1e-6))
    assert document["overlap_mm2"] == pytest.approx(outside_plates.area, abs=1e-3)
    assert document["overlap_mm2"] > 0.99  # a lead crossing: 1 x 1 mm at least (the trace width squared)
    # the small scene's middle dielectric: εr 2.84, 0.14 mm
    assert document["overlap_capacitance_pF"] == pytest.approx(
        document["overlap_mm2"] * 2.84 * EPSILON0_PF_PER_MM / 0.14, rel=1e-12)
    assert document["design_rule_check"]["violations"] == []
    assert [p["net"] for p in document["pads"]] == ["R0", "R1", "C0", "C1"]


def test_the_check_can_fail():
    rules = FabricationSettings()
    sheet = [np.array([[0, 0], [50, 0], [50, 50], [0, 50.0]])]
    plate = np.array([[10, 10], [20, 10], [20, 20], [10, 20.0]])
    lead = np.array([[14.7, 20], [15.3, 20], [15.3, 40], [14.7, 40.0]])  # 0.6 mm wide
    net = np.asarray(unary_union([Polygon(plate), Polygon(lead)]).exterior.coords)[:-1]
    mask = [np.asarray(box(14, 39, 16, 41).exterior.coords)[:-1]]
    thin = check_layer({"SHEET": sheet, "NET_R0": [net], "MASK": mask}, rules, [Polygon(plate)])
    assert any("thinner than trace_width_mm 1" in v for v in thin["violations"])
    near = np.array([[21.5, 10], [30, 10], [30, 20], [21.5, 20.0]])  # 1.5 mm from the plate: fine
    close = np.array([[20.5, 10], [30, 10], [30, 20], [20.5, 20.0]])  # 0.5 mm: not
    ok = check_layer({"SHEET": sheet, "NET_R0": [plate], "NET_R1": [near]}, rules, [])
    assert not any("apart" in v for v in ok["violations"]) and ok["min_clearance_mm"] == pytest.approx(1.5)
    bad = check_layer({"SHEET": sheet, "NET_R0": [plate], "NET_R1": [close]}, rules, [])
    assert any("nets R0 and R1 are 0.5 mm apart" in v for v in bad["violations"])
    edge = check_layer({"SHEET": sheet, "NET_R0": [plate - 9.5]}, rules, [])
    assert any("0.5 mm from the sheet edge" in v for v in edge["violations"])
    split = check_layer({"SHEET": sheet, "NET_R0": [plate, near]}, rules, [])
    assert any("is 2 pieces" in v for v in split["violations"])
    orphan = check_layer({"SHEET": sheet, "NET_R0": [near]}, rules, [Polygon(plate)])
    assert any("capacitor 0's plate lies in 0 nets" in v for v in orphan["violations"])


def test_an_existing_output_is_refused_and_a_failed_write_leaves_nothing(written, tmp_path):
    out, plates, _, scene = written
    routing = route([np.asarray(p.exterior.coords)[:-1] for p in plates], scene.sheet_outline_mm, scene.fabrication)
    with pytest.raises(FabricationError, match="exists \\(a directory\\)"):
        write_fabrication(routing, out, scene, "again")
    (tmp_path / "link").symlink_to(tmp_path / "nowhere")
    with pytest.raises(FabricationError, match="exists \\(a link\\)"):
        write_fabrication(routing, tmp_path / "link", scene, "again")
    assert not (tmp_path / "nowhere").exists()
    broken = type(routing)(routing.array, routing.edge, routing.nets, routing.sheet, routing.plates,
                           FabricationSettings(clearance_mm=5.0, connector_edge="top"))  # broken by the files
    with pytest.raises(FabricationError, match="the written stencils break the design rules"):
        write_fabrication(broken, tmp_path / "new", scene, "broken")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link"]
