"""The optimiser (mscap.design.optimizer): the exact triangle step bound, the feasible step, the
two-loop recursion, outline resampling, and a short run on a coarse poke scene with a
forced remesh and a cascade level, through the command line."""

from __future__ import annotations

import copy
import csv
import dataclasses
import gc
import json
import weakref

import numpy as np
import pytest

from mscap.cli import main
from mscap.design.feasibility import feasible_step, max_step_triangles
from mscap.design.history import HISTORY_FIELDS
from mscap.design.optimizer import _LBFGS, _line_search, _plateau, optimize
from mscap.design.pipeline import Design, build_design
from mscap.design.remesh import remesh, resample_outline
from mscap.errors import ElasticError, GeometryError, InvertedMeshError
from mscap.geometry import polygons as geometry
from mscap.geometry.layout import check_layout
from mscap.scene import load_scene
from tests.conftest import grid_trimesh, to_toml
from tests.scenes import QUICK, scene_dict

pytest.importorskip("igl")


def test_triangle_bound_is_exact():
    mesh = grid_trimesh(6, 5, 6.0, 5.0, lambda c: -np.ones(len(c)), jitter=0.2)
    v = np.random.default_rng(0).normal(size=mesh.points.shape)

    def area(x):
        e = x[mesh.triangles[:, 1:]] - x[mesh.triangles[:, :1]]
        return 0.5 * (e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0])

    a0 = area(mesh.points)
    alpha = max_step_triangles(mesh.points, mesh.triangles, v, keep=0.1)
    assert 0 < alpha < 1
    ratio = area(mesh.points + alpha * v) / a0
    # The binding triangle sits exactly at a tenth of its area; none below it on [0, α].
    assert ratio.min() == pytest.approx(0.1, rel=1e-9)
    for s in np.linspace(0, alpha, 50):
        assert (area(mesh.points + s * v) / a0).min() >= 0.1 - 1e-9
    assert max_step_triangles(mesh.points, mesh.triangles, 0 * v) == 1.0


def test_two_loop_recursion_is_the_bfgs_inverse_update():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(4, 4))
    hessian = a @ a.T + 4 * np.eye(4)
    memory = _LBFGS(size=8)
    pairs = [(s, hessian @ s) for s in rng.normal(size=(6, 4))]
    for s, y in pairs:
        memory.push(s, y)
    # Dense BFGS: H0 = (sᵀy / yᵀy) I of the newest pair, then each pair in turn.
    s, y = pairs[-1]
    inverse = (s @ y) / (y @ y) * np.eye(4)
    for s, y in pairs:
        rho = 1.0 / (y @ s)
        left = np.eye(4) - rho * np.outer(s, y)
        inverse = left @ inverse @ left.T + rho * np.outer(s, s)
    g = rng.normal(size=4)
    np.testing.assert_allclose(memory.direction(g), -inverse @ g, rtol=1e-10)
    np.testing.assert_allclose(-memory.direction(pairs[-1][1]), pairs[-1][0], rtol=1e-10)  # secant
    memory.push(-s, y)  # negative curvature: skipped
    assert len(memory.pairs) == 6


def test_resampling_keeps_corners_and_spacing():
    square = geometry.square((5.0, 5.0), 4.0)
    fine = resample_outline(square, 0.5)
    assert len(fine) == 32
    assert all((np.abs(fine - c).sum(axis=1) < 1e-12).any() for c in square)
    np.testing.assert_allclose(np.linalg.norm(np.roll(fine, -1, axis=0) - fine, axis=1), 0.5)



def slotted_plate(amplitude=0.8062, width=0.2990, wavelength=2.4938, depth=6.9289, h=0.02):
    """A 20 × 10 mm plate with a slot cut from its right side to x = ``depth``: the slot
    follows a sinusoid and is ``width`` wide, its end a half circle; every smooth stretch
    sampled at ``h`` (no corner there)."""
    k = 2 * np.pi / wavelength
    xs = np.arange(20.0, depth, -h)
    t = np.arange(0.0, np.pi, 2 * h / width)
    cap = np.c_[depth - 0.5 * width * np.sin(t), amplitude * np.sin(k * depth) - 0.5 * width * np.cos(t)]
    outline = np.vstack([np.c_[xs, amplitude * np.sin(k * xs) - width / 2], cap,
                         np.c_[xs[::-1], amplitude * np.sin(k * xs[::-1]) + width / 2],
                         [(20.0, 5.0), (0.0, 5.0), (0.0, -5.0), (20.0, -5.0)]])
    return outline if geometry.signed_area(outline) > 0 else outline[::-1]


