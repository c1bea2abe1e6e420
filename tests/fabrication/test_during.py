"""Routing during the optimisation (mscap.fabrication.during): J of the routed sensor,
C_plates(q) + the leads' share at the last route, its gradient by the same adjoints
(Taylor rate 2 with the share in), the share swapped without a solve, and a short
optimisation that routes at its start and end, through the command line."""

from __future__ import annotations

import copy
import dataclasses
import json
import logging

import numpy as np
import pytest

from mscap.cli import main
from mscap.design.optimizer import optimize
from mscap.design.pipeline import build_design
from mscap.errors import FabricationError
from mscap.fabrication.during import WiringOffset, wiring_offset
from mscap.scene import load_scene
from mscap.testing import taylor_test
from tests.conftest import to_toml
from tests.scenes import scene_dict

pytest.importorskip("igl")

# The small scene's two plates 4 mm higher on a 30 x 24 mm sheet, room for the pads below
# them (tests/fabrication/test_wired.py), at rest and pulled 20 %, clamped.
PLATES = {"min_gap_mm": 1.0, "outlines_mm": [[[3.0, 8.0], [13.0, 8.0], [13.0, 20.0], [3.0, 20.0]],
                                             [[17.0, 9.0], [27.0, 9.0], [25.0, 19.0], [19.0, 20.0]]]}
ROUTED = scene_dict(sheet={"width_mm": 30.0, "height_mm": 24.0}, capacitors=PLATES,
                    poses=[{"name": "rest", "kind": "free"},
                           {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"}],
                    mesh={"edge_length_mm": 3.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 3.0},
                    optimizer={"control_spacing_mm": 6.0},
                    fabrication={"route_during_optimisation": True, "assignments": 2})


@pytest.fixture(scope="module")
def scene_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("during") / "routed.toml"
    path.write_text(to_toml(copy.deepcopy(ROUTED)))
    return path


@pytest.fixture(scope="module")
def design(scene_path):
    scene = load_scene(scene_path)
    # A tight Newton tolerance: the differences below resolve J to ~1e-12.
    return build_design(dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, tolerance=1e-12)))


def test_the_leads_share_is_what_routing_adds_and_is_swapped_without_a_solve(design):
    q0 = 0.05 * np.random.default_rng(3).uniform(-1, 1, (design.n_controls, 2))
    plates = design.evaluate(q0)
    routed = design.rerouted(q0)
    share = routed.wiring.offset_pF
    assert share.shape == plates.capacitance_pF.shape
    # A 2 x 1 array without a crossing: the leads only fringe into the other layer's plates
    # and leads, 0.2-1.3 % of a reading (column C0's lead runs past R1's plate).
    assert np.all(share > 0) and np.all(share < 0.02 * plates.capacitance_pF)
    np.testing.assert_array_equal(share, wiring_offset(design.scene, design.sheet, design.deformer.outlines(q0),
                                                       poses=design.poses).offset_pF)
    e = routed.evaluate(q0, warm=plates)
    np.testing.assert_allclose(e.capacitance_pF - e.offset_pF, plates.capacitance_pF, rtol=1e-9)
    swapped = routed.reevaluated(plates)  # the plates' solve, the share put in: the same J
    assert swapped.J == pytest.approx(e.J, rel=1e-9) and swapped.sim is plates.sim
    np.testing.assert_allclose(swapped.dJ_dC, e.dJ_dC, rtol=1e-7, atol=1e-12)
    assert design.reevaluated(swapped).J == pytest.approx(plates.J, rel=1e-12)  # and out again


