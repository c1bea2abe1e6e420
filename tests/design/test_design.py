"""The design pipeline (mscap.design.pipeline): Taylor tests of the whole J(q) — dissimilarity of
the pose capacitances through the elastic adjoints, the barrier and the smoothing, all
through the skinning control — on coarse stretch, poke and glue scenes, once stiff
(ν = 0.499) and once at 100 % stretch; the elastic weights are the interpolated ones.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from mscap.design.history import min_pairwise_l1
from mscap.design.pipeline import build_design
from mscap.design.terms import Term
from mscap.scene import load_scene
from mscap.testing import taylor_test
from tests.conftest import to_toml
from tests.scenes import glue_scene, poke_scene_dict, scene_dict

pytest.importorskip("igl")

REST = {"name": "rest", "kind": "free"}


def stretch(ratio=1.2, nu=None):
    data = scene_dict(poses=[REST, {"name": "pull", "kind": "stretch", "mode": "uniaxial",
                                    "stretch": ratio, "grips": "clamp"}],
                      mesh={"edge_length_mm": 3.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 3.0})
    if nu is not None:
        for material in data["materials"].values():
            material["poisson_ratio"] = nu
    return data


def glue():
    data = glue_scene(1)
    data["poses"] = [REST] + data["poses"]
    return data


SCENES = {
    "stretch": stretch,
    "poke": poke_scene_dict,
    # the electrostatics on prisms (mscap.fem.wedge): their shape derivative in the chain
    "poke_prism": lambda: poke_scene_dict() | {"mesh": poke_scene_dict()["mesh"] | {"element": "prism"}},
    # P2 elasticity refined under the ball and along the held edges
    # (sizing.p2_poke_refinement), beside the tolerance-sized electrostatic mesh's zones
    "poke_p2_refined": lambda: {k: v for k, v in poke_scene_dict().items() if k != "mesh"}
    | {"elastic": {"order": 2, "edge_length_mm": 5.0}},
    "glue": glue,
    "stiff": lambda: stretch(1.2, 0.499),
    "extreme": lambda: stretch(2.0),
    # d in read-out noise units of read-outs tared against the rest pose
    # (readback.ProtocolDissimilarity; the calibration section names the protocol)
    "glue_noise": lambda: glue() | {"optimizer": {"distance": "noise", "tau_noise": 0.01},
                                    "calibration": {"pose": "bent", "reference": "rest",
                                                    "training": {"radius_mm": [15.0, 30.0, 4]},
                                                    "sequence": {"radius_mm": [18.0, 28.0]}}},
    # the read-back bound over a family of three bends, tared against the rest pose, with
    # the plate-area barrier active (the plate is ~50 mm², the budget 54 mm²)
    "glue_readback": lambda: glue() | {
        "optimizer": {"distance": "reconstruction", "design_poses": "family", "family_grid": 3,
                      "tau_mm": 0.05, "max_plate_area_mm2": 54.0},
        "calibration": {"pose": "bent", "reference": "rest", "training": {"radius_mm": [15.0, 30.0, 4]},
                        "sequence": {"radius_mm": [18.0, 28.0]}}},
    # the bound ⊕ the noise of the calibration's map fitted on the grid (readback.ReadbackError),
    # whose complex-step ∂/∂C meets the adjoints
    "glue_map_noise": lambda: glue() | {
        "optimizer": {"distance": "readback", "design_poses": "family", "family_grid": 3, "tau_mm": 0.05},
        "calibration": {"pose": "bent", "reference": "rest", "training": {"radius_mm": [15.0, 30.0, 4]},
                        "sequence": {"radius_mm": [18.0, 28.0]}}},
}


def load(data, tmp_path_factory, name):
    path = tmp_path_factory.mktemp("design") / f"{name}.toml"
    data = copy.deepcopy(data)
    data.setdefault("optimizer", {})["control_spacing_mm"] = 6.0
    path.write_text(to_toml(data))
    scene = load_scene(path)
    # A tight Newton tolerance: the differences below resolve J to ~1e-12.
    return dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, tolerance=1e-12))


@pytest.fixture(scope="module", params=list(SCENES))
def design(request, tmp_path_factory):
    scene = load(SCENES[request.param](), tmp_path_factory, request.param)
    return request.param, build_design(scene)


def test_elastic_weights_follow_the_fine_blend(design):
    name, d = design
    # The elastic mesh's 2D vertices move with the fine mesh's P1 blend: exact at shared
    # points (outline corners) and zero on the sheet edge.
    weights = d.elastic_weights
    assert weights is not None and weights.shape[1] == d.n_controls
    el = d.base.elastic.mesh.mesh2d.points
    lo, hi = el.min(axis=0), el.max(axis=0)
    edge = (np.abs(el - lo) < 1e-9).any(axis=1) | (np.abs(el - hi) < 1e-9).any(axis=1)
    assert np.abs(weights[edge]).max() < 1e-9
    assert weights.min() > -1e-12 and weights.sum(axis=1).max() < 1 + 1e-9


def test_whole_objective_taylor_and_central_differences(design):
    name, d = design
    rng = np.random.default_rng(5)
    q0 = 0.05 * rng.uniform(-1, 1, (d.n_controls, 2))
    base = d.evaluate(q0)
    grad = d.gradient(base)
    delta = rng.uniform(-1, 1, grad.shape)
    taylor = taylor_test(lambda q: d.evaluate(q, warm=base).J, q0, delta, grad, value=base.J,
                         h0=0.02, halvings=4, central_step=2e-5)
    remainders, steps, slope = taylor.second_order, taylor.steps, taylor.slope
    # The noise distance saturates once the poses differ by many noise widths (a pose pair's
    # z² tends to its bound C_ref²/Var), so its J is more curved than its slope: the
    # remainder at the smallest step is ~9 % of the first-order change there, at rate 2.
    relative = 0.15 if name == "glue_noise" else 0.05
    assert remainders[-1] < relative * abs(steps[-1] * slope), (name, str(taylor))
    np.testing.assert_allclose(taylor.rates, 2.0, atol=0.2, err_msg=f"{name}:\n{taylor}")
    assert slope == pytest.approx(taylor.central, rel=1e-5), name


def test_the_refined_p2_scene_is_refined(tmp_path_factory):
    from mscap.mesh.layered import elastic_sizes
    from mscap.scene.sizing import refines_pokes

    scene = load(SCENES["poke_p2_refined"](), tmp_path_factory, "refined")
    sizes = elastic_sizes(scene.sheet, scene.elastic, scene.poses)
    assert refines_pokes(scene.elastic, scene.mesh) and sizes.zones and sizes.strips


def test_min_pairwise_l1():
    c = np.array([[1.0, 2.0], [1.5, 2.0], [4.0, 0.0]])
    assert min_pairwise_l1(c) == pytest.approx(0.5)


def test_bad_optimizer_settings_name_the_key(tmp_path_factory):
    from mscap.errors import SceneError

    scene = load(stretch(), tmp_path_factory, "bad")
    bad = dataclasses.replace(scene, optimizer=dataclasses.replace(scene.optimizer, skinning="nope"))
    with pytest.raises(SceneError, match="optimizer.skinning"):
        build_design(bad)
    bad = dataclasses.replace(scene, optimizer=dataclasses.replace(scene.optimizer, first_step_mm=0.0))
    with pytest.raises(SceneError, match="optimizer.first_step_mm"):
        build_design(bad)
    bad = dataclasses.replace(scene, optimizer=dataclasses.replace(scene.optimizer, distance="nF"))
    with pytest.raises(SceneError, match="optimizer.distance: unknown value 'nF'"):
        build_design(bad)
    with pytest.raises(SceneError, match="at least 2"):
        build_design(dataclasses.replace(scene, poses=scene.poses[:1]))


def test_a_carried_warm_start_reaches_the_same_equilibria_in_fewer_newton_iterations(design):
    """Warm starts move each equilibrium with its deformation gradient to the stepped rest
    nodes (Evaluation.starts_at): the same J and C as from the kept displacements, and no
    more Newton iterations on any scene (summed over the poses) but the refined P2 poke,
    where the carried start took one more (7 against 6)."""
    name, d = design
    rng = np.random.default_rng(8)
    q0 = np.full((d.n_controls, 2), 0.02)
    e = d.evaluate(q0)
    q1 = q0 + 0.3 * rng.uniform(-1, 1, q0.shape)
    carried = d.evaluate(q1, warm=e)
    kept = d.evaluate(q1, warm=e.displacements())
    assert carried.J == pytest.approx(kept.J, rel=1e-9, abs=1e-12), name
    assert np.allclose(carried.capacitance_pF, kept.capacitance_pF, rtol=1e-9, atol=0), name
    assert sum(carried.newton_iterations) <= sum(kept.newton_iterations) + (name == "poke_p2_refined"), name
    for x in (e, carried, kept):
        x.release()


def test_a_released_evaluation_keeps_only_what_warm_starts_need(design):
    """After its gradient, an evaluation drops its factorisations, electrostatic fields and
    moved vertices (the optimiser keeps it beside the next trial); warm starts from it are
    unchanged, and a second gradient is refused rather than computed from nothing."""
    from mscap.errors import DesignError

    name, d = design
    q0 = np.full((d.n_controls, 2), 0.02)
    e = d.evaluate(q0)
    e.release()
    kept = d.evaluate(q0 + 0.01, warm=e)
    d.gradient(kept)
    kept.release()
    assert kept.released and all(r.capacitances.potentials is None and r.vertices is None for r in kept.sim.poses)
    assert all(r.state is None or r.state.operator is None for r in kept.sim.poses)
    again = d.evaluate(q0 + 0.01, warm=e)
    assert again.J == kept.J and np.array_equal(again.capacitance_pF, kept.capacitance_pF), name
    with pytest.raises(DesignError, match="released"):
        d.gradient(kept)
    again.release()


def test_an_evaluation_factorises_only_for_its_gradient(design):
    """Design.evaluate keeps no factorisation, so a rejected line-search trial costs none and
    holds no memory; Design.gradient factorises each loaded pose's Hessian at its
    equilibrium and keeps it (the next trials' modified-Newton starts) until release."""
    name, d = design
    e = d.evaluate(np.full((d.n_controls, 2), 0.02))
    assert all(r.state is None or r.state.operator is None for r in e.sim.poses), name
    d.gradient(e)
    assert all(r.state is None or r.state.operator is not None for r in e.sim.poses), name
    e.release()
    assert all(r.state is None or r.state.operator is None for r in e.sim.poses), name


def test_a_warm_start_on_the_previous_factorisation_reaches_the_same_equilibria(design):
    """An evaluation released with ``keep_elastic`` (the optimiser's current point) keeps
    its elastic factorisations; a nearby trial warm from it starts as modified Newton on
    them (newton.solve_pose's ``stale``): the same J and C to the Newton tolerance, with
    fewer factorising Newton iterations than the same warm start without them, and none
    after a full release."""
    name, d = design
    q0 = np.full((d.n_controls, 2), 0.02)
    e = d.evaluate(q0)
    d.gradient(e)
    e.release(keep_elastic=True)
    loaded = [r.state is not None for r in e.sim.poses]
    kept = e.factorisations(e.sim.elastic)
    if e.sim.elastic is None:
        assert kept is None
    else:
        assert [op is not None for op in kept] == loaded
    q1 = q0 + 0.05
    stale = d.evaluate(q1, warm=e)
    e.release()
    assert e.factorisations(e.sim.elastic) in (None, [None] * len(loaded))
    plain = d.evaluate(q1, warm=e)
    assert stale.J == pytest.approx(plain.J, rel=1e-9, abs=1e-12), name
    assert np.allclose(stale.capacitance_pF, plain.capacitance_pF, rtol=1e-9, atol=0), name
    if any(loaded):
        modified = sum(r.state.stale_iterations for r in stale.sim.poses if r.state is not None)
        assert modified > 0 and sum(stale.newton_iterations) < sum(plain.newton_iterations), name
        assert all(r.state.stale_iterations == 0 for r in plain.sim.poses if r.state is not None)
    for x in (stale, plain):
        x.release()


class Perimeter(Term):
    """The outlines' total length (mm): a term the objective does not ship."""

    def value_and_gradient(self, outlines):
        value, grads = 0.0, []
        for o in outlines:
            o = np.asarray(o, dtype=float)
            edge = np.roll(o, -1, axis=0) - o
            length = np.linalg.norm(edge, axis=1)
            unit = edge / length[:, None]
            value += float(length.sum())
            grads.append(np.roll(unit, 1, axis=0) - unit)
        return value, tuple(grads)


class MeanReading(Term):
    """The mean capacitance (pF) over poses and capacitors."""

    def value_and_gradient(self, c):
        c = np.asarray(c, dtype=float)
        return float(c.mean()), np.full(c.shape, 1.0 / c.size)


def test_a_new_term_is_its_class_and_its_weight(tmp_path_factory, tmp_path):
    """Two terms the objective does not ship, added by name and weight only: J, its
    gradient (Taylor), the optimiser's history, a remesh, the store and ``inspect --run``
    all carry them."""
    from mscap.design.objective import NamedTerm
    from mscap.design.optimizer import optimize
    from mscap.design.remesh import remesh
    from mscap.service.report import history_text
    from mscap.service.schema import record_from_result
    from mscap.service.store import create_store, read_run, write_run

    scene = load(stretch(), tmp_path_factory, "new_term")
    plain = build_design(scene)
    objective = dataclasses.replace(plain.objective, terms=plain.objective.terms + (
        NamedTerm("perimeter", Perimeter(), 0.01, "outlines"), NamedTerm("mean_pF", MeanReading(), -0.5, "capacitance")))
    d = dataclasses.replace(plain, objective=objective)
    rng = np.random.default_rng(7)
    q0 = 0.05 * rng.uniform(-1, 1, (d.n_controls, 2))
    before, e = plain.evaluate(q0), d.evaluate(q0)
    assert list(e.terms) == ["d", "barrier", "smoothing", "perimeter", "mean_pF"]
    assert e.terms["perimeter"] == pytest.approx(Perimeter().value(d.deformer.outlines(q0)), rel=1e-14)
    assert e.terms["mean_pF"] == pytest.approx(e.capacitance_pF.mean(), rel=1e-14)
    assert e.J == pytest.approx(before.J + 0.01 * e.terms["perimeter"] - 0.5 * e.terms["mean_pF"], rel=1e-12)
    grad = d.gradient(e)
    delta = rng.uniform(-1, 1, grad.shape)
    taylor = taylor_test(lambda q: d.evaluate(q, warm=e).J, q0, delta, grad, value=e.J, h0=0.02, halvings=3)
    np.testing.assert_allclose(taylor.rates, 2.0, atol=0.2, err_msg=str(taylor))
    with pytest.raises(Exception, match="history column"):
        NamedTerm("J", Perimeter(), 1.0, "outlines")
    assert remesh(d, e)[0].objective is objective  # a remesh keeps the design's J

    result = optimize(d, max_iterations=2, cascade_levels=0)
    assert all(list(r.terms) == list(e.terms) for r in result.history)
    assert result.history[0].fields[3:8] == ("d", "barrier", "smoothing", "perimeter", "mean_pF")
    record = record_from_result(len(scene.layout.outlines), 0, "scene", scene.layout, result, scene.poses, 1.0)
    with create_store(tmp_path / "r.h5", scene.source, scene.sha256, scene.name, str(scene.path), 1) as store:
        stored = read_run(store, write_run(store, record))
    np.testing.assert_array_equal(stored.history["perimeter"], [r.terms["perimeter"] for r in result.history])
    np.testing.assert_array_equal(stored.history["mean_pF"], [r.terms["mean_pF"] for r in result.history])
    header = [line for line in history_text(stored).splitlines() if line.startswith("iteration")][0]
    assert header.split("\t")[3:8] == ["d", "barrier", "smoothing", "mean_pF", "perimeter"]
