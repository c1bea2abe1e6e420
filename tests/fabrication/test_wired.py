"""The sensor simulated as it is wired: the routed nets meshed conforming to both
conductive layers, their Maxwell matrix read as c_ij, against the same design's plates on
the same mesh. Pinned against the parallel-plate capacitance of the one lead crossing
of pneumatic_quick's design routed to the top edge (tests/fabrication/data)."""

from __future__ import annotations

import numpy as np
import pytest

from mscap.errors import FabricationError
from mscap.fabrication.report import write_fabrication
from mscap.fabrication.router import route
from mscap.fabrication.wired import plates_only, read_wiring_dir, readings, wired_mesh, wiring_of
from mscap.mesh.layered import BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER
from mscap.scene.settings import EPSILON0_PF_PER_MM
from tests.conftest import SMALL_SCENE, to_toml
from tests.fabrication.conftest import pneumatic_design


@pytest.fixture(scope="module")
def routed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wired")
    scene, outlines = pneumatic_design(tmp)  # one free pose, rest: electrostatics only
    routing = route(outlines, scene.sheet_outline_mm, scene.fabrication)
    write_fabrication(routing, tmp / "fab", scene, "pneumatic k3")
    return scene, outlines, routing, tmp / "fab"


def test_the_wired_mesh_holds_each_net_in_its_own_layer(routed):
    scene, _, routing, _ = routed
    mesh = wired_mesh(scene.sheet, wiring_of(routing))
    areas = mesh.mesh2d.areas()[mesh.triangle_of_tet]
    for layer, nets in ((BOTTOM_PLATE_LAYER, routing.layer("bottom")), (TOP_PLATE_LAYER, routing.layer("top"))):
        for i, net in enumerate(nets):
            in_net = (mesh.layer_of_tet == layer) & (mesh.capacitor_of_tet == i)
            # three tets per prism, one slab per layer: a third of the triangles' area each
            assert areas[in_net].sum() / 3 == pytest.approx(net.conductor.area, rel=1e-3)
    assert (mesh.volumes() > 0).all()


def test_a_lead_crossing_adds_its_capacitance_to_its_slot_alone(routed):
    scene, outlines, routing, _ = routed
    (crossing,) = [o for o in routing.overlaps() if o["area_mm2"] > 0.5]
    slot = (crossing["row"], crossing["column"])
    c = routing.array.slots.index(slot)
    wiring = wiring_of(routing)
    wired, _ = readings(scene, scene.sheet, wiring)
    plates, _ = readings(scene, scene.sheet, plates_only(outlines, meshed_like=wiring))
    # εr 2.84 across the 0.14 mm middle layer; a 1 mm wide crossing fringes by as much again
    parallel = crossing["area_mm2"] * 2.84 * EPSILON0_PF_PER_MM / 0.14
    added = wired[0] - plates[0]
    assert 1.0 * parallel < added[c] < 2.5 * parallel
    others = np.delete(np.arange(len(outlines)), c)
    assert np.all(np.abs(added[others]) < 2e-3 * plates[0, others])


def test_the_wiring_read_back_from_the_stencils_is_the_routed_one(routed):
    scene, outlines, routing, fab = routed
    wiring = read_wiring_dir(fab, outlines)
    assert wiring.slots == routing.array.slots
    for read, routed_net in zip(wiring.bottom + wiring.top, routing.layer("bottom") + routing.layer("top")):
        assert read.symmetric_difference(routed_net.conductor).area < 1e-4
    moved = [o + np.array([0.0, 5.0]) for o in outlines]
    with pytest.raises(FabricationError, match="capacitor 0's plate is not in net .* the stencils are of another"):
        read_wiring_dir(fab, moved)
    with pytest.raises(FabricationError, match="wires capacitors \\[0, 1, 2\\], the design has 2"):
        read_wiring_dir(fab, outlines[:2])