def test_the_gradient_with_the_leads_share_in_passes_the_taylor_test(design):
    rng = np.random.default_rng(5)
    q0 = 0.05 * rng.uniform(-1, 1, (design.n_controls, 2))
    plates = design.evaluate(q0)
    # A share as large as a crossing's, different per pose and capacitor: ∂J/∂C moves with it.
    share = plates.capacitance_pF * np.array([[0.03, 0.08], [0.12, -0.05]])
    routed = dataclasses.replace(design, wiring=WiringOffset(share, "test", 0.0))
    base = routed.evaluate(q0, warm=plates)
    grad = routed.gradient(base)
    assert np.abs(grad - design.gradient(design.evaluate(q0, warm=plates))).max() > 0.05 * np.abs(grad).max()
    delta = rng.uniform(-1, 1, grad.shape)
    taylor = taylor_test(lambda q: routed.evaluate(q, warm=base).J, q0, delta, grad, value=base.J,
                         h0=0.02, halvings=4)
    np.testing.assert_allclose(taylor.rates, 2.0, atol=0.2, err_msg=str(taylor))


def test_an_unroutable_design_keeps_the_last_share_and_says_so(design, monkeypatch, caplog):
    def unroutable(*args, **kwargs):
        raise FabricationError("capacitor 1 is blocked")

    monkeypatch.setattr("mscap.fabrication.during.wiring_offset", unroutable)
    with caplog.at_level(logging.WARNING):
        assert design.rerouted(design.deformer.zeros()) is design
    assert "capacitor 1 is blocked; J keeps the plates alone" in caplog.text


def test_an_optimisation_routes_at_its_start_and_end(scene_path):
    result = optimize(build_design(load_scene(scene_path)), max_iterations=2, cascade_levels=0)
    events = [r.event for r in result.reroutes]
    assert events[0] == "start" and events[-1] == "end"
    start = result.reroutes[0]
    assert start.J_before != start.J_after and start.J_after == result.history[0].J
    # The last evaluation is the routed sensor's at the final outlines.
    final = result.evaluation
    share = wiring_offset(result.design.scene, result.design.sheet, result.design.deformer.outlines(final.q),
                          poses=result.design.poses).offset_pF
    np.testing.assert_allclose(final.offset_pF, share, rtol=1e-12)
    assert result.history[-1].J == final.J == result.reroutes[-1].J_after


def test_the_command_reports_each_route(scene_path, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["optimize", str(scene_path), "--max-iterations", "1", "--cascade", "0", "-o", str(out),
                 "--no-figure"]) == 0
    assert "rerouted (start)" in capsys.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert [r["event"] for r in summary["reroutes"]] == ["start", "end"]
    assert summary["final_J"] == summary["reroutes"][-1]["J_after"]
    assert "2 x 1 array" in summary["reroutes"][0]["summary"]


def test_a_routed_start_checks_its_plates_on_the_finer_mesh_and_keeps_the_share(scene_path):
    """A multi-start run stores the routed sensor's capacitances; its finer-mesh check
    re-simulates the plates, so the leads' share is taken out before the comparison and
    put back into the finer capacitances: the estimated error is the plates'
    discretisation, as in the same start without routing (no step: the same layout)."""
    from mscap.service.multistart import run_check, run_start
    from mscap.service.selection import StartConfig

    scene = load_scene(scene_path)
    plain_scene = dataclasses.replace(scene, fabrication=dataclasses.replace(scene.fabrication,
                                                                             route_during_optimisation=False))
    routed, plain = (run_start(s, StartConfig(2, 0, "scene"), max_iterations=0) for s in (scene, plain_scene))
    assert routed.status == plain.status == "ok"
    share = routed.final_capacitance_pF - plain.final_capacitance_pF
    assert np.all(share > 0.001 * plain.final_capacitance_pF)
    np.testing.assert_allclose(routed.finer_capacitance_pF - routed.final_capacitance_pF,
                               plain.finer_capacitance_pF - plain.final_capacitance_pF, rtol=1e-6, atol=1e-9)
    # A check made later (a job resumed between a run and its check) routes the design again.
    unchecked = dataclasses.replace(routed, finer_capacitance_pF=np.full_like(routed.finer_capacitance_pF, np.nan))
    np.testing.assert_allclose(run_check(scene, unchecked).finer_capacitance_pF, routed.finer_capacitance_pF,
                               rtol=1e-6)
