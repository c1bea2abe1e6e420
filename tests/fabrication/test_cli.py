"""``mscap fabricate``: from an `mscap optimize` directory and from a results file (the
stored scene's rules, or another scene's with --scene), and bad input as one line each
with nothing written: an existing or linked -o, rules of 0 or 1e308, rules no design
could meet, a design the rules cannot route."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from mscap.cli import main
from mscap.scene import load_scene
from mscap.service.store import open_store, write_run
from tests.conftest import synthetic_record


@pytest.fixture
def roomy(small_scene_dict):
    """The small scene on a 40 x 30 mm sheet, its plates moved 5 mm in: room for the pads."""
    small_scene_dict["sheet"] = {"width_mm": 40.0, "height_mm": 30.0}
    small_scene_dict["capacitors"]["outlines_mm"] = [
        (np.array(o) + 5.0).tolist() for o in small_scene_dict["capacitors"]["outlines_mm"]]
    return small_scene_dict


def optimize_dir(tmp_path, scene, outlines):
    """An `mscap optimize` output directory holding ``outlines`` of ``scene``."""
    run = tmp_path / "opt"
    run.mkdir()
    (run / "outlines.json").write_text(json.dumps({"scene": str(scene), "outlines_mm": outlines}))
    (run / "summary.json").write_text(json.dumps({"scene": str(scene), "k": len(outlines)}))
    return run


def one_line_error(capsys, args, *needles):
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("mscap: error: "), err
    for needle in needles:
        assert needle in err, err
    return err


def test_fabricate_an_optimize_directory(roomy, write_scene, tmp_path, capsys):
    run = optimize_dir(tmp_path, write_scene(roomy), roomy["capacitors"]["outlines_mm"])
    assert main(["fabricate", str(run), "-o", str(tmp_path / "fab")]) == 0
    out = capsys.readouterr().out
    assert "opt (optimised): 2 x 1 array" in out and "rules met" in out
    document = json.loads((tmp_path / "fab" / "fabrication.json").read_text())
    assert document["design"] == "opt (optimised)" and document["design_rule_check"]["violations"] == []
    assert [s["capacitor"] for s in document["array"]["slots"]] == [0, 1]
    assert sorted(p["net"] for p in document["pads"]) == ["C0", "R0", "R1"]
    # The design as wired, simulated: the plates come from fabrication.json, the nets from
    # the stencils; one free pose, so the readings are the rest capacitances
    assert main(["simulate", str(run / ".." / "scene.toml"), "--wiring", str(tmp_path / "fab"), "-q", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    wired, plates = np.array(record["wired_pF"]), np.array(record["plates_pF"])
    assert wired.shape == plates.shape == (1, 2)
    assert np.all(np.abs(wired / plates - 1) < 0.02)  # two straight leads, no crossing: within 2 %
    one_line_error(capsys, ["simulate", str(run / ".." / "scene.toml"), "--wiring", str(tmp_path / "fab"),
                            "--export", str(tmp_path / "x")], "--wiring simulates with the scene's orders")


def test_fabricate_a_run_of_a_results_file_with_the_stored_or_another_scene(roomy, write_scene, tmp_path, capsys):
    scene = load_scene(write_scene(roomy))
    record = replace(synthetic_record(2, 2000), final_outlines=scene.layout.outlines)
    with open_store(tmp_path / "r.h5", scene) as store:
        write_run(store, record)
    assert main(["fabricate", str(tmp_path / "r.h5"), "--run", record.id, "-o", str(tmp_path / "a")]) == 0
    assert f"{record.id}: 2 x 1 array" in capsys.readouterr().out
    # The read-out of the array as routed: the slots the router chose, not capacitor order
    wiring = tmp_path / "a" / "fabrication.json"
    slots = {s["capacitor"]: (s["row"], s["column"]) for s in json.loads(wiring.read_text())["array"]["slots"]}
    assert main(["readout", str(scene.path), "--design", f"{tmp_path / 'r.h5'}:{record.id}", "--wiring", str(wiring),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["array"]["slots"] == [list(slots[c]) for c in range(2)]
    one_line_error(capsys, ["readout", str(scene.path), "--design", str(tmp_path / "r.h5"), "--wiring", str(wiring),
                            "--rows", "2"], "--wiring gives the array; leave out --rows and --columns")
    # Rules given later: the same scene with a [fabrication] table, named by --scene
    roomy["fabrication"] = {"trace_width_mm": 0.8, "connector_edge": "top", "rows": 1, "columns": 2}
    other = write_scene(roomy, "with_rules.toml")
    assert main(["fabricate", str(tmp_path / "r.h5"), "--run", record.id, "--scene", str(other),
                 "-o", str(tmp_path / "b")]) == 0
    document = json.loads((tmp_path / "b" / "fabrication.json").read_text())
    assert document["connector_edge"] == "top" and document["rules"]["trace_width_mm"] == 0.8
    assert (document["array"]["rows"], document["array"]["columns"]) == (1, 2)


@pytest.mark.parametrize("key, value, needle", [
    ("trace_width_mm", 0.0, "fabrication.trace_width_mm: must lie in [0.001, 10000] mm, got 0.0"),
    ("clearance_mm", 1e308, "fabrication.clearance_mm: must lie in [0.001, 10000] mm, got 1e+308"),
    ("min_radius_mm", 0.6, "fabrication.min_radius_mm: must be at most half the trace width (0.5 mm)"),
    ("pad_pitch_mm", 2.0, "fabrication.pad_pitch_mm: must be at least pad_width_mm + clearance_mm = 2.27 mm"),
    ("connector_edge", "middle", "fabrication.connector_edge: unknown value 'middle'"),
    ("grid_mm", 0.002, "fabrication.grid_mm: a 0.002 mm routing grid over the 40 x 30 mm sheet has 3e+08 cells"),
    ("trace_widht_mm", 1.0, "trace_widht_mm"),
])
def test_bad_rules_are_one_line_naming_the_key(roomy, write_scene, tmp_path, capsys, key, value, needle):
    roomy["fabrication"] = {key: value}
    run = optimize_dir(tmp_path, write_scene(roomy), roomy["capacitors"]["outlines_mm"])
    before = sorted(p.name for p in tmp_path.iterdir())
    one_line_error(capsys, ["fabricate", str(run), "-o", str(tmp_path / "fab")], needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_unroutable_designs_and_taken_outputs_are_one_line_and_write_nothing(small_scene_dict, write_scene,
                                                                               tmp_path, capsys):
    # The small scene's plates come within 4 mm of every edge: 3 pads 3 mm long fit nowhere.
    run = optimize_dir(tmp_path, write_scene(small_scene_dict), small_scene_dict["capacitors"]["outlines_mm"])
    before = sorted(p.name for p in tmp_path.iterdir())
    one_line_error(capsys, ["fabricate", str(run), "-o", str(tmp_path / "fab")],
                   "fabrication.connector_edge: 3 pads", "fit nowhere along the bottom edge")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    (tmp_path / "taken").mkdir()
    one_line_error(capsys, ["fabricate", str(run), "-o", str(tmp_path / "taken")], "exists (a directory)")
    (tmp_path / "link").symlink_to(tmp_path / "elsewhere")
    one_line_error(capsys, ["fabricate", str(run), "-o", str(tmp_path / "link")], "exists (a link)")
    assert not (tmp_path / "elsewhere").exists()
    one_line_error(capsys, ["fabricate", str(tmp_path / "missing.h5"), "-o", str(tmp_path / "fab")],
                   "missing.h5: cannot open as HDF5")
    one_line_error(capsys, ["fabricate", str(run), "--run", "k2_s1_lloyd", "-o", str(tmp_path / "fab")],
                   "--run names a run of a results file")
    (run / "summary.json").write_text("{}")
    one_line_error(capsys, ["fabricate", str(run), "-o", str(tmp_path / "fab")], "names no scene file; give --scene")
