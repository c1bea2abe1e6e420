"""Designing for read-back (mscap.design.readback): the noise of each read-out protocol against
Monte Carlo draws of appendix A's noise, the Cramér–Rao bound against closed forms, Taylor
tests of every term, the family sub-grid of the quick scenes, the selection by bound and
the errors that name the key."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from mscap.scene.calibration import NoiseModel
from mscap.errors import GeometryError, SceneError
from mscap.design.objective import PlateAreaBarrier, capacitance_term
from mscap.design.readback import (DesignFamily, ProtocolDissimilarity, ReconstructionBound, _difference_matrix,
                            design_poses, grid_derivatives, difference_variance, reading_variance)
from mscap.scene import load_scene
from mscap.service.selection import RunSummary, select
from tests.scenes import check_gradient

NOISE = NoiseModel(relative_shift=0.15, additive_pF=2.0)


# --- the noise of each protocol (docs/optimize.md derives these) ------------------------

def draw(c, ref, n, seed):
    """n runs of raw readings of poses ``c`` (k,) each and of the reference, one run's
    shift shared by both (appendix A)."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.85, 1.15, (n, 1))
    noise = lambda: rng.uniform(-2.0, 2.0, (n, len(c)))  # noqa: E731
    return s * c + noise(), s * ref + noise(), s * c + noise()


def test_tared_and_raw_variances_match_monte_carlo():
    c = np.array([30.0, 60.0, 150.0])
    ref = np.array([55.0, 70.0, 120.0])
    n = 400_000
    a, r, b = draw(c, ref, n, 0)
    # Raw: Var(sC + n) = h²C²/3 + σ² exactly; tared: first order in σ/C_ref, E[1/s²] exact.
    raw = reading_variance(c, None, NOISE)[0]
    np.testing.assert_allclose(a.var(axis=0), raw, rtol=0.01)
    rho = c / ref
    tared = reading_variance(rho, ref, NOISE)[0]
    np.testing.assert_allclose((a / r).var(axis=0), tared, rtol=0.02)
    # A difference of two poses read in one run, against one reference reading.
    c2 = c * np.array([1.1, 0.7, 1.3])
    _, _, b = draw(c2, ref, n, 0)
    a, r, _ = draw(c, ref, n, 0)
    v_raw = difference_variance(c - c2, None, NOISE)[0]
    np.testing.assert_allclose((a - b).var(axis=0), v_raw, rtol=0.01)
    v_tared = difference_variance(rho - c2 / ref, ref, NOISE)[0]
    np.testing.assert_allclose((a / r - b / r).var(axis=0), v_tared, rtol=0.02)
    # The per-run shift cancels when tared: bigger plates give less noise in ratio units.
    assert reading_variance(1.0, np.array(200.0), NOISE)[0] < reading_variance(1.0, np.array(20.0), NOISE)[0]


# --- terms: closed forms and Taylor tests -----------------------------------------------

def synthetic_family(reference_row, rng, counts=(3, 2)):
    axes = tuple(np.linspace(0.0, 1.0 + i, n) for i, n in enumerate(counts))
    values = np.array(list(itertools.product(*axes)))
    n, p = len(values), len(axes)
    g = rng.standard_normal((n, p, 6))
    rows = np.arange(n) + (reference_row is not None)
    return DesignFamily(tuple("ab"[:p]), axes, values, rows, reference_row, grid_derivatives(axes),
                        np.einsum("gpo,gqo->gpq", g, g) / 2, np.array([0.7, 0.4][:p]), NOISE)


def test_difference_matrix_is_exact_on_linear_and_quadratic_data():
    v = np.array([0.0, 1.0, 3.0, 4.5])
    np.testing.assert_allclose(_difference_matrix(v) @ (2 * v + 1), 2.0)
    # central differences of a quadratic are exact at the midpoint of the stencil
    d = _difference_matrix(np.array([0.0, 1.0, 2.0])) @ np.array([0.0, 1.0, 4.0])
    assert d[1] == pytest.approx(2.0)


