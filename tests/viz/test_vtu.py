"""VTU and PVD export of ``mscap simulate --export``: rest meshes with a displacement
field (Warp By Vector at scale 1 gives the pose), one ParaView collection over the poses,
no stack tags on the elastic mesh."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from mscap.fem.simulate import simulate
from mscap.scene import load_scene
from mscap.viz.vtu import write_poses
from tests.conftest import SMALL_SCENE, to_toml

POSES = [{"name": "rest", "kind": "free"},
         {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"},
         {"name": "press", "kind": "poke", "center_mm": [8.0, 10.0], "radius_mm": 5.0, "depth_mm": 2.0,
          "held_edges": ["x_min", "x_max"]}]
COARSE = {"edge_length_mm": 6.0, "edge_length_outline_mm": 2.0, "grading_distance_mm": 3.0}


# Shared: P1 on the electrostatic mesh (P2 there, the poke's default, cost 19 s for the same
# export; the own mesh's case exports P2 nodes).
@pytest.fixture(scope="module", params=[{"elastic": {"edge_length_mm": 6.0}},
                                        {"elastic": {"mesh": "shared", "order": 1}, "mesh": COARSE}],
                ids=["own", "shared"])
def exported(request, tmp_path_factory):
    """The small scene's three poses simulated, exported; (simulation, directory, files)."""
    scene_file = tmp_path_factory.mktemp("scene") / "scene.toml"
    scene_file.write_text(to_toml({**SMALL_SCENE, "poses": POSES, **request.param}))
    sim = simulate(load_scene(scene_file))
    out = tmp_path_factory.mktemp("vtu")
    return sim, out, write_poses(out, sim)


def collection(path):
    """(timestep, name, file) of each DataSet of the ParaView collection ``path``."""
    root = ET.parse(path).getroot()
    assert root.tag == "VTKFile" and root.get("type") == "Collection"
    return [(int(d.get("timestep")), d.get("name"), d.get("file")) for d in root.iter("DataSet")]


def test_points_are_the_rest_mesh_and_displacement_reaches_the_pose(exported):
    sim, out, _ = exported
    for result in sim.poses:
        pose = meshio.read(out / f"{result.name}.vtu")
        np.testing.assert_array_equal(pose.points, sim.mesh.points)
        np.testing.assert_allclose(pose.points + pose.point_data["displacement"], result.vertices,
                                   rtol=0, atol=1e-12)
        if sim.transfer is not None:
            elastic = meshio.read(out / f"{result.name}_elastic.vtu")
            rest = sim.elastic.mesh.points
            deformed = (result.state.nodes if result.state else sim.elastic.rest)[:len(rest)]
            np.testing.assert_array_equal(elastic.points, rest)
            np.testing.assert_allclose(elastic.points + elastic.point_data["displacement"], deformed,
                                       rtol=0, atol=1e-12)
    # The poses really move (else the checks above prove nothing); the rest pose does not.
    displacement = {r.name: np.abs(r.vertices - sim.mesh.points).max() for r in sim.poses}
    assert displacement["rest"] == 0.0 and displacement["pull"] > 1.0 and displacement["press"] > 1.0


def test_collections_list_every_pose_in_order(exported):
    sim, out, files = exported
    names = [result.name for result in sim.poses]
    suffixes = ("", "_elastic") if sim.transfer is not None else ("",)
    assert (out / "poses_elastic.pvd").exists() == (sim.transfer is not None)
    for suffix in suffixes:
        path = out / f"poses{suffix}.pvd"
        assert path in files
        steps = collection(path)
        assert steps == [(i, name, f"{name}{suffix}.vtu") for i, name in enumerate(names)]
        assert all((out / file).is_file() for _, _, file in steps)


def test_stack_tags_only_on_the_electrostatic_mesh(exported):
    sim, out, _ = exported
    pose = meshio.read(out / "pull.vtu")
    assert {"layer", "capacitor"} <= set(pose.cell_data)
    np.testing.assert_array_equal(pose.cell_data["capacitor"][0], sim.mesh.capacitor_of_tet)
    if sim.transfer is None:  # shared: the elastic fields sit on the electrostatic mesh
        assert {"J", "stress", "von_mises"} <= set(pose.cell_data)
    else:
        elastic = meshio.read(out / "pull_elastic.vtu")
        assert set(elastic.cell_data) == {"J", "stress", "von_mises"}
        assert set(elastic.point_data) == {"displacement"}
