"""Scene files: valid scenes load into the right values; each bad value is named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.settings import EPSILON0_PF_PER_MM

JOBS = Path(__file__).resolve().parents[2] / "jobs"


@pytest.mark.parametrize("path", sorted(JOBS.glob("*.toml")), ids=lambda p: p.name)
def test_every_job_loads(path):
    scene = load_scene(path)
    assert len(scene.layers) == 5
    assert scene.layout.k >= 1


def test_grid3x3_is_the_papers_array():
    scene = load_scene(JOBS / "grid3x3.toml")
    assert scene.layout.k == 9
    np.testing.assert_allclose(scene.layout.areas_mm2(), 400.0, rtol=1e-14)  # 2 cm squares
    gap = scene.layers[2].thickness_mm
    # Parallel-plate estimate eps A / d ~ 70 pF (paper §4.4).
    c = scene.layers[2].material.permittivity_pF_per_mm * 400.0 / gap
    assert 65.0 < c < 75.0


def test_poking_is_a_2x2_on_10cm():
    scene = load_scene(JOBS / "poking.toml")
    assert scene.layout.k == 4
    lo, hi = scene.sheet_outline_mm.min(axis=0), scene.sheet_outline_mm.max(axis=0)
    np.testing.assert_array_equal(hi - lo, [100.0, 100.0])


def test_values_and_units(small_scene_dict, write_scene):
    scene = load_scene(write_scene(small_scene_dict))
    clear = scene.layers[0].material
    assert clear.permittivity_pF_per_mm == pytest.approx(2.84 * 8.8541878128e-3, rel=1e-15)
    assert EPSILON0_PF_PER_MM == 8.8541878128e-12 * 1e12 / 1e3  # F/m -> pF/mm
    mu, lam = clear.lame_MPa
    assert mu == pytest.approx(0.57 / (2 * 1.47))
    assert lam == pytest.approx(0.57 * 0.47 / (1.47 * 0.06))
    assert scene.thickness_mm == pytest.approx(0.56)
    assert scene.layers[1].fill.name == "clear" and scene.layers[1].material.name == "carbon"
    # outlines are stored counter-clockwise whatever the file's order
    assert all(np.cross(o[1] - o[0], o[2] - o[1]) > 0 for o in scene.layout.outlines)
    assert scene.poses[0].kind == "free"
    assert scene.mesh.order == 1 and scene.mesh.elements_per_layer == 1
    with pytest.raises(ValueError):
        scene.layout.outlines[0][0, 0] = 1.0  # frozen


def test_grid_generators(small_scene_dict, write_scene):
    d = small_scene_dict
    del d["capacitors"]["outlines_mm"]
    for shape, extra, area in [("square", {}, 36.0),
                               ("disk", {}, np.pi * 9.0),
                               ("rounded_square", {"corner_radius_mm": 1.0}, 36.0 - (4 - np.pi))]:
        d["capacitors"]["grid"] = {"shape": shape, "rows": 1, "columns": 2, "size_mm": 6.0,
                                   "pitch_mm": [10.0, 10.0], **extra}
        scene = load_scene(write_scene(d))
        assert scene.layout.k == 2
        areas = scene.layout.areas_mm2()
        # polygonal approximation of arcs at 0.5 mm spacing: within 1 % of the exact area
        np.testing.assert_allclose(areas, area, rtol=1e-2 if shape != "square" else 1e-14)
        centres = [o.mean(axis=0) for o in scene.layout.outlines]
        np.testing.assert_allclose(centres[1] - centres[0], [10.0, 0.0], atol=1e-9)


def _delete(d, path):
    for key in path[:-1]:
        d = d[key]
    del d[path[-1]]


BAD = [
    # (id, mutation, key named in the message, words in the message)
    ("unknown key", lambda d: d["mesh"].update(edge_lenght_mm=1.0), "mesh.edge_lenght_mm",
     "did you mean 'edge_length_mm'"),
    ("unknown top-level", lambda d: d.update(materals={}), "materals", "did you mean 'materials'"),
    ("missing key", lambda d: _delete(d, ["materials", "clear", "poisson_ratio"]), "materials.clear.poisson_ratio",
     "missing"),
    ("tolerance zero", lambda d: d["mesh"].update(tolerance=0.0), "mesh.tolerance", "must be > 0, got 0.0"),
    ("tolerance not relative", lambda d: d["mesh"].update(tolerance=5.0), "mesh.tolerance", "must be < 1, got 5.0"),
    ("wrong type", lambda d: d["mesh"].update(edge_length_mm="fine"), "mesh.edge_length_mm",
     "expected a number, got 'fine'"),
    ("wrong type int", lambda d: d["mesh"].update(elements_per_layer=1.5), "mesh.elements_per_layer",
     "expected an integer"),
    ("thickness zero", lambda d: d["layers"][2].update(thickness_mm=0.0), "layers[2].thickness_mm",
     "must be > 0, got 0.0"),
    ("thickness negative", lambda d: d["layers"][0].update(thickness_mm=-0.1), "layers[0].thickness_mm",
     "must be > 0, got -0.1"),
    ("nu too high", lambda d: d["materials"]["clear"].update(poisson_ratio=0.5),
     "materials.clear.poisson_ratio", "(-1, 0.5), got 0.5"),
    ("nu too low", lambda d: d["materials"]["carbon"].update(poisson_ratio=-1.0),
     "materials.carbon.poisson_ratio", "(-1, 0.5), got -1.0"),
    ("E zero", lambda d: d["materials"]["clear"].update(youngs_modulus_MPa=0),
     "materials.clear.youngs_modulus_MPa", "must be > 0, got 0.0"),
    ("eps below 1", lambda d: d["materials"]["clear"].update(relative_permittivity=0.5),
     "materials.clear.relative_permittivity", "must be >= 1, got 0.5"),
    ("outside sheet", lambda d: d["capacitors"]["outlines_mm"].__setitem__(
        1, [[25.0, 5.0], [35.0, 5.0], [35.0, 15.0], [25.0, 15.0]]),
     "capacitors.outlines_mm[1]", "outside the sheet"),
    ("too close to edge", lambda d: d["capacitors"]["outlines_mm"].__setitem__(
        1, [[17.0, 5.0], [29.5, 5.0], [29.5, 15.0], [17.0, 15.0]]),
     "capacitors.outlines_mm[1]", "0.5 mm from the sheet edge"),
    ("overlap", lambda d: d["capacitors"]["outlines_mm"].__setitem__(
        1, [[10.0, 5.0], [20.0, 5.0], [20.0, 15.0], [10.0, 15.0]]),
     "capacitors.outlines_mm[1]", "capacitors 0 and 1 overlap"),
    ("nested", lambda d: d["capacitors"]["outlines_mm"].__setitem__(
        1, [[5.0, 6.0], [8.0, 6.0], [8.0, 9.0], [5.0, 9.0]]),
     "capacitors.outlines_mm[1]", "overlap"),
    ("gap too small", lambda d: d["capacitors"]["outlines_mm"].__setitem__(
        1, [[13.5, 5.0], [20.0, 5.0], [20.0, 15.0], [13.5, 15.0]]),
     "capacitors.outlines_mm[1]", "0.5 mm apart; the minimum gap is 1 mm"),
    ("self-intersecting", lambda d: d["capacitors"]["outlines_mm"].__setitem__(
        1, [[17.0, 5.0], [27.0, 15.0], [27.0, 5.0], [17.0, 15.0]]),
     "capacitors.outlines_mm[1]", "intersects itself"),
    ("self-intersecting sheet", lambda d: d.update(sheet={"outline_mm": [[0, 0], [30, 20], [30, 0], [0, 20]]}),
     "sheet.outline_mm", "intersects itself"),
    ("four layers", lambda d: d["layers"].pop(), "layers", "exactly 5 layers"),
    ("six layers", lambda d: d["layers"].append(dict(d["layers"][0])), "layers", "bottom to top), got 6"),
    ("layer order", lambda d: d["layers"][1].update(kind="dielectric"), "layers[1].kind",
     "expected 'conductive'"),
    ("unknown material", lambda d: d["layers"][0].update(material="glass"), "layers[0].material",
     "unknown material 'glass'"),
    ("order 3", lambda d: d["mesh"].update(order=3), "mesh.order", "must be 1 or 2, got 3"),
    ("outline coarser", lambda d: d["mesh"].update(edge_length_outline_mm=5.0), "mesh.edge_length_outline_mm",
     "exceeds edge_length_mm"),
    ("bad point", lambda d: d["capacitors"]["outlines_mm"][0].__setitem__(2, [1.0]),
     "capacitors.outlines_mm[0][2]", "expected a point [x, y]"),
    ("pose kind", lambda d: d["poses"].append({"name": "p", "kind": "twist"}), "poses[1].kind",
     "unknown pose kind 'twist'"),
    ("duplicate pose", lambda d: d["poses"].append({"name": "rest", "kind": "free"}), "poses[1].name",
     "duplicate pose name"),
    # on a case-insensitive file system REST.vtu and rest.vtu are one file (issue 48)
    ("pose names by case", lambda d: d["poses"].append({"name": "REST", "kind": "free"}), "poses[1].name",
     "pose name 'REST' differs from 'rest' only by case"),
    # composed and decomposed é are one name
    ("pose names by form", lambda d: d["poses"].extend([{"name": "caf\u00e9", "kind": "free"},
                                                         {"name": "cafe\u0301", "kind": "free"}]),
     "poses[2].name", "duplicate pose name 'café'"),
    ("k range", lambda d: d.update(multistart={"k_min": 4, "k_max": 3}), "multistart.k_min", "exceeds"),
]


@pytest.mark.parametrize("mutate, key, words", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_scene_is_named(small_scene_dict, write_scene, mutate, key, words):
    mutate(small_scene_dict)
    path = write_scene(small_scene_dict)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key}: "), message
    assert words in message, message


def test_a_decomposed_pose_name_is_taken_composed(small_scene_dict, write_scene):
    small_scene_dict["poses"].append({"name": "cafe\u0301", "kind": "free"})  # NFD: refused before
    assert load_scene(write_scene(small_scene_dict)).poses[-1].name == "caf\u00e9"


def test_unreadable_and_malformed(tmp_path):
    with pytest.raises(SceneError, match="cannot read scene file"):
        load_scene(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[sheet\nwidth_mm = 1\n")
    with pytest.raises(SceneError, match=r"bad\.toml: not valid TOML"):
        load_scene(bad)
