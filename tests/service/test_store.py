"""The HDF5 results store, ``mscap inspect`` and ``mscap merge`` on synthetic records
(no optimisation runs)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from mscap.cli import main
from mscap.service.merge import merge
from mscap.design.history import min_pairwise_l1
from mscap.design.history import HISTORY_FIELDS
from mscap.scene import load_scene
from mscap.service.selection import configurations
from mscap.service.store import (ROOT_ATTRS, RUN_ATTRS, RUN_DATASETS, SELECTION_ITEMS, TEMP_PREFIX,
                         RunRecord, StoreError, failed_record, finished_ids, open_store, read_run, read_store,
                         record_from_result, schema_markdown, store_selection, write_run, write_selection)
from tests.conftest import synthetic_record

ROOT = Path(__file__).resolve().parents[2]


def writer_script(path, scene, first_seed: int, then: str) -> str:
    """A Python program that opens the store, writes ``synthetic_record(2, first_seed)``,
    then runs ``then`` (the tests kill it or make it wait)."""
    return textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(ROOT)!r})
        from mscap.scene import load_scene
        from mscap.service.store import open_store, write_run, TEMP_PREFIX
        from tests.conftest import synthetic_record
        store = open_store({str(path)!r}, load_scene({scene.path!r}))
        write_run(store, synthetic_record(2, {first_seed}))
    """) + textwrap.dedent(then)


@pytest.fixture
def scene(free_poses_scene):
    return free_poses_scene(k_max=4)


@pytest.fixture
def other_scene(small_scene_dict, write_scene):
    small_scene_dict["name"] = "other"
    return load_scene(write_scene(small_scene_dict, "other.toml"))


def assert_same(a: RunRecord, b: RunRecord) -> None:
    for name in ("k", "seed", "init", "status", "error", "reason", "iterations", "rank", "poses"):
        assert getattr(a, name) == getattr(b, name), name
    assert abs(a.wall_s - b.wall_s) <= 1e-15 * abs(a.wall_s)
    for name in ("initial_outlines", "final_outlines"):
        assert len(getattr(a, name)) == len(getattr(b, name))
        for x, y in zip(getattr(a, name), getattr(b, name)):
            np.testing.assert_allclose(y, x, rtol=1e-15, atol=0)
    for name in ("initial_capacitance_pF", "final_capacitance_pF"):
        assert getattr(a, name).shape == getattr(b, name).shape
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-15, atol=0)
    assert set(b.history) == set(HISTORY_FIELDS)
    for name in HISTORY_FIELDS:
        assert list(b.history[name]) == list(a.history[name]), name


def test_round_trip(tmp_path, scene):
    record = synthetic_record(3, 3007, "lloyd")
    with open_store(tmp_path / "r.h5", scene, mpi_size=4) as store:
        assert write_run(store, record) == "k3_s3007_lloyd"
        back = read_run(store, "k3_s3007_lloyd")
    assert_same(record, back)
    assert back.metric == min_pairwise_l1(record.final_capacitance_pF)
    with read_store(tmp_path / "r.h5") as f:  # schema as declared, plain types only
        assert set(f.attrs) == set(ROOT_ATTRS)
        assert f.attrs["scene_toml"] == scene.source and f.attrs["scene_sha256"] == scene.sha256
        assert f.attrs["mpi_size"] == 4
        g = f["runs/k3_s3007_lloyd"]
        assert set(g.attrs) == set(RUN_ATTRS)
        assert set(g) == {n.split("/")[0] for n in RUN_DATASETS}
        assert set(g["history"]) == set(HISTORY_FIELDS)
        assert g["final_outline_offsets"][-1] == len(g["final_outline_points_mm"])
        assert g["final_capacitance_pF"].shape == (3, 3)
        for ds in [g[n] for n in g if n != "history"] + [g["history"][n] for n in g["history"]]:
            assert ds.dtype.kind in "fiuO" and ds.dtype.names is None  # no compound, no opaque


