"""``mscap fit`` on a small scene: known parameters recovered from its own readings under
appendix A's noise, a pair the readings cannot separate reported as such, the fitted scene
a normal scene, the same fit on MPI workers, and bad input as one line."""

from __future__ import annotations

import copy
import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from mscap.fem.simulate import simulate
from mscap.scene import load_scene
from mscap.scene.calibration import NoiseModel
from mscap.scene.edit import apply, parameter
from tests.conftest import SMALL_SCENE, to_toml

MSCAP = str(Path(sys.executable).with_name("mscap"))
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
#: The values the synthetic readings are made with; the scene says 1.0 and 1.2.
TRUTH = {"thickness_scale": 0.9, "poses.pull.stretch": 1.25}
RUNS = 20


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    """The small scene (0.14 mm gap, two plates) at rest and pulled 20 % along x."""
    data = copy.deepcopy(SMALL_SCENE)
    data["poses"] = [{"name": "rest", "kind": "free"},
                     {"name": "pull", "kind": "stretch", "mode": "uniaxial", "direction": "x", "stretch": 1.2}]
    path = tmp_path_factory.mktemp("fit") / "small.toml"
    path.write_text(to_toml(data))
    return path


def readings_at(scene_file: Path, values: dict) -> np.ndarray:
    source = scene_file.read_text()
    data = tomllib.loads(source)
    params = [parameter(str(scene_file), data, name) for name in values]
    return simulate(load_scene(scene_file, source=apply(str(scene_file), source, params, list(values.values())))
                    ).capacitance_pF


def write_csv(path: Path, clean: np.ndarray, noise: NoiseModel | None) -> Path:
    """Every run's reading of each pose (appendix A: the run's gain per capacitor, an offset
    per reading), or the clean table once."""
    table = clean[None] if noise is None else noise.apply(clean)
    lines = ["pose,run,C0,C1"] + [f"{pose},{r},{c[0]!r},{c[1]!r}" for r, run in enumerate(table)
                                  for pose, c in zip(("rest", "pull"), run)]
    path.write_text("\n".join(lines) + "\n")
    return path


def mscap_fit(*args, ranks: int = 1) -> subprocess.CompletedProcess:
    command = [MSCAP, "fit", *map(str, args)]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), "--oversubscribe", *command]
    return subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def noisy_fit(scene_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("noisy")
    csv = write_csv(out / "readings.csv", readings_at(scene_file, TRUTH), NoiseModel(runs=RUNS, seed=3))
    done = mscap_fit(scene_file, csv, "-o", out / "fitted.toml", "--param", "thickness_scale",
                     "--param", "poses.pull.stretch=1:2", "--json", "-q")
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout), out / "fitted.toml", csv


def test_known_parameters_come_back_within_their_standard_errors(noisy_fit):
    record, _, _ = noisy_fit
    fitted = {p["name"]: p for p in record["parameters"]}
    for name, truth in TRUTH.items():
        p = fitted[name]
        assert abs(p["fitted"] - truth) < 3 * p["standard_error"], (name, p, truth)
        assert p["standard_error"] < 0.03 * truth  # 20 runs of ±15 % gains: a few per cent at most
    assert record["covariance"] == f"cluster-robust over {RUNS} runs"
    assert not record["not_separated"] and not record["not_determined"]
    # Appendix A's noise: per reading ±2 pF (std 1.15) and the run's ±15 % gain (std 8.7 %,
    # about 2 pF on these 17-26 pF plates): the residuals are that size, not more.
    assert 1.0 < record["rms_pF"] < 3.5


def test_clean_readings_give_the_values_back(scene_file, tmp_path):
    csv = write_csv(tmp_path / "clean.csv", readings_at(scene_file, TRUTH), None)
    done = mscap_fit(scene_file, csv, "-o", tmp_path / "fitted.toml", "--param", "thickness_scale",
                     "--param", "poses.pull.stretch=1:2", "--json", "-q")
    assert done.returncode == 0, done.stderr
    record = json.loads(done.stdout)
    got = {p["name"]: p["fitted"] for p in record["parameters"]}
    # Limited by the mesh, which follows the thickness: a step of 1 % in it moves C by the
    # difference of two meshes as well as by the physics.
    assert got == pytest.approx(TRUTH, rel=3e-3)
    assert record["rms_pF"] < 0.02


def test_the_fitted_scene_is_a_normal_scene_that_reads_as_the_fit_said(noisy_fit, scene_file):
    record, fitted, _ = noisy_fit
    text = fitted.read_text()
    assert text.startswith("# Fitted by `mscap fit`")
    assert "#   thickness_scale = " in text and "± " in text
    scene, original = load_scene(fitted), load_scene(scene_file)
    scale = next(p["fitted"] for p in record["parameters"] if p["name"] == "thickness_scale")
    assert [layer.thickness_mm for layer in scene.layers] == pytest.approx(
        [layer.thickness_mm * scale for layer in original.layers], rel=1e-9)
    assert scene.poses[1].stretch[0] == pytest.approx(record["parameters"][1]["fitted"], rel=1e-9)
    assert all(np.array_equal(a, b) for a, b in zip(scene.layout.outlines, original.layout.outlines))
    assert scene.multistart == original.multistart and scene.mesh == original.mesh
    simulated = np.array(record["simulated_pF"])[:2]  # run 0's rest and pull
    assert simulate(scene).capacitance_pF == pytest.approx(simulated, rel=1e-6)