def test_a_remesh_resamples_an_outline_finer_where_its_chords_cross():
    # 2.4 mm chords of the slotted plate cut across its slot (4 crossings; the outline
    # itself is simple): the remesh resamples that outline at half the spacing until the
    # layout is valid, instead of failing the run (a poking paper start at k = 6 failed
    # so after 467 s), and leaves a valid outline's resampling alone.
    from types import SimpleNamespace

    from mscap.design.remesh import resampled_layout

    slotted, square = slotted_plate(), geometry.square((40.0, 0.0), 8.0)
    assert not geometry.self_intersections(slotted)
    assert geometry.self_intersections(resample_outline(slotted, 2.4))
    scene = SimpleNamespace(sheet_outline_mm=geometry.square((25.0, 0.0), 60.0), min_gap_mm=1.0)
    layout = resampled_layout([slotted, square], 2.4, 0.075, scene)
    check_layout(layout, scene.sheet_outline_mm, scene.min_gap_mm)
    assert 2 * len(resample_outline(slotted, 2.4)) <= len(layout.outlines[0]) < len(slotted)
    np.testing.assert_array_equal(layout.outlines[1], resample_outline(square, 2.4))
    # Nothing finer than the finest spacing: the outline as it is.
    np.testing.assert_array_equal(resampled_layout([slotted, square], 2.4, 2.0, scene).outlines[0], slotted)
    with pytest.raises(GeometryError, match="overlap"):  # an invalid layout still fails, naming why
        resampled_layout([slotted, geometry.square((10.0, 0.0), 4.0)], 2.4, 0.075, scene)


POKES = {"name": "poke_cross", "sheet": {"width_mm": 40.0, "height_mm": 30.0},
         "capacitors": {"min_gap_mm": 1.0, "outlines_mm": [[[8.0, 9.0], [18.0, 9.0], [18.0, 21.0], [8.0, 21.0]],
                                                          [[22.0, 9.0], [32.0, 9.0], [32.0, 21.0], [22.0, 21.0]]]},
         "mesh": {"edge_length_mm": 4.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 2.0},
         "poses": [{"name": f"p{i}", "kind": "poke", "center_mm": c, "radius_mm": 4.0, "depth_mm": 2.0,
                    "held_edges": ["x_min", "x_max"]}
                   for i, c in enumerate([[20.0, 11.0], [20.0, 19.0], [15.0, 15.0]])],
         # revive_silent off: the right plate adds under 1 % to the pokes' separation, so a
         # revival would move it first; these tests count the steps and remeshes that follow
         # (the revival has its own, tests/design/test_revival.py).
         "optimizer": {"control_spacing_mm": 8.0, "max_iterations": 3, "cascade_levels": 1,
                       "revive_silent": False},
         # P1: these tests are about the optimiser's steps, remeshes and memory, not the
         # poke's gain (pokes default to refined P2: the file's 19 tests took 143 s, 51 s on
         # P1); the remesh's warm start is also checked on P2 (poke_scene_p2).
         "elastic": {"order": 1}}


@pytest.fixture(scope="module")
def poke_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("optimize") / "pokes.toml"
    path.write_text(to_toml(scene_dict(**copy.deepcopy(POKES))))
    return path


@pytest.fixture(scope="module")
def poke_scene_p2(tmp_path_factory):
    """:data:`POKES` with the pokes' own default elastic element (refined P2)."""
    path = tmp_path_factory.mktemp("optimize") / "pokes_p2.toml"
    path.write_text(to_toml(scene_dict(**{key: value for key, value in copy.deepcopy(POKES).items()
                                          if key != "elastic"})))
    return path


