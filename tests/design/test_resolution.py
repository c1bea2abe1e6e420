"""The evaluation's error model (mscap.design.resolution): the calibrated pose errors at
their measured points, the signed first-order errors of J and of the min-L1 margin, the
rung a sized mesh was built on, the line-search guard on J + δJ and the report's verdict."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mscap.design.objective import Dissimilarity
from mscap.design.optimizer import _line_search
from mscap.design.resolution import ErrorModel, error_model, pose_error
from mscap.scene import load_scene, sizing
from mscap.scene.poses import FreePose, PokePose, StretchPose
from mscap.service.report import margin_resolution, resolution_text
from tests.conftest import to_toml
from tests.scenes import scene_dict

BALL = PokePose("p", (20.0, 20.0), 5.0, 4.0, ("x_min", "x_max"))


@pytest.mark.parametrize("element, radius, nu, measured", [
    # issue 44's 5 mm ball at a 5 mm edge against its limit 1.122 pF (docs/element_bias.csv,
    # docs/poke_zone_p2.csv: 1.5212, 1.2267, 1.1520 pF) and jobs/poking.toml's 10 mm balls
    # refined (4.965 against 4.874 pF)
    ("P1", 5.0, 0.47, 0.3558), ("P2", 5.0, 0.47, 0.0933), ("P2 refined", 5.0, 0.47, 0.0267),
    ("P2 refined", 10.0, 0.47, 0.0187),
])
def test_poke_errors_are_the_measured_ones(element, radius, nu, measured):
    ball = dataclasses.replace(BALL, radius_mm=radius)
    assert pose_error(ball, element, 5.0, nu) == pytest.approx(measured, rel=0.03)


def test_poke_errors_grow_with_nu_as_measured():
    """P1 +22 / +34 / +48 %, P2 +5.9 / +8.3 / +11.6 % at ν = 0.30 / 0.47 / 0.49 against
    P2 at 1.25 mm (docs/element_bias.csv): the ratios carry over."""
    for element, measured in (("P1", (0.2195, 0.3425, 0.4762)), ("P2", (0.0589, 0.0827, 0.1159))):
        modelled = [pose_error(BALL, element, 5.0, nu) for nu in (0.30, 0.47, 0.49)]
        np.testing.assert_allclose(np.array(modelled) / modelled[1], np.array(measured) / measured[1], rtol=0.02)


def test_pose_errors_shrink_with_the_edge_and_vanish_at_rest():
    """Finer under the ball, smaller bias, on both elements, down to the finest edge
    measured (0.25 R for P2), and no smaller below it; a free pose has none; a glued bend
    on P1 reads low (docs/element_bias.csv: −6.9 % at ν = 0.47)."""
    for element in ("P1", "P2"):
        errors = [pose_error(BALL, element, h, 0.47) for h in (8.0, 5.0, 3.0, 2.0, 1.25)]
        assert all(a > b > 0 for a, b in zip(errors, errors[1:])), errors
    assert pose_error(BALL, "P2", 0.6, 0.47) == pose_error(BALL, "P2", 1.25, 0.47) == pytest.approx(0.015)
    assert pose_error(FreePose("rest"), "P2", 5.0, 0.47) == 0.0
    glue = dataclasses.make_dataclass("Glue", [("kind", str)])("glue")
    assert pose_error(glue, "P1", 5.0, 0.47) == pytest.approx(-0.069)
    stretch = StretchPose("s", "uniaxial", (1.5, 1.0), "roller")
    assert pose_error(stretch, "P2 refined", 5.0, 0.47) == pose_error(stretch, "P2", 5.0, 0.47) == pytest.approx(0.0089)


def model(eps, rest=0):
    return ErrorModel(np.asarray(eps, dtype=float), None, 0.14, rest)


def test_two_poses_biased_alike_are_as_far_apart_relatively():
    """Gains over-read by ε each: their L1 distance over-reads by ε too (signed, not 2ε):
    it is (1 + ε) times its converged value, off by ε/(1 + ε) of itself."""
    rng = np.random.default_rng(3)
    c = 50 + rng.normal(size=(3, 4))
    l1 = np.abs(c[1] - c[2]).sum()
    assert l1 < np.abs(c[0] - c[1]).sum() and l1 < np.abs(c[0] - c[2]).sum()  # (1, 2) is the closest pair
    assert model([0.0, 0.08, 0.08]).margin_error(c, [None] * 4) == pytest.approx(0.08 / 1.08 * l1)
    eps = np.array([0.0, 0.08, 0.02]) / [1.0, 1.08, 1.02]
    g = c - c[0]
    expected = abs(np.sum(np.sign(c[1] - c[2]) * (eps[1] * g[1] - eps[2] * g[2])))
    assert model([0.0, 0.08, 0.02]).margin_error(c, [None] * 4) == pytest.approx(expected)


def test_J_error_is_the_first_order_change_of_J_under_the_bias():
    """δJ = |Σ ∂J/∂C b|: J at C − t b differs from J at C by t δJ + O(t²) (rate 2)."""
    rng = np.random.default_rng(7)
    c = 40 + rng.normal(size=(4, 3))
    term = Dissimilarity(0.5)
    m = model([0.0, 0.05, 0.12, 0.08])
    d, grad = term.value_and_gradient(c)
    bias = m.biases(c, [None] * 3)
    delta = m.J_error(grad, c, [None] * 3)
    remainders = [abs(d - term.value(c - t * bias) - t * delta) for t in (0.4, 0.2, 0.1, 0.05)]
    rates = np.log2(np.array(remainders[:-1]) / remainders[1:])
    assert np.all(rates > 1.9), rates


def test_a_sized_mesh_knows_its_rung_and_a_hand_set_one_does_not(tmp_path):
    data = scene_dict()
    data.pop("mesh", None)
    path = tmp_path / "sized.toml"
    path.write_text(to_toml(data))
    scene = load_scene(path)
    gap = scene.layers[2].thickness_mm
    _, chosen, _ = sizing.settings_for_tolerance(scene.mesh.tolerance, scene.layout.outlines, gap,
                                                 sum(layer.thickness_mm for layer in scene.layers))
    assert sizing.rung_of(scene.mesh, gap) == chosen
    m = error_model(scene.sheet, scene.elastic, scene.poses)
    f = m.plate_errors(scene.layout.outlines)
    np.testing.assert_allclose(f, sizing.predicted_errors(chosen, scene.layout.outlines, gap))
    assert sizing.rung_of(dataclasses.replace(scene.mesh, tolerance=None), gap) is None


def test_the_guard_halves_steps_that_buy_error(monkeypatch):
    """J(α) = 1 − 2α + 10α², δJ(α) = 0.1 + s α. With s = 1, α = 0.125 lowers J (Armijo)
    but J + δJ rises (1.131 > 1.1): halved, counted; 0.0625 lowers both. With s = 3, J + δJ
    rises for every α: no step, every J-decreasing trial counted."""
    from mscap.design import optimizer

    monkeypatch.setattr(optimizer, "feasible_step", lambda design, q, p, alpha: alpha)

    class Line:
        def __init__(self, slope):
            self.slope = slope

        def evaluate(self, q, warm=None):
            alpha = float(q[0, 0])
            return dataclasses.make_dataclass("E", [("J", float), ("error_J", float), ("q", object)], namespace={
                "release": lambda self: None})(1 - 2 * alpha + 10 * alpha ** 2, 0.1 + self.slope * alpha, q)

    start = dataclasses.make_dataclass("E", [("J", float), ("error_J", float), ("q", object)])(
        1.0, 0.1, np.zeros((1, 2)))
    g, p = np.array([[-2.0, 0.0]]), np.array([[1.0, 0.0]])
    accepted, alpha, trials, evaluations, inverted, unresolved = _line_search(Line(1.0), start, g, p, 1.0,
                                                                              resolve=True)
    assert (alpha, trials, unresolved) == (0.0625, 5, 1)
    assert _line_search(Line(1.0), start, g, p, 1.0)[1:] == (0.125, 4, 4, 0, 0)  # without the guard
    none = _line_search(Line(3.0), start, g, p, 1.0, resolve=True)
    # J decreases (Armijo) for α ≤ 0.125: 0.125, ..., 2^-7, five trials of the eight
    assert none[0] is None and none[5] == 5


def test_report_says_whether_the_margin_is_resolved():
    """Bias and remesh noise together against the margin; the noise is the largest jump
    of min L1 at a remesh (the same design on a fresh mesh)."""
    record = dataclasses.make_dataclass("R", [("metric", float), ("history", dict)])(0.67, {
        "event": ["start", "step", "remesh", "step", "remesh", "max_iterations"],
        "min_l1_pF": np.array([0.5, 0.6, 0.62, 0.66, 0.65, 0.67]),
        "margin_error_pF": np.array([0.04, 0.05, 0.05, 0.055, 0.055, 0.056])})
    metric, bias, noise = margin_resolution(record)
    assert (metric, bias) == (0.67, 0.056) and noise == pytest.approx(0.02)
    assert "): resolved" in resolution_text("k3_s1_lloyd", metric, bias, noise)
    assert "NOT resolved" in resolution_text("k3_s1_lloyd", 0.07, 0.056, 0.02)
    assert resolution_text("k3_s1_lloyd", 0.67, float("nan")) == ""
