"""The multi-start's choice made on calibrated read-back error (mscap.service.calibrated;
docs/calibration.md, "Choosing on calibrated error")."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest

from mscap.calibration.service import Candidate, evaluate
from mscap.cli import main
from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.loader import with_overrides
from mscap.service.calibrated import calibrate_selection
from mscap.service.designs import read_design
from mscap.service.selection import CalibratedDesign, RunSummary, by_calibration, select
from mscap.viz.layouts import plot_results
from mscap.service.store import (drop_calibration, open_store, read_calibration, read_store, store_selection,
                                 write_calibration, write_run, write_selection)
from tests.calibration.test_calibration import _OneRank, calibration_scene
from tests.conftest import synthetic_record

ROOT = Path(__file__).resolve().parents[2]
TOL = 0.05


def runs() -> list[RunSummary]:
    """k = 2: a (best bound), b; k = 3: c (best bound: the objective picks k = 3), d pruned, e failed."""
    return [RunSummary("a", 2, True, 5.0, 1.0, bound_mm=0.20), RunSummary("b", 2, True, 4.0, 1.0, bound_mm=0.30),
            RunSummary("c", 3, True, 6.0, 1.0, bound_mm=0.10),
            RunSummary("d", 3, True, 6.5, 1.0, bound_mm=0.05, pruned=True),
            RunSummary("e", 3, False, math.nan, 1.0)]


CALIBRATED = (CalibratedDesign("a", 2, 0.30, 0.01, 0.20), CalibratedDesign("a:initial", 2, 0.25, 0.01, 0.40),
              CalibratedDesign("b", 2, 0.28, 0.01, 0.30), CalibratedDesign("c", 3, 0.29, 0.01, 0.10),
              CalibratedDesign("d", 3, 0.10, 0.01, 0.05), CalibratedDesign("scene", 3, 0.20, 0.01))


def test_calibrated_error_chooses_the_design_and_k_the_objective_would_not():
    objective = select(runs(), TOL, range(2, 4))
    assert (objective.chosen_k, objective.chosen_run) == (3, "c")     # 1/0.10 beats 1.05/0.20
    chosen = select(runs(), TOL, range(2, 4), CALIBRATED)
    # k = 2's best is a's initial layout (0.25 mm); k = 3's is c (0.29): the pruned d and the
    # scene layout are never chosen, however well they calibrate; 1/0.29 < 1.05/0.25: k = 2.
    assert chosen.by_calibration and (chosen.chosen_k, chosen.chosen_run) == (2, "a")
    assert (chosen.chosen_design, chosen.chosen_which) == ("a:initial", "initial")
    assert [(s.k, s.best_design, s.best_error_mm) for s in chosen.per_k] == [(2, "a:initial", 0.25), (3, "c", 0.29)]
    assert [s.best_run for s in chosen.per_k] == ["a", "c"]           # the objective's best runs stay
    assert (chosen.objective_k, chosen.objective_design) == (3, "c") and chosen.plateau_reached
    text = chosen.verdict()
    assert "a:initial 0.25 ± 0.01 mm; next best b 0.28 mm (+12.0 %)" in text
    assert "the objective alone would have chosen c (k = 3), which calibrates at 0.29 mm (+16.0 %)" in text
    assert "the scene's own layout 0.2 mm (better than every design of the run)" in text
    # k = 3 better by more than plateau_tol: the plateau rule takes it, and says it is unconfirmed
    better = [replace(d, error_mm=0.20) if d.label == "c" else d for d in CALIBRATED]
    chosen = select(runs(), TOL, range(2, 4), better)
    assert (chosen.chosen_k, chosen.chosen_design, chosen.plateau_reached) == (3, "c", False)
    assert "Raise [multistart] k_max to 5" in chosen.advice() and "calibrated error" in chosen.advice()
    # nothing eligible with a finite error: the objective's choice, unchanged
    nan = [replace(d, error_mm=math.nan) for d in CALIBRATED]
    assert by_calibration(objective, nan, runs()) is objective
    assert by_calibration(objective, CALIBRATED[-2:], runs()) is objective   # the pruned run, the scene


@pytest.fixture
def scene(write_scene):
    d = calibration_scene()
    d["multistart"] = {"k_min": 2, "k_max": 3, "starts_per_k": 2}
    return load_scene(write_scene(d))


def test_the_store_keeps_the_calibration_and_the_user_sees_the_choice(scene, tmp_path, capsys):
    path = tmp_path / "r.h5"
    records = [replace(synthetic_record(2, 1), bound_mm=0.2), replace(synthetic_record(3, 2), bound_mm=0.1)]
    designs = (CalibratedDesign(records[0].id, 2, 0.25, 0.01, 0.2),
               CalibratedDesign(f"{records[0].id}:initial", 2, 0.21, 0.02, 0.5),
               CalibratedDesign(records[1].id, 3, 0.30, math.nan, 0.1), CalibratedDesign("scene", 2, 0.4, 0.0))
    with open_store(path, scene, force=True) as store:
        for record in records:
            write_run(store, record)
        write_calibration(store, designs, {"noise_seeds": np.array([0, 1, 2]), "noise_runs": 20, "cache": "c.h5",
                                           "wall_s": 1.0, "simulation_s": 2.0})
        write_selection(store, store_selection(store))
    with read_store(path) as store:
        back = read_calibration(store)
        assert [(d.label, d.k) for d in back] == [(d.label, d.k) for d in designs]
        for name in ("error_mm", "spread_mm", "bound_mm"):                # every bit, NaN included
            np.testing.assert_array_equal([getattr(d, name) for d in back], [getattr(d, name) for d in designs])
        g = store["selection"]
        assert (g.attrs["chosen_k"], g.attrs["chosen_design"], g.attrs["objective_chosen_k"]) == \
            (2, f"{records[0].id}:initial", 3)
        assert g["best_design"].asstr()[()].tolist() == [f"{records[0].id}:initial", records[1].id]
        np.testing.assert_array_equal(g["best_error_mm"][()], [0.21, 0.30])
        assert "calibrated" in g.attrs["rule"]
        chosen = read_design(store)                                   # what calibrate/readout take
        assert chosen.label == f"{records[0].id}:initial"
        for a, b in zip(chosen.outlines, records[0].initial_outlines):
            np.testing.assert_array_equal(a, b)
    # what the user sees: inspect's table and the figure show the calibrated choice
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    assert "calibrated (mm)" in text and f"* chosen k = 2, design {records[0].id}:initial" in text
    assert "the calibration of the best designs 1 s wall, its simulations 2 worker-s" in text
    assert "the objective alone would have chosen k3_s0002_random (k = 3), which calibrates at 0.3 mm" in text
    panels = plot_results(path, tmp_path / "r.png")
    assert [(p.k, p.design, p.error_mm, p.chosen) for p in panels] == \
        [(2, f"{records[0].id}:initial", 0.21, True), (3, records[1].id, 0.30, False)]
    assert "calibrated 0.21 mm (initial layout)" in panels[0].title
    with open_store(path, scene) as store:
        del store["calibration"]["k"]                                 # damaged: the objective chooses
        assert read_calibration(store) == ()
        drop_calibration(store)
        assert "calibration" not in store and store_selection(store).chosen_design == records[1].id


def mscap(*args, mpi: int = 2):
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    command = ["mpirun", "-n", str(mpi), "--oversubscribe", str(Path(sys.executable).with_name("mscap")),
               *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)


def test_a_run_calibrates_its_designs_chooses_the_best_and_resumes_without_simulating(write_scene, tmp_path):
    """Two starts of k = 2 on the dome scene, with noise small enough that the plates read
    it: the run ends by calibrating both designs, their initial layouts and the scene
    layout; /calibration holds what `evaluate` gives on the same cache, averaged over the
    three noise seeds; the chosen design is the one of least error; a rerun with a third
    start calibrates again, simulating only its layouts; a job of some starts only (an
    array part) does not calibrate."""
    d = calibration_scene(training={"radius_mm": [30.0, 80.0, 5]}, sequence={"steps": 2, "radius_mm": [75.0, 32.0]},
                          noise={"runs": 20, "additive_pF": 0.01, "relative_shift": 0.01})
    d["multistart"] = {"k_min": 2, "k_max": 2, "starts_per_k": 2, "lloyd_fraction": 0.0, "error_estimate": False}
    d["optimizer"] = {"max_iterations": 2}
    path, results = write_scene(d), tmp_path / "r.h5"
    first = mscap("run", path, "-o", results)
    assert first.returncode == 0, first.stderr
    assert "chosen on calibrated read-back error (5 designs)" in first.stdout
    scene = load_scene(path)
    with read_store(results) as store:
        calibrated = read_calibration(store)
        selection = store_selection(store)
        g = store["calibration"]
        assert g.attrs["noise_seeds"].tolist() == [0, 1, 2] and g.attrs["noise_runs"] == 20
        cache = g.attrs["cache"]
        candidates = [Candidate(d.label, read_design(store, d.run_id, d.which).outlines) if d.run_id
                      else Candidate("scene", scene.layout.outlines) for d in calibrated]
    assert sorted(d.label for d in calibrated) == ["k2_s2000_random", "k2_s2000_random:initial", "k2_s2001_random",
                                                   "k2_s2001_random:initial", "scene"]
    assert Path(cache) == tmp_path / "r_calibration.h5"
    for design, candidate in zip(calibrated, candidates):
        per_seed = [np.nanmean(evaluate(scene, [candidate], cache, replace(scene.calibration.noise, seed=s))[0]
                               .errors.mean) for s in (0, 1, 2)]
        assert design.error_mm == pytest.approx(np.mean(per_seed), rel=1e-12)
        assert design.spread_mm == pytest.approx(np.std(per_seed), rel=1e-9) and design.spread_mm > 0
    best = min((d for d in calibrated if d.which != "scene"), key=lambda d: d.error_mm)
    assert selection.chosen_design == best.label and selection.by_calibration

    # A third start: its run drops /calibration, the end calibrates again, simulating only
    # the new run's two layouts (5 training + 3 sequence poses each).
    again = mscap("run", path, "-o", results, "--starts-per-k", "3")
    assert again.returncode == 0, again.stderr
    assert "16 poses to simulate" in again.stderr
    with read_store(results) as store:
        now = {d.label: d.error_mm for d in read_calibration(store)}
        assert {d.label: d.error_mm for d in calibrated}.items() <= now.items()
        assert len(now) == 7 and "k2_s2002_random:initial" in now
        best = min((label for label in now if label != "scene"), key=now.get)
        assert store_selection(store).chosen_design == best

    part = mscap("run", path, "-o", tmp_path / "part.h5", "--seeds", "0:1")
    assert part.returncode == 0, part.stderr
    with h5py.File(tmp_path / "part.h5") as f:
        assert "calibration" not in f and len(f["runs"]) == 1
    assert not (tmp_path / "part_calibration.h5").exists()
    doc = json.loads(subprocess.run([str(Path(sys.executable).with_name("mscap")), "inspect", str(results), "--json"],
                                    capture_output=True, text=True, cwd=ROOT).stdout)
    assert doc["by_calibration"] and doc["chosen_design"] == best and len(doc["calibrated"]) == 7


@pytest.mark.parametrize("multistart, key, message", [
    ({"calibrate_seeds": 0}, "multistart.calibrate_seeds", "must be in 1..100"),
    ({"calibrate_best": 1001}, "multistart.calibrate_best", "must be in 0..1000"),
    ({"calibrate_best": -1}, "multistart.calibrate_best", ">= 0"),
    ({"calibrate_scene": 1}, "multistart.calibrate_scene", "expected"),
])
def test_calibration_settings_are_checked_naming_the_key(write_scene, multistart, key, message):
    d = calibration_scene()
    d["multistart"] = multistart
    with pytest.raises(SceneError) as info:
        load_scene(write_scene(d))
    assert info.value.key == key and message in str(info.value)
    with pytest.raises(SceneError, match="--calibrate-best"):
        with_overrides(load_scene(write_scene(calibration_scene(), "ok.toml")), calibrate_best=-2)


def test_a_lead_within_the_noise_seeds_spread_is_called_a_tie():
    close = [replace(d, error_mm=0.255, spread_mm=0.004) if d.label == "b" else d for d in CALIBRATED]
    text = select(runs(), TOL, range(2, 4), close).verdict()
    # 0.255 - 0.25 = 0.005 < 2 * hypot(0.004, 0.01) = 0.0215
    assert "next best b 0.255 mm (+2.0 %, within the noise seeds' spread: a tie)" in text
    assert "a tie" not in select(runs(), TOL, range(2, 4), CALIBRATED).verdict()   # 0.03 > 0.028


def test_a_calibration_stopped_midway_chooses_nothing_from_it(scene, tmp_path, monkeypatch):
    """SIGTERM during the calibration's simulations: the designs done so far are no choice;
    the file keeps the objective's selection and no /calibration."""
    import mscap.calibration.service as service

    path = tmp_path / "r.h5"
    with open_store(path, scene, force=True) as store:
        write_run(store, replace(synthetic_record(2, 1), bound_mm=0.2))
        write_selection(store, store_selection(store))
    asked = []
    monkeypatch.setattr(service, "simulate_family", lambda scene, designs, *a, **k: asked.append(designs) or False)
    said = []
    assert not calibrate_selection(scene, path, _OneRank(), said.append)
    assert [d.label for d in asked[0]] == ["k2_s0001_random", "k2_s0001_random:initial", "scene"]
    assert "stopped before every design was calibrated" in said[-1]
    with read_store(path) as store:
        assert "calibration" not in store and not store_selection(store).by_calibration