def test_bound_of_a_one_parameter_sensor_is_the_closed_form():
    # One capacitor, C(θ) = 60 + 10 θ on θ ∈ {0, 1}, tared against C_ref = 50 pF:
    # ρ' = 10/50, Var ρ = σ²(1 + ρ²)/(C_ref²(1 − h²)), e = A/(ρ'²/Var + Λ).
    axes = (np.array([0.0, 1.0]),)
    fam = DesignFamily(("t",), axes, axes[0][:, None], np.array([1, 2]), 0, _difference_matrix(axes[0])[None],
                       np.full((2, 1, 1), 9.0), np.array([12.0]), NOISE)
    c = np.array([[50.0], [60.0], [70.0]])
    rho = np.array([1.2, 1.4])
    var = (4 / 3) * (1 + rho**2) / (50.0**2 * (1 - 0.15**2))
    expected = np.sqrt(9.0 / ((10 / 50) ** 2 / var + 12.0))
    np.testing.assert_allclose(ReconstructionBound(fam).per_pose_mm(c), expected, rtol=1e-12)
    # Nothing read: the prior alone, √(A / Λ): the training range's RMS spread.
    flat = np.array([[50.0], [60.0], [60.0]])
    np.testing.assert_allclose(ReconstructionBound(fam).per_pose_mm(flat), np.sqrt(9.0 / 12.0), rtol=1e-12)
    # The soft maximum lies between the mean and the max of the per-pose bounds.
    value = ReconstructionBound(fam, tau_mm=0.1).value(c)
    assert expected.mean() <= value <= expected.max()


@pytest.mark.parametrize("reference_row", [None, 0])
def test_reconstruction_bound_taylor(reference_row):
    rng = np.random.default_rng(3)
    fam = synthetic_family(reference_row, rng)
    c = 60 + 15 * rng.standard_normal((len(fam.values) + (reference_row is not None), 3))
    for tau in (0.05, 0.5):
        rates, error = check_gradient(ReconstructionBound(fam, tau), c, rng, 1.0, geometric=False)
        assert np.all(np.abs(rates - 2) < 0.2), rates
        assert error < 1e-6


@pytest.mark.parametrize("reference_row", [None, 2])
def test_protocol_dissimilarity_taylor_and_closed_form(reference_row):
    rng = np.random.default_rng(4)
    c = 60 + 10 * rng.standard_normal((6, 3))
    term = ProtocolDissimilarity(NOISE, reference_row, tau=0.5)
    rates, error = check_gradient(term, c, rng, 0.01, geometric=False)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6
    # two poses: the soft minimum of one pair is that pair's z²
    pair = c[:2] if reference_row is None else c[[0, 1, 2]]
    f = pair if reference_row is None else pair / pair[2]
    ref = None if reference_row is None else pair[2]
    d = f[0] - f[1]
    z2 = float(np.sum(d**2 / difference_variance(d, ref, NOISE)[0]))
    two = ProtocolDissimilarity(NOISE, None if reference_row is None else 2, tau=1e-9)
    assert two.value(pair) <= z2 + 1e-12


def test_plate_area_barrier_taylor_zero_far_and_infinite_at_the_budget():
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    triangle = np.array([[20.0, 0.0], [30.0, 0.0], [25.0, 8.0]])
    total = 100.0 + 40.0
    assert PlateAreaBarrier(total / 0.95).value([square, triangle]) > 0
    assert PlateAreaBarrier(total / 0.85).value([square, triangle]) == 0
    assert math.isinf(PlateAreaBarrier(total).value([square, triangle]))
    with pytest.raises(GeometryError, match="max_plate_area_mm2"):
        PlateAreaBarrier(total).value_and_gradient([square, triangle])
    # orientation does not matter
    assert PlateAreaBarrier(150.0).value([square[::-1], triangle]) == PlateAreaBarrier(150.0).value([square, triangle])
    rates, error = check_gradient(PlateAreaBarrier(150.0), [square, triangle[::-1]], np.random.default_rng(0), 0.5)
    assert np.all(np.abs(rates - 2) < 0.2), rates
    assert error < 1e-6


