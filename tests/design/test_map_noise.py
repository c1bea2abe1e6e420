"""The calibration map's noise as an objective term (mscap.design.readback.MapNoise and
ReadbackError): the closed form of an affine sensor, agreement with the noise of the map
`mscap calibrate` fits (mscap.calibration.reconstruction.fit) differentiated by central
differences, Taylor tests with and without a dropped direction, and the scene keys."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from mscap.calibration.reconstruction import fit
from mscap.design.objective import capacitance_term
from mscap.design.readback import (DesignFamily, MapNoise, ReadbackError, ReconstructionBound, design_poses,
                                   grid_derivatives, read_back_estimate, reading_variance)
from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.calibration import NoiseModel
from tests.scenes import check_gradient

NOISE = NoiseModel(relative_shift=0.15, additive_pF=2.0)


def family(values, rows, reference_row, x, dim=1):
    """A design family on ``values`` whose grid poses sit in ``rows`` with targets ``x``."""
    axes = tuple(np.unique(values[:, i]) for i in range(values.shape[1]))
    p, points = values.shape[1], x.shape[1] // dim
    derivative = grid_derivatives(axes)
    slope = np.einsum("pgh,ho->gpo", derivative, x)  # as design_poses makes the bound's sensitivity
    return DesignFamily(tuple("abc"[:p]), axes, values, np.asarray(rows), reference_row, derivative,
                        np.einsum("gpo,gqo->gpq", slope, slope) / points, np.full(p, 0.5), NOISE,
                        target_gram=x @ x.T / points)


def grid(counts):
    axes = [np.linspace(0.0, 1.0 + i, n) for i, n in enumerate(counts)]
    return np.array(list(itertools.product(*axes)))


def calibration_noise(c_rows, fam, x, dim, whitened, smoothing, min_spread, step=1e-5):
    """The per-grid-point squared noise of the map `mscap calibrate` fits on the grid
    (its features, whitening and merging), linearised by central differences."""
    ref = None if fam.reference_row is None else c_rows[fam.reference_row]
    f = c_rows[fam.rows] if ref is None else c_rows[fam.rows] / ref
    std = np.sqrt(reading_variance(f.mean(axis=0), ref, NOISE)[0]) if whitened else None
    model = fit(f, x, "thin_plate_spline", smoothing, std, min_spread)
    var = reading_variance(f, ref, NOISE)[0]
    total = np.zeros(len(f))
    for j in range(f.shape[1]):
        h = step * np.abs(f[:, j])
        up, down = f.copy(), f.copy()
        up[:, j] += h
        down[:, j] -= h
        dy = (model.predict(up) - model.predict(down)) / (2 * h[:, None])
        total += var[:, j] * (dy.reshape(len(f), -1, dim) ** 2).sum(axis=2).mean(axis=1)
    return total


@pytest.mark.parametrize("whitened", [True, False])
def test_an_affine_sensor_has_the_closed_form(whitened):
    # Tared features ρ = A θ + b: the spline reproduces an affine map exactly at any
    # smoothing, so ∂θ/∂ρ = A⁻¹ everywhere and E_g = Σ_j Var(ρ_gj) ‖A⁻¹[:, j]‖² / p.
    values = grid((3, 3))
    a = np.array([[0.30, -0.10], [0.05, 0.20]])
    ref = np.array([50.0, 80.0])
    rho = values @ a.T + np.array([1.0, 1.2])
    c = np.vstack([ref, rho * ref])
    fam = family(values, np.arange(1, 10), 0, values)
    term = MapNoise(fam, smoothing=1.0, whitened=whitened, min_spread=0.5)
    inverse = np.linalg.inv(a)
    var = reading_variance(rho, ref, NOISE)[0]
    expected = (var * (inverse**2).sum(axis=0)).sum(axis=1) / 2
    np.testing.assert_allclose(term.per_pose_mm(c) ** 2, expected, rtol=1e-9)
    assert term.value(c) == pytest.approx(math.sqrt(expected.mean()), rel=1e-9)


def nonlinear_rows(values, k, rng, reference=True):
    """Smooth, nonlinear capacitances (pF) of ``k`` plates over the grid, a reference row first."""
    w = rng.uniform(-1, 1, (values.shape[1], k))
    c = 60 + 20 * np.tanh(values @ w) + 5 * np.sin(values @ rng.uniform(-2, 2, (values.shape[1], k)))
    return np.vstack([np.full(k, 55.0), c]) if reference else c


@pytest.mark.parametrize("case", ["tared", "raw", "structural drop", "weak plate", "shared rows"])
def test_it_is_the_noise_of_the_map_calibrate_fits(case):
    rng = np.random.default_rng(7)
    counts, k, reference = {"structural drop": ((2, 2), 4, True)}.get(case, ((3, 3), 3, case != "raw"))
    values = grid(counts)
    c = nonlinear_rows(values, k, rng, reference)
    rows = np.arange(len(values)) + reference
    if case == "weak plate":  # the third plate reads almost the same everywhere: dropped
        c[1:, 2] = 60 + 1e-3 * rng.standard_normal(len(values))
    if case == "shared rows":  # the first axis's zero makes the second irrelevant (an inflation)
        rows = np.where(values[:, 0] == 0, 1, rows)
        c = c[: rows.max() + 1]
    dim = 3
    x = rng.standard_normal((len(values), 4 * dim)) + values[:, :1]  # vertex targets, 4 points
    if case == "shared rows":  # one pose, one target
        x[values[:, 0] == 0] = x[values[:, 0] == 0][0]
    fam = family(values, rows, 0 if reference else None, x, dim)
    whitened = case != "raw"
    term = MapNoise(fam, smoothing=1.0 if whitened else 0.0, whitened=whitened, min_spread=0.5)
    expected = calibration_noise(c, fam, x, dim, whitened, term.smoothing, 0.5)
    np.testing.assert_allclose(term.per_pose_mm(c) ** 2, expected, rtol=2e-6)


@pytest.mark.parametrize("case", ["tared", "raw", "structural drop", "weak plate"])
def test_map_noise_and_readback_error_taylor(case):
    rng = np.random.default_rng(11)
    counts, k = ((2, 2), 4) if case == "structural drop" else ((3, 2), 3)
    values = grid(counts)
    reference = case != "raw"
    c = nonlinear_rows(values, k, rng, reference)
    if case == "weak plate":
        c[1:, 2] = 60 + 0.05 * values[:, 0]  # spread ≈ 0.02 noise standard deviations
    x = rng.standard_normal((len(values), 6)) + values[:, :1]
    fam = family(values, np.arange(len(values)) + reference, 0 if reference else None, x, 3)
    noise = MapNoise(fam, smoothing=1.0 if reference else 0.0, whitened=reference)
    rates, error = check_gradient(noise, c, rng, 0.05, geometric=False)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6
    both = ReadbackError(ReconstructionBound(fam, 0.25), noise)
    rates, error = check_gradient(both, c, rng, 0.05, geometric=False)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert both.value(c) == pytest.approx(math.hypot(ReconstructionBound(fam, 0.25).value(c), noise.value(c)))


def test_a_map_that_reads_nothing_has_no_slope():
    values = grid((3, 2))
    c = np.vstack([np.full(2, 55.0), np.full((len(values), 2), 60.0) + 1e-4 * values])
    fam = family(values, np.arange(1, 7), 0, values)
    value, grad = MapNoise(fam).value_and_gradient(c)
    assert value == 0.0 and not grad.any()


def test_the_scene_key_and_its_errors(tmp_path):
    text = open("jobs/wrist_quick.toml").read().replace('distance = "reconstruction"', 'distance = "readback"')
    (tmp_path / "w.toml").write_text(text)
    scene = load_scene(tmp_path / "w.toml")
    estimate = read_back_estimate(scene)
    assert isinstance(estimate, ReadbackError) and isinstance(capacitance_term(scene).term, ReadbackError)
    assert capacitance_term(scene).weight == -1.0
    (tmp_path / "listed.toml").write_text(text.replace('design_poses = "family"', 'design_poses = "listed"'))
    with pytest.raises(SceneError, match=r"optimizer\.design_poses.*readback"):
        load_scene(tmp_path / "listed.toml")
    (tmp_path / "cubic.toml").write_text(text.replace("[calibration]\n", '[calibration]\nkernel = "cubic"\n'))
    with pytest.raises(SceneError, match=r"optimizer\.distance.*thin-plate spline.*cubic"):
        load_scene(tmp_path / "cubic.toml")
    # the scenes shipped with "reconstruction" keep the bound as their estimate
    assert isinstance(read_back_estimate(load_scene("jobs/wrist_quick.toml")), ReconstructionBound)


def test_a_readback_scene_is_scored_pruned_and_reported_in_mm(tmp_path):
    from mscap.service.heartbeat import Progress
    from mscap.service.pruning import goodness, score, score_kind

    text = open("jobs/wrist_quick.toml").read().replace('distance = "reconstruction"', 'distance = "readback"')
    (tmp_path / "w.toml").write_text(text)
    scene = load_scene(tmp_path / "w.toml")
    assert score_kind(scene) == "readback"
    # d = −readback (mm): the score is the readback itself, its goodness the precision 1/mm
    assert score("readback", J=0.7, d=-0.42, min_l1_pF=3.0) == pytest.approx(0.42)
    assert goodness("readback", 0.5) == pytest.approx(2.0)
    line = Progress("k2_s2000_lloyd", 2, 5, 3.0, 0.42, kind="readback").objective
    assert line == "read-back 0.42 mm (bound ⊕ map noise)"


def test_the_map_noise_jumps_where_a_direction_crosses_min_spread():
    """A second plate whose reading grows with the family at amplitude a: its direction's
    spread over the grid grows through min_spread = 0.5 noise standard deviations. Below,
    the map drops it; just above, it reads it at full slope, so one 2 % step of a more
    than doubles the map's noise, and the noise falls again as the direction grows: the
    wall that stops the optimiser (docs/results.md, "The bound ⊕ the map's noise as the
    objective"). Away from the crossing the term is smooth (steps below 10 %)."""
    rng = np.random.default_rng(2)
    values = grid((3, 3))
    c = nonlinear_rows(values, 2, rng)
    x = rng.standard_normal((len(values), 6)) + values[:, :1]
    fam = family(values, np.arange(1, 10), 0, x, 3)
    wiggle = np.sin(2 * values[:, 0]) + values[:, 1] ** 2
    term = MapNoise(fam, 1.0, True, 0.5)
    spreads, noise = [], []
    for a in 0.002 * 1.02 ** np.arange(200):
        rows = c.copy()
        rows[1:, 1] = 60 + a * 55 * wiggle
        f = rows[1:] / rows[0]
        std = np.sqrt(reading_variance(f.mean(axis=0), rows[0], NOISE)[0])
        z = (f - f.mean(axis=0)) / std
        spreads.append(np.sqrt(np.linalg.eigvalsh(z.T @ z / len(z))[0]))
        noise.append(term.value(rows))
    spreads, step = np.array(spreads), np.diff(np.log(noise))
    crossing = np.flatnonzero((spreads[:-1] < 0.5) & (spreads[1:] >= 0.5))
    assert len(crossing) == 1 and step[crossing[0]] > np.log(2), step[crossing]
    assert np.abs(np.delete(step, crossing)).max() < 0.1
    assert noise[-1] < noise[crossing[0] + 1] / 2            # and falls as the direction grows
