"""Every shipped ``*_quick`` scene runs its first optimisation step (the paper's scenes
end to end in CI: meshing, all poses, the gradient, one accepted L-BFGS step)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mscap.scene import load_scene

JOBS = Path(__file__).resolve().parents[1] / "jobs"
# biaxial_quick: tests/bodies/test_bodies.py; quick: make run and tests/service/test_multistart.py
QUICK = ["wrist_quick", "joystick_quick", "pneumatic_quick", "glove_quick", "poking_quick", "poking_cross_quick"]
PAPER = ["poking", "poking_cross", "biaxial", "pneumatic", "joystick", "wrist", "glove"]


@pytest.mark.parametrize("name", PAPER)
def test_quick_scene_is_its_paper_scene_on_coarser_settings(name):
    """``<name>_quick.toml`` poses the same problem as ``<name>.toml``: only meshes,
    the multi-start size and the iteration budget differ; its multi-start is small
    enough for 2 cores (at most 10 starts)."""
    import tomllib

    def problem(path):
        data = tomllib.loads(path.read_text())
        for key in ("name", "description", "mesh", "elastic", "multistart"):
            data.pop(key, None)
        data.get("optimizer", {}).pop("max_iterations", None)
        return {key: value for key, value in data.items() if value}  # an emptied [optimizer]

    assert problem(JOBS / f"{name}_quick.toml") == problem(JOBS / f"{name}.toml")
    paper, quick = load_scene(JOBS / f"{name}.toml"), load_scene(JOBS / f"{name}_quick.toml")
    coarse = (quick.mesh.edge_length_mm >= paper.mesh.edge_length_mm
              and quick.mesh.edge_length_outline_mm >= paper.mesh.edge_length_outline_mm
              and quick.elastic.edge_length_mm >= paper.elastic.edge_length_mm
              and quick.mesh.order <= paper.mesh.order)
    assert coarse and quick.mesh != paper.mesh
    ms = quick.multistart
    assert ms.starts_per_k * (ms.k_max - ms.k_min + 1) <= 10 and ms.lloyd_fraction == 1.0
    assert quick.optimizer.max_iterations <= paper.optimizer.max_iterations


@pytest.mark.parametrize("name", QUICK)
def test_quick_scene_takes_one_optimisation_step(name):
    pytest.importorskip("igl")
    from mscap.design.pipeline import build_design
    from mscap.geometry.layout import check_layout
    from mscap.design.optimizer import optimize

    design = build_design(load_scene(JOBS / f"{name}.toml"))
    scene = design.scene
    result = optimize(design, max_iterations=1, cascade_levels=0)
    events = [r.event for r in result.history]
    assert events[0] == "start" and events.count("step") == 1, events
    assert result.history[1].J < result.history[0].J
    assert result.initial.min_l1_pF > 0.5                 # every pose pair reads apart (pF)
    # its design poses: the listed ones, or a sub-grid of the calibration family
    assert result.evaluation.capacitance_pF.shape == (len(design.poses), scene.layout.k)
    check_layout(result.layout, scene.sheet_outline_mm, scene.min_gap_mm)
