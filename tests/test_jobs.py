"""Every shipped ``*_quick`` scene runs its first optimisation step (the paper's scenes
end to end in CI: meshing, all poses, the gradient, one accepted L-BFGS step)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mscap.scene import load_scene

JOBS = Path(__file__).resolve().parents[1] / "jobs"
# biaxial_quick: tests/test_bodies.py; quick: make run and tests/test_multistart.py
QUICK = ["wrist_quick", "joystick_quick", "pneumatic_quick", "glove_quick"]


@pytest.mark.parametrize("name", QUICK)
def test_quick_scene_takes_one_optimisation_step(name):
    pytest.importorskip("igl")
    from mscap.design import build_design
    from mscap.layout import check_layout
    from mscap.optimize import optimize

    scene = load_scene(JOBS / f"{name}.toml")
    result = optimize(build_design(scene), max_iterations=1, cascade_levels=0)
    events = [r.event for r in result.history]
    assert events[0] == "start" and events.count("step") == 1, events
    assert result.history[1].J < result.history[0].J
    assert result.initial.min_l1_pF > 0.5                 # every pose pair reads apart (pF)
    assert result.evaluation.capacitance_pF.shape == (len(scene.poses), scene.layout.k)
    check_layout(result.layout, scene.sheet_outline_mm, scene.min_gap_mm)