def test_permittivity_and_thickness_are_reported_as_a_pair_the_readings_cannot_separate(noisy_fit, scene_file,
                                                                                       tmp_path):
    _, _, csv = noisy_fit
    done = mscap_fit(scene_file, csv, "-o", tmp_path / "f.toml", "--param", "thickness_scale",
                     "--param", "materials.clear.relative_permittivity", "--max-forwards", "3", "-q")
    assert done.returncode == 0, done.stderr
    # C ~ ε / d: to keep the readings, both move up together (correlation +1 up to the fringe).
    assert re.search(r"NOT SEPARATED: thickness_scale and materials.clear.relative_permittivity \(correlation "
                     r"\+(0\.99\d\d|1\.0000)", done.stdout), done.stdout
    assert "not separated by the readings: thickness_scale and materials.clear.relative_permittivity" in \
        (tmp_path / "f.toml").read_text()


def test_the_multistart_runs_on_a_fitted_scene_unchanged(noisy_fit, tmp_path):
    _, fitted, _ = noisy_fit
    out = tmp_path / "results.h5"
    done = subprocess.run([MSCAP, "run", str(fitted), "-o", str(out), "--k-min", "2", "--k-max", "2",
                           "--starts-per-k", "1", "--max-iterations", "2", "-q"], env=ENV, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    inspect = subprocess.run([MSCAP, "inspect", str(out), "--json"], env=ENV, capture_output=True, text=True)
    assert json.loads(inspect.stdout)["chosen_k"] == 2


@pytest.mark.skipif(shutil.which("mpirun") is None, reason="no mpirun (make installs openmpi-bin)")
def test_on_mpi_workers_the_fit_is_the_same(noisy_fit, scene_file, tmp_path):
    """Three workers for two parameters: each trial point and its Jacobian's columns at once;
    the forwards are the same numbers, so the iterates are too."""
    serial, _, csv = noisy_fit
    done = mscap_fit(scene_file, csv, "-o", tmp_path / "fitted.toml", "--param", "thickness_scale",
                     "--param", "poses.pull.stretch=1:2", "--json", "-q", ranks=4)
    assert done.returncode == 0, done.stderr
    record = json.loads(done.stdout)
    assert [p["fitted"] for p in record["parameters"]] == [p["fitted"] for p in serial["parameters"]]
    assert record["ranks"] == 4 and record["forwards"] >= serial["forwards"]


@pytest.mark.parametrize("args, says", [
    (["--param", "layers.glue.thickness_mm"], "layers.glue.thickness_mm: no element named 'glue' in layers"),
    (["--param", "thickness_scale=2:3"], "--param thickness_scale=2:3: the bounds [2, 3] exclude the scene's value 1"),
    (["--param", "thickness_scale=a:3"], "bounds are LO:HI (numbers; either may be empty), got 'a:3'"),
    (["--param", "thickness_scale", "--param", "layers.dielectric.thickness_mm"], "move the same value"),
    (["--param", "thickness_scale", "--step", "0"], "--step must lie in (0, 0.5), got 0.0"),
    (["--param", "thickness_scale", "-o", "/nonexistent/f.toml"], "/nonexistent is not a writable directory"),
])
def test_bad_arguments_are_one_line(scene_file, tmp_path, args, says):
    csv = tmp_path / "r.csv"
    csv.write_text("pose,C0,C1\nrest,24.0,17.0\npull,29.0,21.0\n")
    done = mscap_fit(scene_file, csv, "-o", tmp_path / "f.toml", *args)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert says in done.stderr
    assert not (tmp_path / "f.toml").exists()


@pytest.mark.parametrize("text, says", [
    ("pose,C0,C1\nrest,24.0,\n", "line 2, column C1: blank (a capacitor not measured is left out of the header"),
    ("pose,C0,C1\nrest,24.0,abc\n", "line 2, column C1: 'abc', not a finite number"),
    ("pose,C0,C1\nrest,24.0,nan\n", "line 2, column C1: 'nan', not a finite number"),
    ("pose,C0,C1\nfold,24.0,17.0\n", "line 2: no pose named 'fold' in the scene (it has rest, pull)"),
    ("pose,C0,C7\nrest,24.0,17.0\n", "column C7: the scene has 2 capacitors (C0..C1)"),
    ("pose,C0,C0\nrest,24.0,17.0\n", "column C0 given twice"),
    ("pose,temp,C0\nrest,20,17.0\n", "unknown column 'temp' (expected pose, run and C0..C1)"),
    ("C0,C1\n24.0,17.0\n", "no 'pose' column in the header"),
    ("pose,C0,C1\nrest,24.0\n", "line 2: 2 cells, the header has 3"),
    ("pose,C0,C1\n", "no readings below the header"),
    ("", "empty: expected a header"),
])
def test_a_bad_measurement_file_is_one_line_naming_file_line_and_column(scene_file, tmp_path, text, says):
    csv = tmp_path / "r.csv"
    csv.write_text(text)
    done = mscap_fit(scene_file, csv, "-o", tmp_path / "f.toml", "--param", "thickness_scale")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert f"{csv}: " in done.stderr and says in done.stderr, done.stderr


def test_a_measurement_path_that_is_not_a_file_is_one_line(scene_file, tmp_path):
    done = mscap_fit(scene_file, tmp_path, "-o", tmp_path / "f.toml", "--param", "thickness_scale")
    assert done.returncode == 2 and "is a directory, not a measurement CSV" in done.stderr