def test_feasible_step_never_overlaps_or_inverts(poke_scene):
    design = build_design(load_scene(poke_scene))
    q = design.deformer.zeros()
    # Push capacitor 0 bodily into capacitor 1 (and through it): the step stops short.
    p = np.where((design.deformer.control_outline == 0)[:, None], [30.0, 0.0], 0.0)
    alpha = feasible_step(design, q, p)
    assert 0 < alpha < 1
    layout = design.deformer.layout(q + alpha * p)
    check_layout(layout, design.scene.sheet_outline_mm, design.scene.min_gap_mm)
    assert (design.deformer.mesh2d.areas() > 0).all()
    moved = design.deformer.points2d(q + alpha * p)
    assert (dataclasses.replace(design.deformer.mesh2d, points=moved).areas() > 0).all()


def test_optimize_decreases_J_with_remesh_and_cascade(poke_scene):
    scene = load_scene(poke_scene)
    result = optimize(build_design(scene))
    events = [r.event for r in result.history]
    assert events[0] == "start" and "cascade" in events and events[-1] in ("max_iterations", "converged")
    steps = [r for r in result.history if r.event == "step"]
    assert len(steps) >= 3
    for before, after in zip(result.history, result.history[1:]):
        if after.event == "step":
            assert after.J < before.J
    assert result.evaluation.min_l1_pF > result.initial.min_l1_pF
    check_layout(result.layout, scene.sheet_outline_mm, scene.min_gap_mm)


def test_line_search_counts_the_trials_the_mesh_stopped(monkeypatch):
    """Along J(α) = 1 - 2α + 10α² from α = 1 the search halves to the first α that
    decreases J enough (Armijo, c = 1e-4): 1, 0.5, 0.25, 0.125. A trial whose deformed
    electrostatic mesh inverts halves too, and is counted: that count decides a remesh."""
    from mscap.design import optimizer

    monkeypatch.setattr(optimizer, "feasible_step", lambda design, q, p, alpha: alpha)

    class Line:
        def __init__(self, fail=()):
            self.tried, self.fail = [], fail

        def evaluate(self, q, warm=None):
            alpha = float(q[0, 0])
            self.tried.append(alpha)
            if alpha in self.fail:
                raise InvertedMeshError("pose 'p': 1 dielectric tets are inverted")
            return dataclasses.make_dataclass("E", [("J", float), ("q", object)], namespace={
                "release": lambda self: None})(1 - 2 * alpha + 10 * alpha ** 2, q)

    start = dataclasses.make_dataclass("E", [("J", float), ("q", object)])(1.0, np.zeros((1, 2)))
    g, p = np.array([[-2.0, 0.0]]), np.array([[1.0, 0.0]])  # J'(0) along p: -2
    line = Line()
    accepted, alpha, trials, evaluations, inverted, _ = _line_search(line, start, g, p, 1.0)
    assert line.tried == [1.0, 0.5, 0.25, 0.125] and trials == evaluations == 4 and inverted == 0
    assert accepted.J == pytest.approx(1 - 0.25 + 10 / 64)
    line = Line(fail=(1.0, 0.5))
    _, alpha, trials, evaluations, inverted, _ = _line_search(line, start, g, p, 1.0)
    assert line.tried == [1.0, 0.5, 0.25, 0.125] and inverted == 2
    line = Line(fail=tuple(0.5 ** n for n in range(8)))
    assert _line_search(line, start, g, p, 1.0) == (None, 0.0, 8, 8, 8, 0)


