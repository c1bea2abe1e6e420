"""Stored designs: the ``mscap optimize`` output directory round trip (write → read →
compare) and the design named by a spec with its baselines, on duck-typed results (no
optimisation run)."""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest

from mscap.design.history import HISTORY_FIELDS, Record
from mscap.geometry.layout import Layout
from mscap.scene import load_scene
from mscap.service.designs import (OPTIMIZE_FILES, design_layouts, read_optimize_output, split_design_spec,
                                   write_optimize_output)
from mscap.service.store import StoreError, open_store, write_run
from tests.conftest import synthetic_record


@pytest.fixture
def scene(small_scene_dict, write_scene):
    small_scene_dict["poses"] = [{"name": "rest", "kind": "free"}, {"name": "a", "kind": "free"},
                                 {"name": "b", "kind": "free"}]
    return load_scene(write_scene(small_scene_dict))


def optimize_result(scene):
    """An ``OptimizeResult``-shaped object: the scene's layout moved by 0.25 mm."""
    after = Layout(tuple(o + [0.25, 0.0] for o in scene.layout.outlines))
    rows = [Record(0, 0, -1.0, {"d": 1.0, "barrier": 0.1, "smoothing": 0.2}, 3.0, 0.0, 1.0, "start", 1, 5, 30.0, 1.0, 0.5),
            Record(1, 0, -2.0, {"d": 2.0, "barrier": 0.1, "smoothing": 0.2}, 1.0, 0.3, 1.4, "remesh", 2, 6, 29.0, 0.9, 1.5)]
    caps = np.array([[1.0, 2.0], [1.5, 2.5], [3.0, 1.0]]) / 3
    return SimpleNamespace(layout=after, history=tuple(rows), iterations=1, reason="converged", time_s=2.5, reroutes=(),
                           initial=SimpleNamespace(capacitance_pF=caps * 0.5, min_l1_pF=0.25, J=-1.0),
                           evaluation=SimpleNamespace(capacitance_pF=caps, min_l1_pF=0.5, J=-2.0))


def test_optimize_output_round_trip(scene, tmp_path):
    result = optimize_result(scene)
    out = tmp_path / "run"
    summary = write_optimize_output(out, scene, scene.layout, result, seed=7, init="scene")
    assert sorted(p.name for p in out.iterdir()) == sorted(OPTIMIZE_FILES)
    assert summary["k"] == 2 and summary["remeshes"] == 1 and summary["poses"] == ["rest", "a", "b"]
    assert "final_bound_mm" not in summary  # no design family
    assert json.loads((out / "summary.json").read_text()) == summary

    run = read_optimize_output(out)
    assert run.name == "run" and run.summary == summary
    for read, written in zip(run.outlines, result.layout.outlines):
        np.testing.assert_allclose(read, written, atol=5e-7)  # outlines.json keeps 6 decimals
    with open(out / "capacitance.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["pose", "stage", "C0_pF", "C1_pF"] and len(rows) == 1 + 2 * 3
    assert [float(c) for c in rows[4][2:]] == pytest.approx(result.evaluation.capacitance_pF[0], abs=1e-6)
    with open(out / "history.csv") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == HISTORY_FIELDS and rows[2][HISTORY_FIELDS.index("event")] == "remesh"


def test_design_layouts_of_an_optimize_directory(scene, tmp_path):
    out = tmp_path / "opt"
    write_optimize_output(out, scene, scene.layout, optimize_result(scene), seed=0, init="scene")
    (label, outlines), (base, base_outlines) = design_layouts(scene, str(out), None)
    assert label == "opt (optimised)" and base == "scene layout"
    np.testing.assert_allclose(base_outlines[1], scene.layout.outlines[1])
    assert [lbl for lbl, _ in design_layouts(scene, str(out), ["scene"])] == ["opt (optimised)", "scene layout"]
    with pytest.raises(StoreError, match="only the baselines 'initial' and 'scene'"):
        design_layouts(scene, str(out), ["k2_s0000_lloyd"])
    (out / "outlines.json").unlink()
    with pytest.raises(StoreError, match="not an `mscap optimize` output directory"):
        read_optimize_output(out)


def test_design_layouts_of_a_results_file(scene, tmp_path):
    path = tmp_path / "r.h5"
    record = synthetic_record(2, 2000)
    with open_store(path, scene) as store:
        write_run(store, record)
    assert split_design_spec(f"{path}:{record.id}") == (str(path), record.id)
    layouts = design_layouts(scene, f"{path}:{record.id}", ["initial", "scene", f"{record.id}:initial"])
    assert [label for label, _ in layouts] == [f"{record.id} (optimised)", f"{record.id}:initial", "scene layout",
                                               f"{record.id}:initial"]
    np.testing.assert_array_equal(layouts[0][1][0], record.final_outlines[0])
    np.testing.assert_array_equal(layouts[1][1][1], record.initial_outlines[1])