@pytest.mark.parametrize("column", ["size_ratio", "error_J", "margin_error_pF"])
def test_a_run_written_before_an_optional_column_reads_it_as_nan(tmp_path, scene, column):
    """``history/size_ratio`` (the electrostatic mesh's quality), ``error_J`` and
    ``margin_error_pF`` (the evaluation's estimated error, mscap.design.resolution; all
    2026-12-05) are absent from files written before them: such a run reads back whole
    with NaN there and is not damaged."""
    from mscap.service.checks import damaged_runs

    record = synthetic_record(3, 3007, "lloyd")
    with open_store(tmp_path / "r.h5", scene) as store:
        write_run(store, record)
    with h5py.File(tmp_path / "r.h5", "r+") as f:
        del f[f"runs/k3_s3007_lloyd/history/{column}"]
    with read_store(tmp_path / "r.h5") as store:
        back = read_run(store, "k3_s3007_lloyd")
        assert damaged_runs(store) == {}
    assert np.isnan(back.history[column]).all() and len(back.history[column]) == 5
    np.testing.assert_array_equal(back.history["min_angle_deg"], record.history["min_angle_deg"])


def test_record_pickles():
    """Records travel from workers to the master over MPI (pickled)."""
    import pickle

    record = synthetic_record(3, 1)
    assert_same(record, pickle.loads(pickle.dumps(record)))


def test_failed_record(tmp_path, scene):
    record = failed_record(4, 4002, "random", "MeshError: triangle quality 0.01 < 0.1", wall_s=2.5, rank=3)
    with open_store(tmp_path / "r.h5", scene) as store:
        write_run(store, record)
        back = read_run(store, record.id)
    assert not back.ok and back.status == "failed" and back.error == record.error
    assert back.rank == 3 and back.wall_s == 2.5 and math.isnan(back.metric)
    assert back.final_outlines == () and back.final_capacitance_pF.shape == (0, 4)
    assert all(len(v) == 0 for v in back.history.values())
    from mscap.geometry.layout import Layout

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    layout = Layout((square, square + 2, square + 4.5, square + 7))
    with_layout = failed_record(4, 4003, "lloyd", "GeometryError: overlap", 0.1, initial_layout=layout)
    with open_store(tmp_path / "r.h5", scene) as store:
        write_run(store, with_layout)
        back = read_run(store, with_layout.id)
    assert not back.ok and len(back.initial_outlines) == 4
    np.testing.assert_array_equal(back.initial_outlines[3], layout.outlines[3])


def test_record_from_result(scene):
    """From an ``OptimizeResult``-shaped object (duck-typed: no optimisation run)."""
    from types import SimpleNamespace

    from mscap.geometry.layout import Layout
    from mscap.design.history import Record

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    before, after = Layout((square, square + 2)), Layout((square * 1.5, square + 3))
    rows = [Record(0, 0, -1.0, {"d": 1.0, "barrier": 0.1, "smoothing": 0.2}, 3.0, 0.0, 1.0, "start", 1, 5, 30.0, 1.0, 0.5),
            Record(1, 0, -2.0, {"d": 2.0, "barrier": 0.1, "smoothing": 0.2}, 1.0, 0.3, 1.4, "converged", 2, 6, 29.0, 0.9, 1.5)]
    caps = np.array([[1.0, 2.0], [1.5, 2.5], [3.0, 1.0]])
    result = SimpleNamespace(history=tuple(rows), iterations=1, reason="converged", layout=after,
                             initial=SimpleNamespace(capacitance_pF=caps * 0.5),
                             evaluation=SimpleNamespace(capacitance_pF=caps))
    r = record_from_result(2, 2000, "lloyd", before, result, scene.poses, wall_s=12.0, rank=2)
    assert r.ok and r.poses == ("rest", "a", "b") and r.iterations == 1 and r.metric == 1.0
    np.testing.assert_array_equal(r.final_outlines[0], after.outlines[0])
    np.testing.assert_array_equal(r.initial_outlines[1], before.outlines[1])
    assert list(r.history["event"]) == ["start", "converged"] and r.history["newton_iterations"].dtype == np.int64


