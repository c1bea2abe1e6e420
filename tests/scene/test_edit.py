"""Scene parameters by name (``mscap.scene.edit``): what a name picks, and values written
into a scene file's text with its comments kept."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.edit import apply, format_number, parameter

POKING = Path(__file__).resolve().parents[2] / "jobs" / "poking.toml"


@pytest.fixture(scope="module")
def poking():
    source = POKING.read_text()
    return source, tomllib.loads(source)


def test_names_pick_the_places_a_user_reads(poking):
    _, data = poking
    p = parameter("p", data, "layers.dielectric.thickness_mm")
    assert p.places == (("layers", 2, "thickness_mm"),) and p.start == 0.14
    assert parameter("p", data, "materials.clear.relative_permittivity").start == 2.84
    every = parameter("p", data, "poses.*.depth_mm")
    assert [place[1] for place in every.places] == [1, 2, 3, 4] and every.start == 13.0  # not the rest pose
    assert parameter("p", data, "poses.poke_2.center_mm[1]").places == (("poses", 3, "center_mm", 1),)
    scale = parameter("p", data, "thickness_scale")
    assert scale.start == 1.0 and scale.bases == (0.14, 0.07, 0.14, 0.07, 0.14) and scale.scale


def test_values_written_into_the_text_load_as_that_scene_and_keep_the_comments(poking):
    source, data = poking
    names = ["thickness_scale", "materials.clear.relative_permittivity", "poses.*.depth_mm",
             "poses.poke_0.center_mm[0]", "capacitors.grid.size_mm"]
    text = apply("p", source, [parameter("p", data, n) for n in names], [0.8, 3.1, 11.5, 31.25, 20.0])
    scene = load_scene(POKING, source=text)
    assert [layer.thickness_mm for layer in scene.layers] == pytest.approx([0.112, 0.056, 0.112, 0.056, 0.112])
    assert scene.layers[2].material.relative_permittivity == 3.1
    assert [p.depth_mm for p in scene.poses[1:]] == [11.5] * 4
    assert list(scene.poses[1].center_mm) == [31.25, 30.0]
    assert {line for line in source.splitlines() if line.startswith("#")} == \
        {line for line in text.splitlines() if line.startswith("#")}
    assert len(text.splitlines()) == len(source.splitlines())  # line for line: nothing moved
    changed = [(a, b) for a, b in zip(source.splitlines(), text.splitlines()) if a != b]
    assert len(changed) == 5 + 1 + 4 + 1 + 1  # five layers, ε, four depths, one centre, the size
    assert ("relative_permittivity = 2.84", "relative_permittivity = 3.1") in changed


def test_a_value_keeps_its_line_comment():
    source = "[a]\nx = 1.5   # the gap\n"
    text = apply("p", source, [parameter("p", tomllib.loads(source), "a.x")], [2.0])
    assert text == "[a]\nx = 2.0   # the gap\n"


def test_format_number_is_a_toml_float():
    assert format_number(2.0) == "2.0" and format_number(0.1 + 0.2) == "0.3" and format_number(1e-12) == "1e-12"
    assert tomllib.loads(f"x = {format_number(123456789012.0)}")["x"] == pytest.approx(123456789012.0)


@pytest.mark.parametrize("name, says", [
    ("layers.glue.thickness_mm", "no element named 'glue' in layers (it has protective_bottom"),
    ("materials.clear.density", "no key 'density' in materials.clear (it has poisson_ratio"),
    ("poses.*.kind", "no element * picks holds a number"),
    ("poses.poke_0.center_mm[2]", "center_mm has no element [2]"),
    ("sheet..width_mm", "not a parameter name"),
    ("name", "not a number in the scene"),
])
def test_a_bad_name_says_what_is_there(poking, name, says):
    with pytest.raises(SceneError, match=r"^p: " + r"\S+: " + ".*" + says.replace("(", r"\(").replace("[", r"\[")
                       .replace("]", r"\]").replace("*", r"\*")):
        parameter("p", poking[1], name)


def test_a_wildcard_over_different_values_is_refused():
    data = {"poses": [{"name": "a", "depth_mm": 1.0}, {"name": "b", "depth_mm": 2.0}]}
    with pytest.raises(SceneError, match="start at different values"):
        parameter("p", data, "poses.*.depth_mm")


def test_a_place_the_line_editor_cannot_reach_is_an_error_not_another_scene():
    source = "[a]\nx = [\n  1.0,\n  2.0,\n]\n"
    p = parameter("p", tomllib.loads(source), "a.x[1]")
    with pytest.raises(SceneError, match="cannot write a.x into the file's text"):
        apply("p", source, [p], [3.0])
    inline = "a = {x = 1.0}\n"
    with pytest.raises(SceneError, match="cannot write a.x"):
        apply("p", inline, [parameter("p", tomllib.loads(inline), "a.x")], [3.0])


def test_a_dotted_key_is_written_where_it_stands():
    source = "[capacitors]\ngrid.size_mm = 18.0\n"
    text = apply("p", source, [parameter("p", tomllib.loads(source), "capacitors.grid.size_mm")], [17.0])
    assert text == "[capacitors]\ngrid.size_mm = 17.0\n"