def test_screening_skips_the_trials_the_outline_terms_reject(monkeypatch):
    """J(α) = −d + G = 1 − 2α + 10α², the capacitance term d = −1 + 2α and the outline
    terms G = 10α² (flat at α = 0: d's first-order gain is 2 per unit α). α = 1 and 0.5
    raise G by 10 and 2.5, more than twice d's gain (4, 2): screened, not evaluated. α =
    0.25 (G +0.625 ≤ 1) is evaluated and fails Armijo, 0.125 is accepted: the same α, J and
    trial count as without screening, in 2 evaluations instead of 4."""
    from mscap.design import optimizer

    monkeypatch.setattr(optimizer, "feasible_step", lambda design, q, p, alpha: alpha)

    class Geometry:
        def value(self, outlines):
            return 10 * float(outlines) ** 2

    class Line:
        objective = dataclasses.make_dataclass("O", [("geometry", object)], namespace={
            "capacitance_value": lambda self, terms: -terms["d"]})(Geometry())  # J = −d + G
        deformer = dataclasses.make_dataclass("D", [], namespace={"outlines": lambda self, q: q[0, 0]})()

        def __init__(self):
            self.tried = []

        def outline_gradient(self, q):
            return np.array([[20 * float(q[0, 0]), 0.0]])

        def evaluate(self, q, warm=None):
            alpha = float(q[0, 0])
            self.tried.append(alpha)
            return dataclasses.make_dataclass("E", [("J", float), ("q", object)], namespace={
                "release": lambda self: None})(1 - 2 * alpha + 10 * alpha ** 2, q)

    start = dataclasses.make_dataclass("E", [("J", float), ("terms", dict), ("q", object)])(1.0, {"d": -1.0},
                                                                                           np.zeros((1, 2)))
    g, p = np.array([[-2.0, 0.0]]), np.array([[1.0, 0.0]])
    plain, screened = Line(), Line()
    without = _line_search(plain, start, g, p, 1.0, screen=False)
    with_ = _line_search(screened, start, g, p, 1.0, screen=True)
    assert plain.tried == [1.0, 0.5, 0.25, 0.125] and screened.tried == [0.25, 0.125]
    assert with_[1:] == (0.125, 4, 2, 0, 0) and without[1:] == (0.125, 4, 4, 0, 0)
    assert with_[0].J == without[0].J == pytest.approx(1 - 0.25 + 10 / 64)


def test_screening_leaves_the_path_as_it_was(tmp_path):
    """``screen_trials`` skips only trials Armijo would reject. On jobs/quick.toml's scene
    (P2 elasticity, as shipped) the line searches of steps 4 and 5 try α at which the
    outline terms rise by 0.1–2.9, 10–80 times what d can gain: screened, the two runs take
    the same 5 steps to the same J with fewer evaluations (3 on the meshes before the 2D
    quality bounds of mscap/mesh/triangulate.py, 1 since: 9 → 8). (On the seven quick scenes and
    all seven paper ones every path was the same, in 0.43–0.98 of the evaluations:
    docs/optimize.md, "Screening line-search trials".)"""
    path = tmp_path / "quick.toml"
    path.write_text(QUICK.replace("order = 1\n", "order = 2\n", 1))
    scene = load_scene(path)
    runs = {}
    for screen in (False, True):
        settings = dataclasses.replace(scene.optimizer, screen_trials=screen)
        runs[screen] = optimize(build_design(dataclasses.replace(scene, optimizer=settings)), max_iterations=5,
                                cascade_levels=0)
    off, on = runs[False], runs[True]
    assert [r.J for r in on.history] == [r.J for r in off.history]
    assert sum(r.evaluations for r in on.history) == sum(r.evaluations for r in off.history) - 1


def test_plateau_compares_J_with_its_value_window_steps_back():
    values = [10.0, 9.0, 8.95, 8.94]
    assert _plateau(values, 8.94, window=2, tolerance=0.01)  # 9 - 8.94 = 0.06 <= 0.0894
    assert not _plateau(values, 8.94, window=3, tolerance=0.01)  # 10 - 8.94 = 1.06
    assert not _plateau(values, 8.94, window=4, tolerance=1.0)  # fewer steps than the window
    assert not _plateau(values, 8.94, window=0, tolerance=1.0)  # 0: off
    assert _plateau([0.30, 0.298], 0.298, window=1, tolerance=0.01)  # a bound of 0.3 mm: relative to |J|
    assert not _plateau([0.30, 0.29], 0.29, window=1, tolerance=0.01)  # 3.4 %, not 0.01 of max(|J|, 1)


def test_a_plateau_ends_each_level_after_its_window(poke_scene):
    """stall_window = 2 with a tolerance no gain reaches (the other two rules off): each
    level ends exactly two steps after its start or its last remesh, not at
    max_iterations = 6; with the rule off the same run takes all 6 steps per level."""
    scene = load_scene(poke_scene)

    def run(window):
        settings = dataclasses.replace(scene.optimizer, max_iterations=6, stall_window=window, stall_tolerance=1e6,
                                       relative_tolerance=0.0, gradient_tolerance=0.0)
        return [r.event for r in optimize(build_design(dataclasses.replace(scene, optimizer=settings))).history]

    events = run(2)
    assert events[-1] == "converged" and events.count("cascade") == 1, events
    since = 0
    for event in events[1:]:
        if event in ("cascade", "converged"):
            assert since == 2, events
        since = since + 1 if event == "step" else 0
    assert run(0).count("step") == 12


