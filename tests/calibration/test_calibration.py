"""Virtual calibration: the noise model, the RBF reconstruction, the [calibration]
section, the cached family simulation and ``mscap calibrate``."""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from mscap.calibration.service import Candidate, evaluate, family, physics_sha256, simulate_family, \
    targets
from mscap.calibration.reconstruction import MIN_SPREAD, fit, point_errors, score, whitened
from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.calibration import NoiseModel
from mscap.service.store import RunRecord, open_store, write_run

from tests.conftest import SMALL_SCENE

ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------- noise model
def test_noise_model_ranges_moments_and_independence():
    noise = NoiseModel(relative_shift=0.15, additive_pF=2.0, runs=400, seed=3)
    factor, offset = noise.draw(np.random.default_rng(3), 50, 4)
    assert factor.shape == (400, 1, 4) and offset.shape == (400, 50, 4)
    assert 0.85 <= factor.min() and factor.max() <= 1.15 and np.abs(offset).max() <= 2.0
    # uniform on [-a, a]: mean 0, variance a²/3 (400·4 and 80 000 samples)
    assert abs(factor.mean() - 1) < 4 * 0.15 / np.sqrt(3 * factor.size)
    assert factor.var() == pytest.approx(0.15**2 / 3, rel=0.1)
    assert offset.var() == pytest.approx(4 / 3, rel=0.02)
    # the per-run factor is one draw per run and capacitor, the offsets independent of it
    corr = np.corrcoef(np.broadcast_to(factor, offset.shape).ravel(), offset.ravel())[0, 1]
    assert abs(corr) < 4 / np.sqrt(offset.size)
    run_corr = np.corrcoef(offset[:, 0, 0], offset[:, 1, 0])[0, 1]   # pose to pose, same capacitor
    assert abs(run_corr) < 4 / np.sqrt(noise.runs)

    clean = np.array([[50.0, 60.0], [70.0, 80.0], [90.0, 100.0]])
    noisy = NoiseModel(runs=200).apply(clean)
    ratio_shift = noisy - NoiseModel(runs=200).apply(clean)
    assert np.all(ratio_shift == 0)                                   # seeded: reproducible
    # every read-out within the model's envelope (shifted by ±15 %, then ±2 pF)
    assert np.all(noisy >= 0.85 * clean - 2.0) and np.all(noisy <= 1.15 * clean + 2.0)
    zero = NoiseModel(relative_shift=0.0, additive_pF=0.0, runs=5).apply(clean)
    np.testing.assert_array_equal(zero, np.broadcast_to(clean, zero.shape))


# ---------------------------------------------------------------- reconstruction
def test_rbf_is_exact_on_training_poses_and_reproduces_affine_maps():
    rng = np.random.default_rng(0)
    c = 50 + 20 * rng.random((30, 3))
    y = rng.random((30, 12))
    model = fit(c, y)
    np.testing.assert_allclose(model.predict(c), y, atol=1e-9)
    # thin-plate splines carry a degree-1 polynomial: affine data are reproduced anywhere
    a, b = rng.random((3, 12)), rng.random(12)
    affine = fit(c, c @ a + b)
    c_new = 40 + 40 * rng.random((7, 3))
    np.testing.assert_allclose(affine.predict(c_new), c_new @ a + b, atol=1e-8)


def test_identical_capacitances_are_merged_to_the_mean_target():
    c = np.array([[1.0, 2.0], [3.0, 1.0], [1.0, 2.0], [2.0, 5.0], [4.0, 4.0]])
    y = np.array([[0.0], [1.0], [2.0], [3.0], [4.0]])
    model = fit(c, y)
    assert [g.tolist() for g in model.groups] == [[0, 2], [1], [3], [4]]
    np.testing.assert_allclose(model.predict(c[[0, 1, 3]]), [[1.0], [1.0], [3.0]], atol=1e-9)