# --- the quick scenes' design poses -----------------------------------------------------

def quick(name):
    return load_scene(f"jobs/{name}_quick.toml")


def test_wrist_family_is_a_sub_grid_with_the_reference_and_exact_differences():
    scene = quick("wrist")
    designed = design_poses(scene)
    fam = designed.family
    assert [a.tolist() for a in fam.axes] == [[-25.0, 5.0, 40.0], [-15.0, 5.0, 20.0]]
    assert designed.names[0] == "rest" and fam.reference_row == 0
    assert designed.names[1] == "grid[flexion_deg=-25, deviation_deg=-15]"
    assert len(designed.poses) == 10 and sorted(fam.rows) == list(range(1, 10))
    assert len(scene.poses) == 9 and not hasattr(scene, "design_family")  # the scene stays as listed
    # the training grid's members: the sub-grid takes its first, middle and last values
    training = scene.calibration.training
    assert all(any(np.allclose(v, t) for t in training) for v in fam.values)
    # the difference operator is exact on data linear in the parameters
    linear = fam.values @ np.array([2.0, -3.0])
    np.testing.assert_allclose(fam.derivative[0] @ linear, 2.0)
    np.testing.assert_allclose(fam.derivative[1] @ linear, -3.0)


def test_equal_family_poses_share_a_row():
    # pneumatic: without a dent the ball's angle changes nothing, and the rest pose is the
    # uninflated one: 2 × 2 × 3 grid points, 2 × (1 + 3) distinct poses.
    designed = design_poses(quick("pneumatic"))
    assert len(designed.family.rows) == 12 and len(designed.poses) == 8
    assert designed.family.reference_row == 0
    # joystick: tilt 0 in any direction is the centre pose
    designed = design_poses(quick("joystick"))
    assert len(designed.family.rows) == 12 and len(designed.poses) == 9
    assert (designed.family.rows[:4] == designed.family.reference_row).all()


def test_family_settings_errors_name_the_key(tmp_path):
    scene = quick("wrist")
    opt = scene.optimizer
    with pytest.raises(SceneError, match="optimizer.family_grid"):
        design_poses(dataclasses.replace(scene, optimizer=dataclasses.replace(opt, family_grid=(1,))))
    with pytest.raises(SceneError, match="optimizer.family_grid.*only 8"):
        design_poses(dataclasses.replace(scene, optimizer=dataclasses.replace(opt, family_grid=(3, 9))))
    with pytest.raises(SceneError, match="optimizer.design_poses"):
        design_poses(dataclasses.replace(scene, calibration=None))
    with pytest.raises(SceneError, match="optimizer.design_poses: unknown value 'some'"):
        design_poses(dataclasses.replace(scene, optimizer=dataclasses.replace(opt, design_poses="some")))
    listed = dataclasses.replace(scene, optimizer=dataclasses.replace(opt, design_poses="listed"))
    with pytest.raises(SceneError, match='design_poses = "family"'):
        capacitance_term(listed)
    text = open("jobs/wrist_quick.toml").read().replace("family_grid = 3", "family_grid = [3, 2.5]")
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(SceneError, match="optimizer.family_grid: expected an integer"):
        load_scene(tmp_path / "bad.toml")


def test_noise_distance_uses_the_scene_protocol():
    # the wrist is tared against its rest pose: the listed poses' term divides by row 0
    scene = quick("wrist")
    listed = dataclasses.replace(scene, optimizer=dataclasses.replace(scene.optimizer, distance="noise",
                                                                      design_poses="listed"))
    term = capacitance_term(listed)
    assert isinstance(term, ProtocolDissimilarity) and term.reference_row == 0
    assert term.noise == scene.calibration.noise


# --- selection by the bound -------------------------------------------------------------