def test_resume_finished_ids(tmp_path, scene):
    path = tmp_path / "r.h5"
    with open_store(path, scene) as store:
        write_run(store, synthetic_record(2, 2000))
        write_run(store, failed_record(2, 2001, "random", "boom", 1.0))
    with open_store(path, scene, mpi_size=3) as store:
        assert finished_ids(store) == {"k2_s2000_random", "k2_s2001_random"}
        assert store.attrs["sessions"] == 2 and store.attrs["mpi_size"] == 3
        todo = [c for c in configurations(scene) if c.id not in finished_ids(store)]
        assert len(todo) == len(configurations(scene)) - 1  # the synthetic 2000 is not a configuration
        write_run(store, synthetic_record(2, 2000, scale=2.0))  # replacing a run keeps one copy
        assert finished_ids(store) == {"k2_s2000_random", "k2_s2001_random"}


def test_refuses_other_scene_unless_force(tmp_path, scene, other_scene):
    path = tmp_path / "r.h5"
    with open_store(path, scene) as store:
        write_run(store, synthetic_record(2, 2000))
    with pytest.raises(StoreError) as info:
        open_store(path, other_scene)
    message = str(info.value)
    assert scene.sha256 in message and other_scene.sha256 in message and "--force" in message
    with open_store(path, other_scene, force=True) as store:  # starts over
        assert finished_ids(store) == set() and store.attrs["scene_sha256"] == other_scene.sha256


def test_refuses_non_mscap_file(tmp_path, scene):
    path = tmp_path / "x.h5"
    h5py.File(path, "w").close()
    with pytest.raises(StoreError, match="not an mscap results file"):
        open_store(path, scene)
    (tmp_path / "t.h5").write_text("not hdf5")
    with pytest.raises(StoreError, match="cannot open"):
        open_store(tmp_path / "t.h5", scene)


