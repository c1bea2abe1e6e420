"""Sensitivity-map starts (mscap.design.starts): the capacitance density of a homogeneous
deformation in closed form, the glove's map finding one plate per knuckle as the
hand-placed layout has them, the multi-start's schedule and the errors."""

from __future__ import annotations

import numpy as np
import pytest

from mscap.design.starts import capacitance_density, sensitivity_layout, sensitivity_map, start_layout
from mscap.errors import GeometryError, SceneError
from mscap.fem.simulate import elastic_setup
from mscap.mesh.layered import mesh_sheet
from mscap.scene import load_scene
from mscap.service.selection import configurations
from tests.conftest import to_toml
from tests.scenes import scene_dict

STRETCH = [{"name": "rest", "kind": "free"},
           {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"}]


def test_capacitance_density_of_a_homogeneous_deformation(tmp_path):
    # F = diag(a, b, c) with shear in the plane: J = abc, J_s = ab (the plane's area), so
    # the parallel-plate density J_s² / J = ab / c in every triangle; a rotation changes nothing.
    path = tmp_path / "s.toml"
    path.write_text(to_toml(scene_dict(poses=STRETCH)))
    scene = load_scene(path)
    problem, _ = elastic_setup(scene.sheet, scene.elastic, mesh_sheet(scene.sheet), scene.poses, transfer=False)
    a, b, c, shear = 1.3, 0.9, 0.8, 0.25
    f = np.array([[a, shear, 0.0], [0.0, b, 0.0], [0.0, 0.0, c]])
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for deformation in (f, turn @ f):
        density = capacitance_density(problem, problem.rest @ deformation.T)
        np.testing.assert_allclose(density, a * b / c, rtol=1e-12)
    np.testing.assert_allclose(capacitance_density(problem, problem.rest), 1.0, rtol=1e-12)


@pytest.fixture(scope="module")
def glove():
    scene = load_scene("jobs/glove_quick.toml")
    return scene, sensitivity_map(scene)


def test_the_glove_map_puts_one_plate_on_each_knuckle(glove):
    """The hand-placed glove layout has one plate per finger over the knuckles. The map of
    the 16 design poses (each finger straight or bent by 60°) clusters the sheet by which
    finger strains it: every k = 4 start lands within 2.5 mm of the hand-placed centres."""
    scene, smap = glove
    assert smap.signature.shape[1] == 16
    hand = np.array([o.mean(axis=0) for o in scene.layout.outlines])
    for seed in (0, 1, 2):
        sites = np.array([o.mean(axis=0) for o in sensitivity_layout(scene, 4, seed, smap).outlines])
        distance = np.linalg.norm(sites[:, None] - hand[None], axis=2)
        assert np.sort(distance.min(axis=0)).max() < 2.5, distance.min(axis=0)
        assert len(set(distance.argmin(axis=1))) == 4  # one plate per knuckle
    # the strained band: the knuckle line, not the back of the hand
    hot = smap.points[smap.sensitivity > 0.5 * smap.sensitivity.max()]
    assert abs(hot[:, 1].mean() - 39.0) < 4.0


def test_the_schedule_puts_sensitivity_starts_first_and_errors_name_the_key(tmp_path):
    data = scene_dict(poses=STRETCH, multistart={"k_min": 2, "k_max": 3, "starts_per_k": 4,
                                                  "lloyd_fraction": 0.5, "sensitivity_fraction": 0.25})
    path = tmp_path / "m.toml"
    path.write_text(to_toml(data))
    inits = [c.init for c in configurations(load_scene(path)) if c.k == 2]
    assert inits == ["sensitivity", "lloyd", "lloyd", "random"]
    data["multistart"]["sensitivity_fraction"] = 1.5
    path.write_text(to_toml(data))
    with pytest.raises(SceneError, match=r"multistart\.sensitivity_fraction"):
        load_scene(path)


def test_a_scene_of_free_poses_has_nothing_to_read(tmp_path):
    path = tmp_path / "free.toml"
    path.write_text(to_toml(scene_dict(poses=[{"name": "rest", "kind": "free"}, {"name": "b", "kind": "free"}])))
    scene = load_scene(path)
    with pytest.raises(GeometryError, match="nothing to read"):
        start_layout(scene, 2, 0, "sensitivity")
    with pytest.raises(GeometryError, match="unknown init 'voronoi'"):
        start_layout(scene, 2, 0, "voronoi")


def test_hot_spots_that_share_a_region_still_give_a_valid_layout():
    """On pneumatic_quick the clusters' hot spots lie close together (the inflation and the
    indent strain the same middle of the sheet): squares on them did not fit at any size
    (the first multi-start with sensitivity starts failed them at k = 2 and 3). Each
    cluster's plate then goes to its strongest triangle with room: valid layouts of
    plates at least half the mean size, for every k and seed tried."""
    from mscap.geometry.initial import plate_size_mm
    from mscap.geometry.layout import check_layout

    scene = load_scene("jobs/pneumatic_quick.toml")
    smap = sensitivity_map(scene)
    for k in (2, 3, 4):
        for seed in (k * 1000, k * 1000 + 1):
            layout = sensitivity_layout(scene, k, seed, smap)
            check_layout(layout, scene.sheet_outline_mm, 2 * scene.min_gap_mm)
            sides = [np.ptp(o[:, 0]) for o in layout.outlines]
            assert layout.k == k and min(sides) >= 0.45 * plate_size_mm(scene)