def test_a_layout_under_two_labels_counts_its_simulations_once(scene, monkeypatch):
    """The scene's layout and a scene start's initial layout are one cache entry: the
    calibration's simulation time counts it once; each label gets its (equal) error."""
    import mscap.calibration.service as service
    from mscap.calibration.reconstruction import PoseErrors
    from mscap.service.calibrated import score_designs

    def fake(scene, designs, cache, noise=None, seeds=()):
        errors = np.arange(len(seeds) * 2 * 3, dtype=float).reshape(len(seeds) * 2, 3)   # 2 runs, 3 poses
        return [service.DesignScore(designs[0], PoseErrors(errors, errors), np.ones(3), 5, 0, 5, 0, 7.0)]
    monkeypatch.setattr(service, "evaluate", fake)
    same = tuple(np.array(o) for o in scene.layout.outlines)
    designs = [Candidate("scene", same), Candidate("k2_s2999_scene:initial", same),
               Candidate("k2_s2999_scene", tuple(o + 1.0 for o in same))]
    scored, simulation_s = score_designs(scene, designs, {}, "unused.h5")
    assert simulation_s == 14.0                                   # two layouts, not three
    # seed i's runs are rows 2i, 2i+1: means 2.5, 8.5, 14.5 -> 8.5 ± std
    assert [d.error_mm for d in scored] == [8.5] * 3
    assert scored[0].spread_mm == pytest.approx(np.std([2.5, 8.5, 14.5]))