@pytest.mark.parametrize("failures, error, events", [
    # Every trial of the first mesh inverts its deformed electrostatic tets: remesh, go on.
    (99, InvertedMeshError, ["start", "remesh", "step", "step", "max_iterations"]),
    # Three trials do, the fourth (α/8) is accepted: the mesh held the step back, remesh after it.
    (3, InvertedMeshError, ["start", "step", "remesh", "step", "max_iterations"]),
    # A failure that is not the mesh's: the search stalls as before.
    (99, ElasticError, ["start", "stalled"]),
])
def test_a_mesh_that_inverts_is_remeshed_not_stalled(poke_scene, monkeypatch, failures, error, events):
    """wrist_quick stalled at a design where one pose's deformed electrostatic mesh inverted
    (15 tets, 1e-4 mm³) for any step along −∇J, crawling with 0.003-0.03 mm steps and
    ending with a read-back bound of 0.66 mm where a fresh mesh went on to 0.51 mm."""
    design = build_design(load_scene(poke_scene))
    evaluate, left = Design.evaluate, iter(range(failures))

    def failing(self, q, warm=None):
        if self is design and warm is not None and next(left, None) is not None:
            raise error("pose 'p0': 15 dielectric tets are inverted or degenerate (e.g. tet 396)")
        return evaluate(self, q, warm)

    monkeypatch.setattr(Design, "evaluate", failing)
    result = optimize(design, max_iterations=2, cascade_levels=0)
    assert [r.event for r in result.history] == events
    if failures == 99 and error is InvertedMeshError:
        assert result.history[1].evaluations == 9  # the 8 failed trials and the new mesh's evaluation
        assert result.history[-1].J < result.history[1].J  # the new mesh's steps descend


def test_designs_remeshed_away_from_are_freed(poke_scene, monkeypatch):
    """A remesh replaces the design: the old one's PETSc solvers are destroyed and nothing
    keeps it alive (petsc4py frees native memory only on destroy; a multi-start worker
    that kept them grew to 3 GB on poking_cross), nor its meshes through the initial
    evaluation. A cascade level keeps the meshes, so it shares the solvers."""
    from mscap.design import optimizer, remesh as remeshing

    built, calls = [], iter(range(1000))
    original = remeshing.build_design

    def recording_build(*args, **kwargs):
        built.append(original(*args, **kwargs))
        return built[-1]

    monkeypatch.setattr(remeshing, "build_design", recording_build)
    monkeypatch.setattr(optimizer, "needs_remesh", lambda *args: next(calls) in (0, 1))  # two remeshes
    design = build_design(load_scene(poke_scene))
    open_beside = []  # per evaluation: how many other designs still hold solvers (a cascade level shares them)
    evaluate = Design.evaluate

    def recording_evaluate(self, *args, **kwargs):
        open_beside.append(sum(1 for d in [design, *built] if d.workspace and d.workspace is not self.workspace))
        return evaluate(self, *args, **kwargs)

    monkeypatch.setattr(Design, "evaluate", recording_evaluate)
    result = optimize(design, max_iterations=3)
    assert [r.event for r in result.history].count("remesh") == 2
    # The old design is closed before the new one's first evaluation, not after (both alive
    # were the whole-start memory peak: biaxial 944 → 701 MB across a remesh).
    assert open_beside and not any(open_beside)
    assert len(built) == 2 and design.workspace == {} and built[0].workspace == {}
    first, second = weakref.ref(built[0]), weakref.ref(built[1])
    built.clear()
    gc.collect()
    assert first() is None  # the caller's design stays the caller's; the intermediate one is gone
    assert second() is None or second() is result.design or second().workspace == {}
    assert result.initial.sim is None and result.initial.capacitance_pF.shape == result.evaluation.capacitance_pF.shape
    # The result's design still evaluates (a closed design makes new solvers).
    np.testing.assert_allclose(result.design.evaluate(result.evaluation.q).J, result.evaluation.J, rtol=1e-9)
    result.design.close()


