"""``mscap calibrate`` checks its arguments before it simulates the pose family (issue
21: ``--runs -5`` was refused only after the whole family had been simulated, 87 s on
the glove), and a scene's noise and family sizes are bounded at load."""

from __future__ import annotations

import pytest

from mscap.cli import main
from mscap.errors import SceneError
from mscap.scene import load_scene
from tests.calibration.test_calibration import calibration_scene


@pytest.mark.parametrize("option, value, words", [
    ("--runs", "-5", "runs must be in 1..1000000, got -5"),
    ("--relative-shift", "nan", "relative shift must be in [0, 1), got nan"),
    ("--additive-pF", "inf", "additive noise must be finite and >= 0 pF, got inf"),
    ("--seed", "-1", "seed must be in 0..4294967295, got -1"),
])
def test_bad_noise_options_stop_before_any_simulation(write_scene, tmp_path, capsys, option, value, words):
    # The design file does not exist: before the fix the command got as far as reading it
    # (and with a real one, through the whole family) before looking at the noise options.
    scene = write_scene(calibration_scene())
    assert main(["calibrate", str(scene), "--design", str(tmp_path / "missing.h5"), "-q", option, value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err


@pytest.mark.parametrize("change, key, words", [
    ({"noise": {"runs": 10**9}}, "calibration.noise.runs", "must be <= 1e+06"),
    ({"noise": {"seed": 2**40}}, "calibration.noise.seed", "must be <= 4.29497e+09"),
    ({"sequence": {"steps": 10**9, "radius_mm": [80.0, 35.0]}}, "calibration.sequence.steps", "must be <= 10000"),
    ({"sequence": {"radius_mm": [80.0, float("nan")]}}, "calibration.sequence.radius_mm", "finite numbers"),
    ({"training": {"radius_mm": [30.0, float("inf"), 3]}}, "calibration.training.radius_mm", "finite numbers"),
])
def test_family_and_noise_sizes_are_bounded(write_scene, change, key, words):
    path = write_scene(calibration_scene(**change))
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f"{path}: {key}: ") and words in str(info.value), str(info.value)