def test_half_written_group_is_dropped(tmp_path, scene):
    """A process killed (SIGKILL) while writing a run group leaves a file that opens; the
    temporary group is dropped, the finished run survives intact."""
    path = tmp_path / "r.h5"
    script = writer_script(path, scene, 2000, """
        g = store["runs"].create_group(TEMP_PREFIX + "k3_s3000_random")
        g.attrs["k"] = 3
        g.create_dataset("initial_outline_points_mm", data=[[0.0, 1.0]])
        store.flush()
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT)
    assert done.returncode == -signal.SIGKILL
    with h5py.File(path, "r") as f:
        assert TEMP_PREFIX + "k3_s3000_random" in f["runs"]
    with open_store(path, scene) as store:
        assert finished_ids(store) == {"k2_s2000_random"}
        assert list(store["runs"]) == ["k2_s2000_random"]
        assert_same(synthetic_record(2, 2000), read_run(store, "k2_s2000_random"))


def test_killed_while_writing_many_runs(tmp_path, scene):
    """SIGKILL at an arbitrary moment of a loop of writes: the file opens and every
    finished run reads back complete."""
    path = tmp_path / "r.h5"
    script = writer_script(path, scene, 0, """
        print("ready", flush=True)
        for i in range(1, 100000):
            write_run(store, synthetic_record(2 + i % 3, i))
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    import time

    time.sleep(0.7)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with open_store(path, scene) as store:
        ids = finished_ids(store)
        assert ids and not any(i.startswith(TEMP_PREFIX) for i in store["runs"])
        for rid in ids:
            r = read_run(store, rid)
            assert_same(synthetic_record(r.k, r.seed), r)


def test_inspect_while_a_writer_holds_the_file(tmp_path, scene, capsys):
    """``mscap inspect`` reads a running job's file; a second writer is refused clearly."""
    path = tmp_path / "r.h5"
    script = writer_script(path, scene, 0, """
        print("ready", flush=True)
        sys.stdin.readline()
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        assert main(["inspect", str(path), "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["runs_total"] == 1
        if os.environ.get("HDF5_USE_FILE_LOCKING", "").upper() != "FALSE":
            with pytest.raises(StoreError, match="open for writing in another process"):
                open_store(path, scene)
    finally:
        proc.communicate("\n", timeout=30)
    assert proc.returncode == 0


def test_selection_group(tmp_path, scene):
    with open_store(tmp_path / "r.h5", scene) as store:
        for k, scale in ((2, 1.0), (3, 3.0), (4, 3.05)):
            write_run(store, synthetic_record(k, k * 1000, scale=scale))
        write_run(store, failed_record(4, 4001, "random", "boom", 1.0))
        selection = store_selection(store)
        write_selection(store, selection)
        write_selection(store, selection)  # rewriting replaces
        g = store["selection"]
        assert set(g) | set(g.attrs) == set(SELECTION_ITEMS)
        assert list(g["k"][()]) == [2, 3, 4] and list(g["runs_failed"][()]) == [0, 0, 1]
        assert g.attrs["chosen_k"] == selection.chosen_k
        assert g["best_run"].asstr()[list(g["k"][()]).index(selection.chosen_k)] == selection.chosen_run


def test_silent_plates_threshold_is_half_the_offset_noise():
    """A plate is silent when its read-out's standard deviation over the design poses is
    below half the per-reading offset noise σ = a/√3 (1.155 pF for appendix A's ±2 pF)."""
    from mscap.scene.calibration import NoiseModel
    from mscap.service.report import SILENT_FRACTION, silent_plates

    sigma = 2.0 / np.sqrt(3)
    wave = np.array([-1.0, 1.0, -1.0, 1.0])  # standard deviation 1
    c = np.column_stack([50 + 0.99 * SILENT_FRACTION * sigma * wave, 40 + 1.01 * SILENT_FRACTION * sigma * wave,
                         np.full(4, 30.0), 60 + 5 * wave])
    (plate0, plate2) = silent_plates(c)
    assert plate0[0] == 0 and plate0[1] == pytest.approx(50) and plate0[2] == pytest.approx(0.99 * 0.5 * sigma)
    assert plate2 == (2, 30.0, 0.0)
    assert [p for p, _, _ in silent_plates(c, NoiseModel(additive_pF=0.2))] == [2]   # less noise: only the dead one
    assert silent_plates(c[:1]) == [] and silent_plates(np.full((3, 2), np.nan)) == []


def test_narrow_necks_name_the_plates_a_stencil_may_not_cut():
    # The feature size is [optimizer] min_feature_mm, else half the min gap (1 mm here);
    # a 0.3 mm slot cut 4 mm into a 5 mm square is a neck (its sides are > 2π mm apart
    # along the outline); the square's corners, 0.3 mm apart only near a corner, are not.
    from mscap.geometry import polygons
    from mscap.service.report import narrow_necks, narrow_necks_text
    from tests.design.test_objective import slotted_square

    slot, square = slotted_square(0.3, spacing=0.1), polygons.square((20.0, 0.0), 5.0)
    assert polygons.narrowest_neck(slot, 2 * np.pi, 1.0) == pytest.approx(0.3, rel=1e-9)
    assert polygons.narrowest_neck(square, 2 * np.pi, 1.0) == np.inf
    feature, necks = narrow_necks([square, slot], '[capacitors]\nmin_gap_mm = 2.0\n')
    assert feature == 1.0 and len(necks) == 1 and necks[0][0] == 1 and necks[0][1] == pytest.approx(0.3)
    assert "plate 1 of k2_s1 has a neck or slot 0.3 mm wide, narrower than 1 mm" in narrow_necks_text("k2_s1", necks,
                                                                                                    feature)
    assert narrow_necks([slot], '[optimizer]\nmin_feature_mm = 0.25\n') == (0.25, [])
    assert narrow_necks([slot], "not toml ][") == (pytest.approx(float("nan"), nan_ok=True), [])


def synthetic_store(path, scene, metrics: dict, failures=()):
    """Runs with a prescribed final metric per (k, seed): capacitances of poses on a line."""
    with open_store(path, scene, mpi_size=2) as store:
        for (k, seed), m in metrics.items():
            c = np.zeros((3, k))
            c[:, 0] = [0.0, m, 2 * m + 1]  # min pairwise L1 = m
            record = synthetic_record(k, seed)
            write_run(store, RunRecord(**{**record.__dict__, "final_capacitance_pF": c, "wall_s": 10.0}))
        for k, seed in failures:
            write_run(store, failed_record(k, seed, "random", "Newton failed", 1.0))
        write_selection(store, store_selection(store))


def test_a_design_with_a_silent_plate_reads_as_one_plate_less(tmp_path, scene, capsys):
    """k = 3's best wins the plateau rule on its min L1, but its plate 2 reads 5 pF at every
    pose: ``mscap inspect`` counts the plates that read (per k and per run) and says that
    as a sensor it is a 2-plate design, with its min L1 over those plates."""
    from mscap.service.report import reading_plates

    path = tmp_path / "r.h5"
    designs = {2: [[0, 0], [1, 1], [2, 2]],  # min L1 2 pF
               3: [[0, 0, 5], [1.5, 1.5, 5], [3, 3, 5.001]]}  # 3 pF, plate 2 silent
    with open_store(path, scene, mpi_size=2) as store:
        for k, c in designs.items():
            record = synthetic_record(k, 1000 * k)
            write_run(store, RunRecord(**{**record.__dict__, "final_capacitance_pF": np.array(c, float)}))
        write_selection(store, store_selection(store))
    reading = reading_plates(np.array(designs[3], float))
    assert (reading.k, reading.silent, reading.plates, reading.metric_pF) == (3, (2,), 2, pytest.approx(3.0))
    assert reading_plates(np.array(designs[2], float)).silent == ()
    assert main(["inspect", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["chosen_k"] == 3 and [e["best_reading_plates"] for e in doc["per_k"]] == [2, 2, None]
    # As sensors both designs have 2 plates; k = 3's reads better over them (3 against 2 pF).
    assert doc["by_reading_plates"] == {"plates": 2, "run": "k3_s3000_random",
                                        "best": {"2": {"score": pytest.approx(3.0), "run": "k3_s3000_random"}}}
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    assert text.splitlines()[1].split()[-1] == "reads" and "2/3" in text and "2/2" in text
    assert ("k = 3's best design reads on 2 of its 3 plates: without plate 2 its min L1 is 3 pF, k = 2's best "
            "2 pF: as a sensor it is a 2-plate design") in text
    assert ("by the plates that read: 2 plates, run k3_s3000_random (the rule on k picks 3); best per number of "
            "plates read: 2: 3 pF (k3_s3000_random)") in text
    assert main(["inspect", str(path), "--runs"]) == 0
    assert [line.split()[-1] for line in capsys.readouterr().out.splitlines()] == ["reads", "2/2", "2/3"]


def test_inspect_json(tmp_path, scene, capsys):
    path = tmp_path / "r.h5"
    synthetic_store(path, scene, {(2, 2000): 1.0, (2, 2001): 1.5, (3, 3000): 2.0, (4, 4000): 2.02},
                    failures=[(3, 3001), (4, 4001)])
    assert main(["inspect", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["chosen_k"] == 3 and doc["chosen_run"] == "k3_s3000_random" and doc["runs_total"] == 6
    assert [(e["k"], e["runs_ok"], e["runs_failed"], e["best_metric"], e["best_run"]) for e in doc["per_k"]] == [
        (2, 2, 0, 1.5, "k2_s2001_random"), (3, 1, 1, 2.0, "k3_s3000_random"), (4, 1, 1, 2.02, "k4_s4000_random")]
    # the synthetic runs read only on plate 0: the chosen run's plates 1 and 2 are silent
    assert doc["silent_plates"] == [{"plate": 1, "mean_pF": 0.0, "std_pF": 0.0}, {"plate": 2, "mean_pF": 0.0, "std_pF": 0.0}]
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    assert "*   3" in text and "chosen k = 3" in text
    assert "warning: plate 2 of k3_s3000_random reads 0.00 ± 0 pF at every design pose" in text
    assert main(["inspect", str(path), "--run", "k3_s3001_random"]) == 0
    assert "error: Newton failed" in capsys.readouterr().out
    assert main(["inspect", str(path), "--run", "k2_s2000_random"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[2].startswith("no finer-mesh check")  # the synthetic runs were not checked
    assert out[3].split("\t") == list(HISTORY_FIELDS) and len(out) == 4 + 5
    assert main(["inspect", str(path), "--run", "nope"]) == 2
    assert "no run 'nope'" in capsys.readouterr().err


def test_merge(tmp_path, scene, other_scene, capsys):
    a, b, c = tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "c.h5"
    synthetic_store(a, scene, {(2, 2000): 1.0, (3, 3000): 2.0}, failures=[(4, 4000)])
    synthetic_store(b, scene, {(4, 4000): 2.5, (4, 4001): 2.6}, failures=[(2, 2001)])
    assert main(["merge", str(a), str(b), "-o", str(tmp_path / "all.h5")]) == 0
    with read_store(tmp_path / "all.h5") as f:
        assert finished_ids(f) == {"k2_s2000_random", "k2_s2001_random", "k3_s3000_random", "k4_s4000_random",
                                   "k4_s4001_random"}
        assert read_run(f, "k4_s4000_random").ok  # the successful copy wins over the failed one
        with read_store(a) as fa:
            assert_same(read_run(fa, "k3_s3000_random"), read_run(f, "k3_s3000_random"))
        assert f.attrs["scene_sha256"] == scene.sha256
        assert f["selection"].attrs["chosen_k"] == 4 and f["selection"].attrs["chosen_run"] == "k4_s4001_random"
    assert main(["merge", str(a), str(b), "-o", str(tmp_path / "all.h5")]) == 2  # exists
    assert "--force" in capsys.readouterr().err
    assert merge([a, b], tmp_path / "all.h5", force=True) == 5
    synthetic_store(c, other_scene, {(2, 2000): 1.0})
    with pytest.raises(StoreError, match="different scenes") as info:
        merge([a, c], tmp_path / "x.h5")
    assert scene.sha256 in str(info.value) and other_scene.sha256 in str(info.value)


def test_docs_match_schema():
    """docs/hdf5.md carries the schema tables generated from the code."""
    text = (ROOT / "docs" / "hdf5.md").read_text()
    assert schema_markdown() in text


def test_a_file_of_another_schema_version_is_refused(tmp_path):
    import h5py

    from mscap.scene import load_scene
    from mscap.service.store import SCHEMA_VERSION, StoreError, open_store
    from tests.conftest import SMALL_SCENE, to_toml

    path = tmp_path / "scene.toml"
    path.write_text(to_toml(SMALL_SCENE))
    scene = load_scene(path)
    out = tmp_path / "r.h5"
    open_store(out, scene).close()
    with h5py.File(out, "r+") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(StoreError, match=rf"schema_version {SCHEMA_VERSION + 1}; this mscap writes {SCHEMA_VERSION}"):
        open_store(out, scene)
    open_store(out, scene, force=True).close()  # --force starts over


def test_read_design_takes_the_chosen_or_named_run(tmp_path, scene):
    from mscap.service.designs import read_design, split_design_spec

    assert split_design_spec("out/a.h5") == ("out/a.h5", None)
    assert split_design_spec("out/a.h5:k2_s0001_random") == ("out/a.h5", "k2_s0001_random")
    assert split_design_spec("/a:b/c.hdf5") == ("/a:b/c.hdf5", None)
    path = tmp_path / "r.h5"
    with open_store(path, scene) as store:
        empty_error = pytest.raises(StoreError, match="no successful run")
        with empty_error:
            read_design(store, None)
        for rec in (synthetic_record(2, 1, scale=1.0), synthetic_record(3, 2, scale=5.0),
                    failed_record(4, 3, "random", "MeshError: boom", 1.0)):
            write_run(store, rec)
        write_selection(store, store_selection(store))
    with read_store(path) as store:
        chosen = store_selection(store).chosen_run
        best = read_design(store)
        assert best.run_id == chosen and best.label == chosen and best.which == "final"
        rec = read_run(store, chosen)
        assert len(best.outlines) == rec.k
        np.testing.assert_array_equal(best.capacitance_pF, rec.final_capacitance_pF)
        first = read_design(store, "k2_s0001_random", "initial")
        assert first.label == "k2_s0001_random:initial"
        np.testing.assert_array_equal(first.outlines[0], synthetic_record(2, 1).initial_outlines[0])
        with pytest.raises(StoreError, match="failed .*MeshError: boom"):
            read_design(store, "k4_s0003_random")
        with pytest.raises(StoreError, match="no run 'k9'"):
            read_design(store, "k9")


def test_read_back_bounds_round_trip_and_decide_the_selection(tmp_path, scene, capsys):
    """Runs designed for read-back store their bound; the best run per k is then the one
    with the smallest bound (not the largest min L1), and inspect shows the bounds."""
    path = tmp_path / "r.h5"
    runs = {(2, 2000): (1.0, 0.80), (2, 2001): (1.5, 0.90), (3, 3000): (2.0, 0.50), (4, 4000): (2.5, 0.49)}
    with open_store(path, scene, mpi_size=2) as store:
        for (k, seed), (m, bound) in runs.items():
            c = np.zeros((3, k))
            c[:, 0] = [0.0, m, 2 * m + 1]
            record = RunRecord(**{**synthetic_record(k, seed).__dict__, "final_capacitance_pF": c,
                                  "bound_mm": bound, "initial_bound_mm": 2 * bound})
            write_run(store, record)
            back = read_run(store, record.id)
            assert back.bound_mm == bound and back.initial_bound_mm == 2 * bound
        write_selection(store, store_selection(store))
        g = store["selection"]
        np.testing.assert_array_equal(g["best_bound_mm"][()], [0.80, 0.50, 0.49])
        assert g.attrs["chosen_run"] == "k3_s3000_random" and "read-back bound" in g.attrs["rule"]
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "best bound (mm)" in out and "k2_s2000_random" in out and "k2_s2001_random" not in out
    assert main(["inspect", str(path), "--runs"]) == 0
    assert "1.6 → 0.8" in capsys.readouterr().out


def test_the_plateau_rule_on_the_plates_that_read():
    """``reading_choice``: each finished, unpruned design counts as the sensor of its plates
    that read, scored over those plates (min L1) or by its read-back bound."""
    from mscap.service.report import Reading, reading_choice
    from mscap.service.selection import RunSummary

    runs = [RunSummary("k2_s1_lloyd", 2, True, 2.0, 1.0), RunSummary("k3_s2_lloyd", 3, True, 3.0, 1.0),
            RunSummary("k4_s3_lloyd", 4, True, 3.5, 1.0), RunSummary("k4_s4_random", 4, True, 9.0, 1.0, pruned=True),
            RunSummary("k5_s5_lloyd", 5, False, math.nan, 1.0)]
    readings = {"k2_s1_lloyd": Reading(2, (), 2.0), "k3_s2_lloyd": Reading(3, (2,), 2.9),
                "k4_s3_lloyd": Reading(4, (), 3.5), "k4_s4_random": Reading(4, (), 9.0)}
    tight = reading_choice(runs, readings, 0.05)  # 3.5 > 1.05 × 2.9: four plates
    assert (tight.plates, tight.run) == (4, "k4_s3_lloyd") and not tight.by_bound
    assert tight.best == {2: (2.9, "k3_s2_lloyd"), 4: (3.5, "k4_s3_lloyd")}  # the k = 3 design is a 2-plate one
    loose = reading_choice(runs, readings, 0.25)  # 3.5 ≤ 1.25 × 2.9: two plates, read by the k = 3 design
    assert (loose.plates, loose.run) == (2, "k3_s2_lloyd")
    assert "by the plates that read: 2 plates, run k3_s2_lloyd (the rule on k picks 4)" in loose.text(4)
    bounded = [RunSummary(r.id, r.k, r.ok, r.metric, r.wall_s, bound_mm=b, pruned=r.pruned)
               for r, b in zip(runs, (0.5, 0.45, 0.3, 0.1, math.nan))]
    by_bound = reading_choice(bounded, readings, 0.05)
    assert by_bound.by_bound and by_bound.best == {2: (0.45, "k3_s2_lloyd"), 4: (0.3, "k4_s3_lloyd")}
    assert by_bound.plates == 4 and reading_choice([], {}, 0.05).text(None) == ""
