"""pneumatic_quick's chosen design (tests/fabrication/data) as a scene of its own: the
small scene's stack and one free pose (electrostatics only), routed to the top edge with
the read-out's default slots, where one row lead crosses one column lead."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mscap.scene import load_scene
from tests.conftest import SMALL_SCENE, to_toml

DATA = Path(__file__).parent / "data" / "pneumatic_quick_k3.json"


def pneumatic_design(directory: Path):
    """``(scene, plate outlines)`` of the design, the scene written into ``directory``."""
    design = json.loads(DATA.read_text())
    scene_dict = dict(SMALL_SCENE, sheet={"outline_mm": design["sheet_mm"]})
    scene_dict["capacitors"] = {"min_gap_mm": 2.0, "outlines_mm": design["outlines_mm"]}
    scene_dict["fabrication"] = {"connector_edge": "top", "assignments": 1}
    (directory / "scene.toml").write_text(to_toml(scene_dict))
    return load_scene(directory / "scene.toml"), [np.array(o) for o in design["outlines_mm"]]