def test_point_errors_and_noise_free_score():
    truth = np.array([[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]])
    pred = truth + np.array([[3.0, 4.0, 0.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(point_errors(pred, truth, 3), [[5.0, 0.0]])
    c = np.array([[10.0, 0.0], [0.0, 10.0], [5.0, 5.0], [1.0, 1.0]])
    model = fit(c, np.arange(8.0).reshape(4, 2))
    errors = score(model, c, np.arange(8.0).reshape(4, 2), 1, NoiseModel(0.0, 0.0, runs=3))
    assert errors.mean.shape == (3, 4) and errors.max.max() < 1e-9


def test_whitened_map_drops_a_direction_below_the_noise_and_stays_bounded():
    """Two read-outs: the first spans the family, the second moves 1e-6 pF with it (a
    plate that reads almost nothing). The raw thin-plate spline follows that trend with
    its linear part and sends a 1 pF error of the second read-out kilometres away; the
    whitened map drops the direction (spread 1.5e-7 noise std) and equals the spline on the
    first read-out alone (in 1-D a thin-plate spline is scale- and shift-equivariant: its
    r² log a term is a polynomial its linear part absorbs)."""
    t = np.linspace(0.0, 1.0, 9)
    c = np.column_stack([50 + 10 * t, 20 + 1e-6 * t**2])
    y = np.column_stack([30 * t**2, np.cos(3 * t)])
    std = np.array([2.0, 2.0])
    raw, white = fit(c, y), fit(c, y, noise_std=std)
    assert white.features.directions == 1
    assert white.features.spread[0] == pytest.approx(np.std(10 * t) / 2.0, rel=1e-6)
    assert white.features.spread[1] < 1e-6
    noisy = c[[2, 6]] + [[0.0, 1.0], [0.0, -1.0]]
    assert np.abs(raw.predict(noisy)).max() > 1e6                          # mm: the blow-up
    alone = fit(c[:, :1], y)
    np.testing.assert_allclose(white.predict(noisy), alone.predict(noisy[:, :1]), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(white.predict(c), y, atol=1e-6)            # still through the training data


def test_whitened_features_are_in_noise_units_and_answer_the_mean_without_signal():
    """A read-out scaled by λ with its noise scaled by λ is the same feature: the map does
    not change (to round-off). With every direction below ``min_spread`` noise standard
    deviations the map answers the mean training target, whatever the read-out."""
    rng = np.random.default_rng(1)
    c = 50 + 20 * rng.random((25, 3))
    y = rng.random((25, 4))
    std = np.array([1.0, 2.0, 0.5])
    scale = np.array([3.0, 0.1, 7.0])
    base, scaled = fit(c, y, noise_std=std), fit(c * scale, y, noise_std=std * scale)
    probe = 45 + 30 * rng.random((6, 3))
    np.testing.assert_allclose(scaled.predict(probe * scale), base.predict(probe), rtol=1e-8, atol=1e-10)
    spread = whitened(c, std).spread
    assert spread.min() > MIN_SPREAD
    quiet = fit(c, y, noise_std=np.full(3, 10 * spread.max() * std.max() / MIN_SPREAD))
    assert quiet.interpolator is None and quiet.features.directions == 0
    np.testing.assert_allclose(quiet.predict(probe), np.broadcast_to(y.mean(axis=0), (6, 4)), rtol=1e-12)
    with pytest.raises(ValueError, match="positive noise standard deviations"):
        fit(c, y, noise_std=np.array([1.0, 0.0, 1.0]))


# ---------------------------------------------------------------- scenes
def calibration_scene(**calibration) -> dict:
    """The small test sheet glued onto a dome whose radius the calibration varies."""
    d = copy.deepcopy(SMALL_SCENE)
    d["objects"] = {"pad": {"generator": "dome", "width_mm": 31.0, "height_mm": 21.0,
                            "corner_mm": [-0.5, -0.5], "edge_length_mm": 1.5}}
    d["poses"] = [{"name": "rest", "kind": "free"},
                  {"name": "dome", "kind": "glue", "object": "pad", "radius_mm": 40.0}]
    d["calibration"] = {"pose": "dome", "training": {"radius_mm": [30.0, 80.0, 6]},
                        "sequence": {"steps": 4, "radius_mm": [80.0, 35.0, 26.0]},
                        "noise": {"runs": 20}} | calibration
    return d


def test_calibration_section_is_read(write_scene):
    scene = load_scene(write_scene(calibration_scene()))
    cal = scene.calibration
    assert cal.pose == "dome" and cal.parameters == ("radius_mm",) and cal.target == "vertices"
    np.testing.assert_allclose(cal.training.ravel(), [30, 40, 50, 60, 70, 80])
    # 4 steps per leg: 80 → 35 → 26 (26 and 28.25 lie below the training range)
    np.testing.assert_allclose(cal.sequence.ravel(), [80, 68.75, 57.5, 46.25, 35, 32.75, 30.5, 28.25, 26])
    assert cal.in_range.tolist() == [True] * 7 + [False] * 2
    assert cal.noise == NoiseModel(0.15, 2.0, 20, 0)
    assert (cal.features, cal.smoothing, cal.min_spread) == ("whitened", 1.0, 0.5)   # smoothing in noise units
    raw = load_scene(write_scene(calibration_scene(features="raw"), "raw.toml")).calibration
    assert (raw.features, raw.smoothing) == ("raw", 0.0)                             # the paper's map
    poses = family(scene, "training")
    assert [p.name for p in poses][:2] == ["training_0", "training_1"]
    assert dict(poses[2].generator_parameters)["radius_mm"] == 50.0
    y, dim = targets(scene, "sequence")
    assert dim == 3 and y.shape == (9, 3 * len(scene.poses[1].object.rest.uv))
    assert load_scene(write_scene(calibration_scene(), "plain.toml")).calibration is not None


def test_a_sequence_mostly_outside_the_training_ranges_is_warned_about(write_scene, caplog):
    """Two of nine sequence poses below the range (above): read quietly. Six of nine
    (radius 26-38.75 mm against a training range from 40 mm): the warning names the file,
    the counts and the ranges (pneumatic_quick narrowed, all 16 outside, read worse with
    every optimised k = 2 design than with its start: docs/results.md)."""
    import logging

    with caplog.at_level(logging.WARNING, logger="mscap.scene.calibration"):
        load_scene(write_scene(calibration_scene()))
        assert not caplog.records
        path = write_scene(calibration_scene(training={"radius_mm": [40.0, 80.0, 5]},
                                             sequence={"steps": 4, "radius_mm": [50.0, 35.0, 26.0]}), "out.toml")
        scene = load_scene(path)
    assert (~scene.calibration.in_range).sum() == 6  # 38.75 … 26 mm
    (record,) = caplog.records
    assert str(path) in record.getMessage()
    assert "6 of the 9 [calibration.sequence] poses lie outside" in record.getMessage()
    assert "radius_mm 40..80" in record.getMessage()



@pytest.mark.parametrize("change, key, message", [
    ({"pose": "nope"}, "calibration.pose", "no pose named 'nope'"),
    ({"pose": "rest"}, "calibration.pose", "no number parameters"),
    ({"training": {"depth": [1.0, 2.0, 3]}}, "calibration.training.depth", "no number parameter 'depth'"),
    ({"training": {"radius_mm": [30.0, 80.0]}}, "calibration.training.radius_mm", "[start, stop, count]"),
    ({"training": {"radius_mm": [30.0, 80.0, 2.5]}}, "calibration.training.radius_mm", "integer count"),
    ({"sequence": {"radius_mm": [30.0], "radius": [1.0]}}, "calibration.sequence.radius", "not a parameter"),
    ({"training": {"radius_mm": [10.0, 80.0, 3]}}, "calibration.training.radius_mm", "at {'radius_mm': 10.0}"),
    ({"kernel": "spline"}, "calibration.kernel", "unknown RBF kernel"),
    ({"target": "pixels"}, "calibration.target", "unknown value"),
    ({"features": "pca"}, "calibration.features", "expected one of whitened, raw"),
    ({"min_spread": -1.0}, "calibration.min_spread", ">= 0"),
    ({"noise": {"additive_pF": 0.0}, "reference": "rest"}, "calibration.features", "use features = 'raw'"),
    ({"noise": {"relative_shift": 1.5}}, "calibration.noise.relative_shift", "must be < 1"),
    ({"noise": {"runs": 10, "sed": 1}}, "calibration.noise.sed", "did you mean 'seed'"),
])
def test_calibration_section_errors_name_the_key(write_scene, change, key, message):
    with pytest.raises(SceneError) as info:
        load_scene(write_scene(calibration_scene(**change)))
    assert info.value.key == key and message in str(info.value)


def test_physics_hash_ignores_the_calibration_section(write_scene):
    a = load_scene(write_scene(calibration_scene(), "a.toml"))
    other = calibration_scene(noise={"runs": 7, "seed": 4}, kernel="cubic")
    other |= {"optimizer": {"distance": "noise"}, "multistart": {"k_max": 3}, "description": "x"}
    b = load_scene(write_scene(other, "b.toml"))
    assert physics_sha256(a) == physics_sha256(b)
    assert a.calibration.family_sha256() == b.calibration.family_sha256()
    c = calibration_scene()
    c["materials"]["clear"]["youngs_modulus_MPa"] = 0.6
    assert physics_sha256(load_scene(write_scene(c, "c.toml"))) != physics_sha256(a)


# ---------------------------------------------------------------- pipeline
class _OneRank:
    """A stand-in communicator: one rank, no MPI calls."""

    def Get_rank(self):
        return 0

    def Get_size(self):
        return 1

    def bcast(self, value, root=0):
        return value


def designs(scene):
    base = tuple(np.array(o) for o in scene.layout.outlines)
    return [Candidate("given", base), Candidate("moved", (base[0] + [1.0, 0.0], base[1] - [1.0, 0.0]))]


def test_noise_free_reconstruction_is_exact_on_training_poses(write_scene, tmp_path):
    """Sequence = the training grid, no noise: every vertex comes back to round-off."""
    scene = load_scene(write_scene(calibration_scene(sequence={"steps": 5, "radius_mm": [30.0, 80.0]})))
    np.testing.assert_allclose(scene.calibration.sequence, scene.calibration.training)
    ds = designs(scene)[:1]
    simulate_family(scene, ds, tmp_path / "cache.h5", _OneRank())
    (s,) = evaluate(scene, ds, tmp_path / "cache.h5", NoiseModel(0.0, 0.0, runs=2))
    assert s.errors.max.max() < 1e-6                       # mm
    assert s.no_signal.max() > 0.1                          # the poses do differ (mm)


def test_a_reference_pose_cancels_the_per_run_shift(write_scene, tmp_path):
    """Read-outs divided by the rest pose's, read in the same run: a purely multiplicative
    per-run shift cancels exactly, so the training poses come back to round-off, while
    the raw read-outs are off by millimetres."""
    scene = load_scene(write_scene(calibration_scene(reference="rest",
                                                     sequence={"steps": 5, "radius_mm": [30.0, 80.0]})))
    assert scene.calibration.reference == "rest"
    ds = designs(scene)[:1]
    lines = []
    simulate_family(scene, ds, tmp_path / "c.h5", _OneRank(), progress=lines.append)
    assert "+ reference pose rest); 13 poses to simulate" in lines[0]      # 6 + 6 + 1
    shift_only = NoiseModel(relative_shift=0.15, additive_pF=0.0, runs=20)
    (tared,) = evaluate(scene, ds, tmp_path / "c.h5", shift_only)
    assert tared.errors.max.max() < 1e-6
    raw_scene = dataclasses.replace(scene, calibration=dataclasses.replace(scene.calibration, reference=None))
    (raw,) = evaluate(raw_scene, ds, tmp_path / "c.h5", shift_only)
    assert raw.errors.mean.mean() > 0.1                           # mm
    with pytest.raises(SceneError, match="calibration.reference: no pose named 'flat'"):
        load_scene(write_scene(calibration_scene(reference="flat"), "bad.toml"))


def test_cache_is_reused_extended_and_survives_a_noise_change(write_scene, tmp_path):
    # The raw map: on this small sheet the untared read-outs vary over the family by less
    # than half the per-run shift's spread, so the whitened map answers the mean pose
    # whatever the additive noise (test_reconstruction.py covers that).
    scene = load_scene(write_scene(calibration_scene(features="raw")))
    cache = tmp_path / "cache.h5"
    lines = []
    ds = designs(scene)
    simulate_family(scene, ds[:1], cache, _OneRank(), progress=lines.append)
    assert "15 poses to simulate" in lines[0]
    lines.clear()
    simulate_family(scene, ds, cache, _OneRank(), progress=lines.append)     # only the new design
    assert "15 poses to simulate" in lines[0] and all("given" not in line for line in lines[1:])
    with h5py.File(cache) as f:
        groups = {f["designs"][g].attrs["label"]: f["designs"][g] for g in f["designs"]}
        assert set(groups) == {"given", "moved"}
        c = groups["given"]["training_capacitance_pF"][()]
        assert np.isfinite(c).all() and c.shape == (6, 2)
        # a smaller dome radius stretches the sheet more: capacitance grows (plate area ~ λ²/λ_z)
        assert np.all(np.diff(c, axis=0) < 0)
    lines.clear()
    renoised = load_scene(write_scene(calibration_scene(noise={"runs": 5, "additive_pF": 0.5}, features="raw"),
                                      "n.toml"))
    simulate_family(renoised, ds, cache, _OneRank(), progress=lines.append)
    assert "0 poses to simulate" in lines[0]
    quiet, loud = (evaluate(renoised, ds, cache), evaluate(scene, ds, cache))
    assert quiet[0].errors.mean.shape == (5, 9) and loud[0].errors.mean.shape == (20, 9)
    assert np.nanmean(quiet[0].errors.mean) < np.nanmean(loud[0].errors.mean)
    stiffer = calibration_scene()
    stiffer["materials"]["clear"]["youngs_modulus_MPa"] = 0.6
    lines.clear()
    simulate_family(load_scene(write_scene(stiffer, "s.toml")), ds[:1], cache, _OneRank(), progress=lines.append)
    assert "15 poses to simulate" in lines[0]                  # other physics: cache started over


def test_a_cache_held_elsewhere_or_behind_a_link_is_refused_untouched(write_scene, tmp_path):
    """The cache is opened like a results file (mscap.outfile): a cache another
    process writes is refused before anything is truncated, and a link is never followed."""
    from mscap.errors import MscapError
    from mscap.outfile import WriteLock

    scene = load_scene(write_scene(calibration_scene()))
    held = tmp_path / "held.h5"
    held.write_bytes(b"another job's cache")
    other = WriteLock(held)  # its own open file: the lock of another writer
    try:
        with pytest.raises(MscapError, match="open for writing in another process"):
            simulate_family(scene, designs(scene)[:1], held, _OneRank())
    finally:
        other.close()
    assert held.read_bytes() == b"another job's cache"
    target = tmp_path / "target.txt"
    target.write_text("keep")
    (tmp_path / "link.h5").symlink_to(target)
    with pytest.raises(MscapError, match="symbolic link"):
        simulate_family(scene, designs(scene)[:1], tmp_path / "link.h5", _OneRank())
    assert target.read_text() == "keep"


def test_a_failing_pose_is_nan_and_left_out(write_scene, tmp_path, monkeypatch):
    import mscap.fem.simulate as simulate_module
    from mscap.errors import MscapError

    real = simulate_module.simulate

    def flaky(scene, **kwargs):
        if any(p.name == "training_2" for p in kwargs.get("poses") or scene.poses):
            raise MscapError("pose training_2, load step 1: residual 1e3 (forced)")
        return real(scene, **kwargs)

    monkeypatch.setattr(simulate_module, "simulate", flaky)
    scene = load_scene(write_scene(calibration_scene()))
    ds = designs(scene)[:1]
    simulate_family(scene, ds, tmp_path / "c.h5", _OneRank())
    with h5py.File(tmp_path / "c.h5") as f:
        g = f["designs"][ds[0].key]
        c = g["training_capacitance_pF"][()]
        assert np.isnan(c[2]).all() and np.isfinite(np.delete(c, 2, axis=0)).all()
        assert g["training_done"][()].all()
    (s,) = evaluate(scene, ds, tmp_path / "c.h5")
    assert s.training_failed == 1 and s.training_used == 5 and np.isfinite(s.errors.mean).all()


def test_parameter_targets_for_a_poke_family(write_scene, tmp_path):
    d = copy.deepcopy(SMALL_SCENE)
    d["poses"] = [{"name": "rest", "kind": "free"},
                  {"name": "poke", "kind": "poke", "center_mm": [8.0, 10.0], "radius_mm": 4.0,
                   "depth_mm": 1.0, "held_edges": ["x_min", "x_max"]}]
    d["calibration"] = {"pose": "poke", "training": {"depth_mm": [0.5, 2.0, 4]},
                        "sequence": {"steps": 3, "depth_mm": [0.5, 2.0]}}
    scene = load_scene(write_scene(d))
    assert scene.calibration.target == "parameters"
    ds = designs(scene)[:1]
    simulate_family(scene, ds, tmp_path / "c.h5", _OneRank())
    (s,) = evaluate(scene, ds, tmp_path / "c.h5", NoiseModel(0.0, 0.0, runs=1))
    assert s.errors.max.max() < 1e-9                        # depth (mm) back exactly


# ---------------------------------------------------------------- command line
def results_file(scene, path: Path) -> None:
    base = tuple(np.array(o) for o in scene.layout.outlines)
    record = RunRecord(k=2, seed=0, init="lloyd", status="ok", poses=("rest", "dome"),
                       initial_outlines=(base[0] + [1.0, 0.0], base[1] - [1.0, 0.0]), final_outlines=base,
                       initial_capacitance_pF=np.ones((2, 2)), final_capacitance_pF=np.array([[1.0, 2.0], [3.0, 5.0]]))
    with open_store(path, scene, force=True) as f:
        write_run(f, record)


def mscap(*args, mpi: int = 0, cwd=None):
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    command = [str(Path(sys.executable).with_name("mscap")), *map(str, args)]
    if mpi:
        command = ["mpirun", "-n", str(mpi), "--oversubscribe", *command]
    return subprocess.run(command, capture_output=True, text=True, env=env, cwd=cwd or ROOT, timeout=300)


def test_cli_writes_errors_summary_and_figure_and_mpi_matches_serial(write_scene, tmp_path):
    path = write_scene(calibration_scene())
    scene = load_scene(path)
    results_file(scene, tmp_path / "r.h5")
    serial = mscap("calibrate", path, "--design", tmp_path / "r.h5", "--baseline", "initial", "--runs", "10")
    assert serial.returncode == 0, serial.stderr
    assert "k2_s0000_lloyd (optimised)" in serial.stdout and "k2_s0000_lloyd:initial" in serial.stdout
    out = tmp_path / "r_calibration"
    summary = json.loads((out / "summary.json").read_text())
    assert [d["label"] for d in summary["designs"]] == ["k2_s0000_lloyd (optimised)", "k2_s0000_lloyd:initial"]
    assert summary["noise"]["runs"] == 10 and summary["out_of_range_poses"] == 2
    assert summary["features"] == "whitened" and summary["min_spread"] == 0.5
    assert all(len(d["spread_noise_std"]) == 2 and 0 <= d["directions"] <= 2 for d in summary["designs"])
    raw = mscap("calibrate", path, "--design", tmp_path / "r.h5", "--runs", "10", "--features", "raw",
                "-o", tmp_path / "raw")                                 # the cached simulations, re-scored
    assert raw.returncode == 0, raw.stderr
    raw_summary = json.loads((tmp_path / "raw" / "summary.json").read_text())
    assert (raw_summary["features"], raw_summary["smoothing"], raw_summary["min_spread"]) == ("raw", 0.0, None)
    assert all(d["spread_noise_std"] is None and d["directions"] == 2 for d in raw_summary["designs"])
    assert "0 poses to simulate" in raw.stdout + raw.stderr
    rows = (out / "errors.csv").read_text().splitlines()
    assert rows[0].startswith("design,k,pose,radius_mm,in_training_range,mean_error") and len(rows) == 1 + 2 * 9
    assert (out / "errors.png").stat().st_size > 10_000

    parallel = mscap("calibrate", path, "--design", tmp_path / "r.h5", "--cache", tmp_path / "p.h5",
                     "-o", tmp_path / "p", "--runs", "10", mpi=3)
    assert parallel.returncode == 0, parallel.stderr
    with h5py.File(tmp_path / "r_calibration.h5") as a, h5py.File(tmp_path / "p.h5") as b:
        for key in a["designs"]:
            for which in ("training", "sequence"):
                np.testing.assert_allclose(b["designs"][key][f"{which}_capacitance_pF"][()],
                                           a["designs"][key][f"{which}_capacitance_pF"][()], rtol=1e-9)
    assert (tmp_path / "p" / "errors.csv").read_text() == (out / "errors.csv").read_text()


def test_cli_errors(write_scene, tmp_path):
    d = calibration_scene()
    del d["calibration"]
    plain = write_scene(d, "plain.toml")
    results_file(load_scene(plain), tmp_path / "r.h5")
    result = mscap("calibrate", plain, "--design", tmp_path / "r.h5")
    assert result.returncode == 2 and "no [calibration] section" in result.stderr
    path = write_scene(calibration_scene())
    result = mscap("calibrate", path, "--design", f"{tmp_path / 'r.h5'}:k9_s0000_lloyd")
    assert result.returncode == 2 and "no run 'k9_s0000_lloyd'" in result.stderr
    other = calibration_scene()
    other["name"] = "other"
    result = mscap("calibrate", write_scene(other, "o.toml"), "--design", tmp_path / "r.h5")
    assert result.returncode == 2 and "holds results of scene 'small'" in result.stderr
    result = mscap("calibrate", path, "--design", tmp_path / "r.h5", "--smoothing", "-1")
    assert result.returncode == 2 and "--smoothing must be >= 0, got -1.0" in result.stderr


def test_cli_takes_an_optimize_directory(write_scene, tmp_path):
    """`mscap optimize` output (outlines.json, summary.json) as the design; `initial` is
    rebuilt from its (k, seed, init), here the scene's own layout."""
    path = write_scene(calibration_scene())
    scene = load_scene(path)
    run = tmp_path / "opt"
    run.mkdir()
    moved = [np.array(o) + [0.5, 0.0] for o in scene.layout.outlines]
    (run / "outlines.json").write_text(json.dumps({"outlines_mm": [o.tolist() for o in moved]}))
    (run / "summary.json").write_text(json.dumps({"k": 2, "seed": 0, "init": "scene"}))
    result = mscap("calibrate", path, "--design", run, "--runs", "5")
    assert result.returncode == 0, result.stderr
    summary = json.loads((run / "calibration" / "summary.json").read_text())
    assert [d["label"] for d in summary["designs"]] == ["opt (optimised)", "scene layout"]
    assert (run / "calibration.h5").exists()
    bad = mscap("calibrate", path, "--design", run, "--baseline", "k2_s0000_lloyd")
    assert bad.returncode == 2 and "only the baselines 'initial' and 'scene'" in bad.stderr