def test_selection_by_bound_picks_the_smallest_bound_and_its_plateau():
    runs = [RunSummary("k2_a", 2, True, 30.0, 1.0, bound_mm=0.80), RunSummary("k2_b", 2, True, 50.0, 1.0,
                                                                                 bound_mm=0.90),
            RunSummary("k3_a", 3, True, 10.0, 1.0, bound_mm=0.50), RunSummary("k4_a", 4, True, 60.0, 1.0,
                                                                                 bound_mm=0.49)]
    s = select(runs, 0.05, range(2, 5))
    assert s.by_bound and [k.best_run for k in s.per_k] == ["k2_a", "k3_a", "k4_a"]
    # k = 4 improves the bound by 2 % < 5 %: k = 3 is the plateau
    assert s.chosen_k == 3 and s.chosen_run == "k3_a" and s.per_k[1].best_bound_mm == 0.50
    # without bounds, the paper's rule on the metric
    plain = select([dataclasses.replace(r, bound_mm=math.nan) for r in runs], 0.05, range(2, 5))
    assert not plain.by_bound and plain.per_k[0].best_run == "k2_b" and plain.chosen_k == 4


def test_both_keeps_the_listed_poses_and_adds_the_new_grid_poses():
    # The wrist's listed poses include the four corners of the 3 × 3 grid (the design
    # poses' combinations) and the rest pose: 9 listed + 5 new grid poses.
    scene = quick("wrist")
    both = design_poses(dataclasses.replace(scene, optimizer=dataclasses.replace(scene.optimizer,
                                                                                 design_poses="both")))
    names = list(both.names)
    assert names[:9] == [p.name for p in scene.poses] and len(names) == 14
    fam = both.family
    assert fam.reference_row == 0
    corners = {names[fam.rows[i]] for i in (0, 2, 6, 8)}
    assert corners == {"extension_radial", "extension_ulnar", "flexion_radial", "flexion_ulnar"}


def test_a_poke_family_reconstructs_its_parameters():
    # A non-glue template: the target is the parameter itself, so G = 1 and the bound of a
    # perfectly read parameter is its Cramér–Rao standard deviation in mm of depth.
    from mscap.scene.calibration import CalibrationSettings

    scene = quick("poking")
    template, rest = scene.poses[1], scene.poses[0]
    depths = np.linspace(5.0, 13.0, 5)[:, None]
    cal = CalibrationSettings(pose=template.name, parameters=("depth_mm",), training=depths, sequence=depths,
                              in_range=np.ones(5, bool), target="parameters", reference=rest.name)
    opt = dataclasses.replace(scene.optimizer, distance="reconstruction", design_poses="family", family_grid=(3,))
    design = design_poses(dataclasses.replace(scene, calibration=cal, optimizer=opt))
    assert list(design.names) == [rest.name, "grid[depth_mm=5]", "grid[depth_mm=9]", "grid[depth_mm=13]"]
    assert [p.depth_mm for p in design.poses[1:]] == [5.0, 9.0, 13.0]
    np.testing.assert_allclose(design.family.sensitivity, 1.0)
    assert design.family.prior[0] == pytest.approx(12 / 8.0**2)


def test_a_calibrated_scene_designs_for_read_back_by_default(tmp_path):
    text = open("jobs/wrist_quick.toml").read()
    bare = text.replace('distance = "reconstruction"\n', "").replace('design_poses = "family"\n', "")
    (tmp_path / "bare.toml").write_text(bare)
    opt = load_scene(tmp_path / "bare.toml").optimizer
    assert (opt.distance, opt.design_poses) == ("reconstruction", "family")
    (tmp_path / "paper.toml").write_text(bare.replace("[optimizer]\n", '[optimizer]\ndistance = "pF"\n'))
    opt = load_scene(tmp_path / "paper.toml").optimizer
    assert (opt.distance, opt.design_poses) == ("pF", "listed")
    # without a [calibration] section the paper's objective stays the default
    assert quick("poking").optimizer.distance == "pF"