@pytest.mark.parametrize("order", [1, 2])
def test_remesh_keeps_the_outlines_and_warm_starts(poke_scene, poke_scene_p2, order):
    design = build_design(load_scene(poke_scene if order == 1 else poke_scene_p2))
    assert design.base.elastic.order == order
    rng = np.random.default_rng(2)
    q = 0.4 * rng.uniform(-1, 1, (design.n_controls, 2))
    q *= feasible_step(design, design.deformer.zeros(), q)
    e = design.evaluate(q)
    new, warm = remesh(design, e)
    # The new outlines are polygons through points of the old ones (every 1 mm here, the
    # half elastic outline edge), so the old outlines lie within the chordal error.
    for old, polygon, chain in zip(design.deformer.outlines(q), new.sheet.layout.outlines,
                                   new.deformer.outlines(new.deformer.zeros())):
        assert geometry.point_segment_distance(polygon, geometry.edges(old)).min(axis=1).max() < 1e-9
        assert geometry.point_segment_distance(old, geometry.edges(chain)).min(axis=1).max() < 0.05
    cold = new.evaluate(new.deformer.zeros())
    hot = new.evaluate(new.deformer.zeros(), warm=warm)
    # Measured: 3–5 Newton iterations per pose warm, about 3× that cold.
    assert sum(hot.newton_iterations) < 0.6 * sum(cold.newton_iterations)
    np.testing.assert_allclose(hot.capacitance_pF, cold.capacitance_pF, rtol=1e-9)
    # A new mesh of the same geometry: capacitances move by the discretisation only.
    np.testing.assert_allclose(hot.capacitance_pF, e.capacitance_pF, rtol=0.02)


@pytest.mark.parametrize("keep", [True, False])
def test_a_remesh_keeps_the_lbfgs_memory(poke_scene, monkeypatch, keep):
    """``keep_memory_at_remesh``: the step after a remesh uses the curvature pairs taken
    before it (the controls keep their number and order), or none when it is off. On
    wrist_quick keeping them gave 4 of 4 starts a lower bound (0.448 → 0.403 mm mean) in
    fewer evaluations (docs/optimize.md, "Remeshing keeps the L-BFGS memory")."""
    from mscap.design import optimizer

    scene = load_scene(poke_scene)
    settings = dataclasses.replace(scene.optimizer, keep_memory_at_remesh=keep, relative_tolerance=0.0,
                                   gradient_tolerance=0.0, stall_window=0)
    calls = iter(range(1000))
    monkeypatch.setattr(optimizer, "needs_remesh", lambda *args: next(calls) == 1)  # after the second step
    seen = []  # the memory size at each direction the optimiser asks for
    direction = _LBFGS.direction

    def recording(self, g):
        seen.append(len(self.pairs))
        return direction(self, g)

    monkeypatch.setattr(_LBFGS, "direction", recording)
    result = optimize(build_design(dataclasses.replace(scene, optimizer=settings)), max_iterations=4,
                      cascade_levels=0)
    events = [r.event for r in result.history]
    assert events[:4] == ["start", "step", "step", "remesh"], events
    # The directions of the first and the second step, then of the step after the remesh.
    assert seen[1] >= 1, seen  # the first step's pair
    assert seen[2] >= seen[1] if keep else seen[2] == 0, seen


def test_command_writes_every_output(poke_scene, tmp_path, capsys):
    out = tmp_path / "run"
    status = main(["optimize", str(poke_scene), "--max-iterations", "1", "--cascade", "0", "-o", str(out), "-q"])
    assert status == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in ("k", "seed", "init", "iterations", "time_s", "initial_min_l1_pF", "final_min_l1_pF",
                "capacitance_pF"):
        assert key in summary
    assert summary["k"] == 2 and summary["init"] == "scene" and len(summary["capacitance_pF"]) == 3
    with open(out / "history.csv") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == HISTORY_FIELDS and len(rows) >= 3
    # every record carries the quality of the mesh it was evaluated on (mscap.mesh.shape)
    ratios = [float(row[HISTORY_FIELDS.index("size_ratio")]) for row in rows[1:]]
    assert all(1.0 <= r < 6.0 for r in ratios), ratios
    outlines = json.loads((out / "outlines.json").read_text())["outlines_mm"]
    assert len(outlines) == 2
    assert (out / "layout.png").stat().st_size > 10_000
    assert (out / "capacitance.csv").read_text().count("\n") == 1 + 2 * 3
    assert "min pairwise L1" in capsys.readouterr().out