def test_a_directory_that_is_not_a_fabrication_is_one_line(tmp_path, capsys):
    from mscap.cli import main

    (tmp_path / "fab").mkdir()
    (tmp_path / "fab" / "fabrication.json").write_text('{"array": {"rows": 1}}')
    scene = tmp_path / "scene.toml"
    scene.write_text(to_toml(SMALL_SCENE))
    assert main(["simulate", str(scene), "--wiring", str(tmp_path / "fab"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an `mscap fabricate` output directory" in err
    assert main(["simulate", str(scene), "--wiring", str(tmp_path / "nowhere"), "-q"]) == 2
    assert "No such file" in capsys.readouterr().err


def test_thinning_keeps_every_plate_point_and_moves_near_ones_onto_the_edge():
    import shapely
    from shapely.geometry import box

    from mscap.fabrication.wired import _resampled

    plate = box(0, 0, 10, 10)
    edges = plate.boundary
    corners = shapely.get_coordinates(edges)
    # a ring along the plate's bottom edge with one point 5e-7 below it (the files' rounding),
    # one 1e-4 beside the corner (10, 0), then a round end below it in 0.05 mm steps
    arc = np.column_stack([5 + 0.5 * np.cos(np.linspace(np.pi, 2 * np.pi, 31)),
                           -0.5 + 0.5 * np.sin(np.linspace(np.pi, 2 * np.pi, 31))])
    ring = np.vstack([[0, 0], [3, -5e-7], [9.9999, 0], [10, 0], arc[::-1]])
    thinned = _resampled(ring, edges, corners, spacing=0.25)
    assert [0, 0] in thinned.tolist() and [10, 0] in thinned.tolist()
    assert [3, 0] in thinned.tolist()  # moved onto the edge, exactly
    assert (thinned[:, 0] == 9.9999).sum() == 0 and (thinned == [10, 0]).all(axis=1).sum() == 1  # merged
    off = thinned[~np.isclose(thinned[:, 1], 0)]
    steps = np.linalg.norm(np.diff(off, axis=0), axis=1)
    assert len(off) < 31 and steps.min() >= 0.25 - 1e-12  # the arc thinned to the spacing


def test_the_leads_share_on_one_mesh_is_mesh_converged_where_the_readings_are_not(tmp_path):
    """The plates alone on the wired design's own mesh (``meshed_like``): the readings'
    discretisation error cancels from the leads' share. Two plates, a 2 x 1 array to the
    bottom edge, no crossing: at 1 mm outline edges the readings are 13 % high against
    0.25 mm, the share within 25 % (on two meshes it was -0.45 pF against +0.05 pF)."""
    from mscap.scene import load_scene
    from tests.scenes import scene_dict

    plates = {"min_gap_mm": 1.0, "outlines_mm": [[[3.0, 8.0], [13.0, 8.0], [13.0, 20.0], [3.0, 20.0]],
                                                 [[17.0, 9.0], [27.0, 9.0], [25.0, 19.0], [19.0, 20.0]]]}
    shares, wired = [], []
    for h, outline in ((3.0, 1.0), (2.0, 0.25)):
        path = tmp_path / f"h{outline}.toml"
        path.write_text(to_toml(scene_dict(sheet={"width_mm": 30.0, "height_mm": 24.0}, capacitors=plates,
                                           mesh={"edge_length_mm": h, "edge_length_outline_mm": outline,
                                                 "grading_distance_mm": 3.0},
                                           fabrication={"connector_edge": "bottom", "assignments": 2})))
        scene = load_scene(path)
        wiring = wiring_of(route(scene.layout.outlines, scene.sheet_outline_mm, scene.fabrication))
        as_wired, _ = readings(scene, scene.sheet, wiring)
        alone, _ = readings(scene, scene.sheet, plates_only(scene.layout.outlines, meshed_like=wiring))
        shares.append(as_wired[0] - alone[0])
        wired.append(as_wired[0])
    coarse, fine = shares
    assert np.all(fine > 0.002 * wired[1]) and np.all(fine < 0.02 * wired[1])
    np.testing.assert_allclose(coarse, fine, rtol=0.25)
    assert np.all(wired[0] - wired[1] > 5 * fine)  # the readings' own error: many shares


def test_each_conductive_layer_is_carbon_black_inside_its_own_nets_only(routed):
    """The leads' stiffness: a tet of a conductive layer takes the plate material where its
    triangle lies in a net of that layer (``mesh2d.conductor_of_layer``), the fill
    elsewhere, whatever the other layer holds there."""
    from mscap.mesh.layered import tet_values

    scene, _, routing, _ = routed
    mesh = wired_mesh(scene.sheet, wiring_of(routing))
    mu = tet_values(mesh, scene.layers, lambda material: material.lame_MPa[0])
    carbon, clear = (scene.layers[BOTTOM_PLATE_LAYER].material.lame_MPa[0],
                     scene.layers[BOTTOM_PLATE_LAYER].fill.lame_MPa[0])
    conductive = np.isin(mesh.layer_of_tet, (BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER))
    np.testing.assert_array_equal(mu[conductive] == carbon, mesh.capacitor_of_tet[conductive] >= 0)
    assert set(np.unique(mu[conductive])) == {carbon, clear}
    # a bottom lead's triangles: carbon below, clear above where no column net lies over it
    labels = mesh.mesh2d.conductor_of_layer[mesh.triangle_of_tet]
    lead_only = (labels[:, 0] >= 0) & (labels[:, 1] < 0)
    assert np.all(mu[lead_only & (mesh.layer_of_tet == BOTTOM_PLATE_LAYER)] == carbon)
    assert np.all(mu[lead_only & (mesh.layer_of_tet == TOP_PLATE_LAYER)] == clear)
    assert (lead_only & (mesh.layer_of_tet == TOP_PLATE_LAYER)).any()


def test_the_plates_alone_are_meshed_on_the_wired_designs_very_triangulation(routed):
    """One gmsh run for both: the same curves give the same triangulation, shared (the
    fragmenting and meshing was 8 of the glove design's 30 s of wired readings)."""
    scene, outlines, routing, _ = routed
    wiring = wiring_of(routing)
    wired, alone = wired_mesh(scene.sheet, wiring), wired_mesh(scene.sheet, plates_only(outlines, meshed_like=wiring))
    assert alone.mesh2d.points is wired.mesh2d.points and alone.mesh2d.triangles is wired.mesh2d.triangles
    assert not np.array_equal(alone.capacitor_of_tet, wired.capacitor_of_tet)  # the labels differ
    own = wired_mesh(scene.sheet, plates_only(outlines))  # other curves: another triangulation
    assert len(own.mesh2d.points) != len(wired.mesh2d.points)
