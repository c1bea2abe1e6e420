"""The pneumatic and hand generators (mscap/bodies/pneumatic.py, hand.py) and the biaxial, pneumatic and
glove scenes: exact kinematics, parameter checks, the scenes' poses, one optimisation step."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mscap.bodies.basic import cylinder
from mscap.bodies.glue import _grid, check_covers
from mscap.scene.glue import read_glue_pose, read_objects
from mscap.bodies.hand import FINGERS, _hand_bend, hand
from mscap.bodies.pneumatic import pneumatic
from mscap.bodies.registry import GENERATORS
from mscap.errors import SceneError
from mscap.geometry import polygons as geometry
from mscap.scene import load_scene
from mscap.scene._toml import Table

JOBS = Path(__file__).resolve().parents[2] / "jobs"
SCENES = ("biaxial", "biaxial_quick", "pneumatic", "pneumatic_quick", "glove", "glove_quick")
SCENE = "scene.toml"

R = 20.0                                   # actuator radius (mm) of the unit tests
ACTUATOR = {"radius_mm": R, "length_mm": 80.0}
MIDDLE = {"center_mm": (50.0, 30.0)}    # the top line and the middle between the caps
HAND = {"knuckle_mm": 45.0}
PITCH, DEPTH, BLEND, WEB = 19.0, 8.0, 36.0, 15.0      # the hand generator's defaults


def sheet(width, height, edge=1.0):
    """Parameter points and triangles of a width × height object with its corner at
    (-2, -2): its centre, the default ``center_mm``, is (width/2 - 2, height/2 - 2)."""
    surface = _grid(width, height, (-2.0, -2.0), edge)
    return surface.uv, surface.triangles


def actuator_object():
    return sheet(104.0, 64.0)              # centre (50, 30), as in jobs/pneumatic.toml


def hand_object():
    return sheet(84.0, 54.0)               # centre u = 40, as in jobs/glove.toml


def triangle_stretches(uv, triangles, points):
    """(m, 2) principal stretches (largest first) of the map uv -> points per triangle."""
    a, b, c = (uv[triangles[:, i]] for i in range(3))
    pa, pb, pc = (points[triangles[:, i]] for i in range(3))
    rest, posed = np.stack([b - a, c - a], axis=2), np.stack([pb - pa, pc - pa], axis=2)
    gradient = posed @ np.linalg.inv(rest)
    return np.linalg.svd(gradient, compute_uv=False)


def radial(points, axis_u=50.0):
    """Distance from the actuator's axis (u = axis_u, z = -R) at t = 1."""
    return np.hypot(points[:, 0] - axis_u, points[:, 2] + R)


def around(phi_deg, v, axis_u=50.0):
    """Parameter points at angles ``phi_deg`` from the top line u = ``axis_u`` and at
    axial positions ``v`` (give ``center_mm`` = (axis_u, v_c) with them)."""
    u = axis_u + R * np.radians(np.atleast_1d(phi_deg))
    return np.column_stack(np.broadcast_arrays(u, np.atleast_1d(v))).astype(float)


# --------------------------------------------------------------------------- t = 0

@pytest.mark.parametrize("generator, uv, parameters", [
    (pneumatic, actuator_object()[0], ACTUATOR | {"inflation_mm": 6.0, "indent_mm": 5.0,
                                                  "obstacle_deg": -90.0, "thin_side_deg": 30.0}),
    (hand, hand_object()[0], HAND | {"index_deg": 60.0, "ring_deg": -20.0, "spread_deg": 15.0}),
])
def test_load_fraction_zero_is_the_flat_sheet_exactly(generator, uv, parameters):
    flat = generator(uv, 0.0, **parameters)
    np.testing.assert_array_equal(flat, np.column_stack([uv, np.zeros(len(uv))]))


def test_generators_are_registered_by_importing_the_generators():
    assert GENERATORS["pneumatic"] is pneumatic and GENERATORS["hand"] is hand


# --------------------------------------------------------------------------- pneumatic

def test_pneumatic_without_inflation_or_dent_is_the_isometric_roll():
    uv, triangles = actuator_object()
    for t in (0.4, 1.0):
        rolled = cylinder(uv, t, radius_mm=R)
        np.testing.assert_array_equal(pneumatic(uv, t, **ACTUATOR), rolled)
        np.testing.assert_allclose(triangle_stretches(uv, triangles, rolled), 1.0, atol=1e-3)


def test_pneumatic_bulge_is_largest_on_the_thin_wall_and_vanishes_at_the_caps():
    inflation, ratio = 6.0, 0.25
    phi = np.linspace(-150.0, 150.0, 61)
    for thin in (0.0, 40.0):
        parameters = ACTUATOR | MIDDLE | {"inflation_mm": inflation, "wall_ratio": ratio,
                                          "thin_side_deg": thin}
        growth = radial(pneumatic(around(phi, 30.0), 1.0, **parameters)) - R
        # The documented profile: inflation (ρ + (1 − ρ) cos²((φ − φ_thin)/2)) mid-length.
        expected = inflation * (ratio + (1 - ratio) * np.cos(np.radians(phi - thin) / 2) ** 2)
        np.testing.assert_allclose(growth, expected, atol=1e-12)
        assert phi[np.argmax(growth)] == thin
    # Along the axis: cos² from the middle (v = 30) to zero at the caps (v = 30 ± 40),
    # beyond which the actuator keeps its radius.
    v = np.array([30.0, 40.0, 50.0, 70.0, 75.0])
    p = pneumatic(around(0.0, v), 1.0, **ACTUATOR, **MIDDLE, inflation_mm=inflation)
    expected = inflation * np.cos(np.pi * (v - 30.0) / 80.0) ** 2 * (v < 70.0)
    np.testing.assert_allclose(radial(p) - R, expected, atol=1e-12)


def test_pneumatic_hoop_stretch_on_the_thin_wall_is_one_plus_inflation_over_radius():
    h = 1e-4
    uv = around(np.degrees(np.array([-h, h]) / R), 30.0)
    for inflation in (3.0, 6.0):
        p = pneumatic(uv, 1.0, **ACTUATOR, **MIDDLE, inflation_mm=inflation)
        assert np.linalg.norm(p[1] - p[0]) / (2 * h) == pytest.approx(1 + inflation / R, rel=1e-7)


def test_pneumatic_obstacle_pushes_its_side_in_and_leaves_the_other_side():
    contacts = 50.0 + R * np.radians([90.0, -90.0])       # inside the object: same centre
    uv = np.vstack([actuator_object()[0], np.column_stack([contacts, [30.0, 30.0]])])
    inflated = pneumatic(uv, 1.0, **ACTUATOR, inflation_mm=6.0)
    for side in (90.0, -90.0):
        pushed = pneumatic(uv, 1.0, **ACTUATOR, inflation_mm=6.0, indent_mm=5.0,
                           obstacle_deg=side, obstacle_radius_mm=20.0)
        u_ball = 50.0 + R * math.radians(side)
        reach = np.hypot(uv[:, 0] - u_ball, uv[:, 1] - 30.0)
        # The contact point moves 5 mm towards the axis; the dent is round, 20 mm in
        # radius on the surface; elsewhere nothing moves, the opposite side included.
        centre = np.argmin(reach)
        assert reach[centre] < 1e-12
        assert radial(inflated)[centre] - radial(pushed)[centre] == pytest.approx(5.0, abs=1e-12)
        dented = reach < 20.0 - 1e-9
        assert (radial(pushed)[dented] < radial(inflated)[dented]).all()
        np.testing.assert_array_equal(pushed[~dented], inflated[~dented])
        assert (~dented & (np.sign(uv[:, 0] - 50.0) == -np.sign(side))).sum() > 2000


# --------------------------------------------------------------------------- hand

def finger_rotation(flexion_deg, spread_deg, t=1.0):
    """The documented finger rotation R_z(t α) R_x(−t θ), built by scipy."""
    return Rotation.from_euler("ZX", [t * spread_deg, -t * flexion_deg], degrees=True).as_matrix()


def test_hand_back_stays_and_finger_cores_turn_rigidly_about_their_knuckles():
    uv, _ = sheet(84.0, 84.0)              # centre u = 40; reaches 37 mm beyond the knuckles
    angles = {"index_deg": 60.0, "middle_deg": 0.0, "ring_deg": 30.0, "little_deg": -20.0}
    spread = 15.0
    flat = np.column_stack([uv, np.zeros(len(uv))])
    for t in (0.5, 1.0):
        p = hand(uv, t, **HAND, **angles, spread_deg=spread)
        back = uv[:, 1] <= HAND["knuckle_mm"] - BLEND / 2
        np.testing.assert_array_equal(p[back], flat[back])
        beyond = uv[:, 1] >= HAND["knuckle_mm"] + BLEND / 2
        for i, finger in enumerate(FINGERS):
            centre = 40.0 + (i - 1.5) * PITCH
            core = beyond & (np.abs(uv[:, 0] - centre) <= (PITCH - WEB) / 2)
            assert core.sum() >= 5
            joint = np.array([centre, HAND["knuckle_mm"], -DEPTH])
            turn = finger_rotation(angles[f"{finger}_deg"], spread * (1.5 - i) / 1.5, t)
            np.testing.assert_allclose(p[core], (flat[core] - joint) @ turn.T + joint, atol=1e-12)


def test_hand_sign_conventions():
    # Flexion > 0 bends a finger into the palm (−z); spread > 0 fans the index towards
    # −u and the little finger towards +u; the back of the hand stays.
    uv = np.array([[-2.0, -2.0], [82.0, 52.0], [11.5, 52.0], [68.5, 52.0], [40.0, 0.0]])
    flexed = hand(uv, 1.0, **HAND, index_deg=40.0)
    spread = hand(uv, 1.0, **HAND, spread_deg=20.0)
    assert flexed[2, 2] < -3.0 and abs(flexed[3, 2]) < 1e-12
    assert spread[2, 0] < 11.5 - 1.0 and spread[3, 0] > 68.5 + 1.0
    np.testing.assert_array_equal(spread[4], [40.0, 0.0, 0.0])


def test_hand_area_check_is_the_surface_jacobian():
    # The refusal uses the analytic area ratio |dp/du x dp/dv|: central differences agree.
    uv = np.random.default_rng(0).uniform([-2.0, -2.0], [82.0, 52.0], (2000, 2))
    h = 1e-6
    for angles in ({"index_deg": 60.0, "middle_deg": 0.0, "ring_deg": 30.0, "little_deg": -20.0,
                    "spread_deg": 15.0},
                   {"index_deg": -30.0, "middle_deg": 80.0, "ring_deg": 0.0, "little_deg": 45.0,
                    "spread_deg": -10.0}):
        ratio = _hand_bend(uv, 1.0, 40.0, HAND["knuckle_mm"], PITCH, DEPTH, BLEND, WEB,
                           tuple(angles[f"{f}_deg"] for f in FINGERS), angles["spread_deg"],
                           need_ratio=True)[1]
        parameters = HAND | angles | {"center_mm": (40.0, 0.0)}
        d_u, d_v = ((hand(uv + step, 1.0, **parameters) - hand(uv - step, 1.0, **parameters))
                    / (2 * h) for step in (np.array([h, 0.0]), np.array([0.0, h])))
        np.testing.assert_allclose(ratio, np.linalg.norm(np.cross(d_u, d_v), axis=1), atol=1e-7)


# --------------------------------------------------------------------------- parameters

PARAMETER_ERRORS = [
    ("pneumatic", ACTUATOR | {"radius_mm": 0.0}, "radius_mm", "must be > 0"),
    ("pneumatic", ACTUATOR | {"radius_mm": 10.0}, "radius_mm",
     "more than once around the actuator"),
    ("pneumatic", ACTUATOR | {"length_mm": -1.0}, "length_mm", "must be > 0"),
    ("pneumatic", ACTUATOR | {"inflation_mm": -1.0}, "inflation_mm", r"must lie in \[0, 10\]"),
    ("pneumatic", ACTUATOR | {"inflation_mm": 10.5}, "inflation_mm", r"must lie in \[0, 10\]"),
    ("pneumatic", ACTUATOR | {"inflation_mm": 8.0, "length_mm": 20.0}, "inflation_mm",
     "steeper than 45° along the axis"),
    ("pneumatic", ACTUATOR | {"wall_ratio": 1.5}, "wall_ratio", r"must lie in \[0, 1\]"),
    ("pneumatic", ACTUATOR | {"indent_mm": 11.0}, "indent_mm", r"must lie in \[0, 10\]"),
    ("pneumatic", ACTUATOR | {"indent_mm": 8.0, "obstacle_radius_mm": 10.0}, "indent_mm",
     "dent steeper than 45°"),
    ("pneumatic", ACTUATOR | {"obstacle_radius_mm": 0.0}, "obstacle_radius_mm", "must lie in"),
    ("pneumatic", ACTUATOR | {"obstacle_radius_mm": 40.0}, "obstacle_radius_mm",
     "a quarter of the circumference"),
    ("pneumatic", ACTUATOR | {"obstacle_deg": 200.0}, "obstacle_deg", r"must lie in \[-180, 180\]"),
    ("pneumatic", ACTUATOR | {"thin_side_deg": -181.0}, "thin_side_deg",
     r"must lie in \[-180, 180\]"),
    ("hand", HAND | {"pitch_mm": 0.0}, "pitch_mm", "must be > 0"),
    ("hand", HAND | {"blend_mm": -5.0}, "blend_mm", "must be > 0"),
    ("hand", HAND | {"joint_depth_mm": -1.0}, "joint_depth_mm", "must be >= 0"),
    ("hand", HAND | {"web_mm": 20.0}, "web_mm", r"must lie in \(0, pitch_mm"),
    ("hand", HAND | {"middle_deg": 95.0}, "middle_deg", r"must lie in \[-90, 90\]"),
    ("hand", HAND | {"little_deg": -91.0}, "little_deg", r"must lie in \[-90, 90\]"),
    ("hand", HAND | {"spread_deg": 31.0}, "spread_deg", r"must lie in \[-30, 30\]"),
    # Extension compresses the back on the inside of the bend (all four: the first named).
    ("hand", HAND | {f"{f}_deg": -45.0 for f in FINGERS} | {"blend_mm": 10.0}, "index_deg",
     r"compress the surface to 0\.2.* of its area"),
    ("hand", HAND | {"ring_deg": -60.0, "middle_deg": 20.0, "blend_mm": 10.0}, "ring_deg",
     r"fold the surface over \(signed area ratio -"),
]


@pytest.mark.parametrize("generator, parameters, key, message", PARAMETER_ERRORS)
def test_out_of_range_parameters_name_the_key(generator, parameters, key, message):
    width, height = (104.0, 64.0) if generator == "pneumatic" else (84.0, 54.0)
    objects = read_objects(Table(SCENE, "objects", {"o": {
        "generator": generator, "width_mm": width, "height_mm": height,
        "corner_mm": [-2.0, -2.0], "edge_length_mm": 2.0}}), SCENE)
    keys = {"name": "p", "kind": "glue", "object": "o"} | parameters
    with pytest.raises(SceneError, match=rf"scene\.toml: poses\[0\]\.{key}: .*{message}"):
        read_glue_pose(Table(SCENE, "poses[0]", keys), objects)


# --------------------------------------------------------------------------- scenes

@pytest.fixture(scope="module")
def scenes():
    return {name: load_scene(JOBS / f"{name}.toml") for name in SCENES}


def test_biaxial_poses_stretch_each_direction_between_clamps(scenes):
    for name in ("biaxial", "biaxial_quick"):
        rest, along_x, along_y = scenes[name].poses
        assert rest.kind == "free"
        assert (along_x.mode, along_x.stretch, along_x.grips) == ("uniaxial", (1.5, 1.0), "clamp")
        assert (along_y.mode, along_y.stretch, along_y.grips) == ("uniaxial", (1.0, 1.5), "clamp")
        # The swap x <-> y maps the layout onto itself with the plates exchanged in pairs
        # (none onto itself): each reading of one stretch is another plate's of the other.
        outlines = scenes[name].layout.outlines
        centres = np.array([o.mean(axis=0) for o in outlines])
        swapped = [int(np.argmin(np.abs(centres - c[::-1]).sum(axis=1))) for c in centres]
        assert sorted(swapped) == list(range(4)) and all(j != i for i, j in enumerate(swapped))


# The sheet's principal stretches at t = 1 that docs/scenes.md reports, with a margin of
# 0.005 for the rounding.
STRETCH_RANGES = {"pneumatic": (0.93, 1.30), "glove": (0.81, 1.39)}


@pytest.mark.parametrize("name", ("pneumatic", "glove"))   # the quick scenes: the same poses
def test_glued_poses_cover_the_sheet_without_degenerate_triangles(scenes, name):
    scene = scenes[name]
    assert len(scene.poses) == (4 if name == "pneumatic" else 23)
    assert all(p.kind == "glue" for p in scene.poses)
    rest = scene.poses[0].object.rest
    centroids = rest.uv[rest.triangles].mean(axis=1)
    on_sheet = geometry.points_in_polygon(centroids, scene.sheet_outline_mm)
    lowest, highest = STRETCH_RANGES[name]
    for pose in scene.poses:
        check_covers(pose, scene.sheet_outline_mm)
        assert pose.object.rest is rest               # one object: the same triangles
        for t in (0.25, 0.5, 1.0):
            points = pose.vertex_positions(t)
            assert points.shape == (len(rest.uv), 3)
            stretches = triangle_stretches(rest.uv, rest.triangles, points)
            assert stretches[:, 1].min() > 0.5, (pose.name, t)            # over the object
            if t == 1.0:
                on = stretches[on_sheet]
                assert on[:, 1].min() > lowest - 0.005, pose.name
                assert on[:, 0].max() < highest + 0.005, pose.name


@pytest.mark.parametrize("name", ("biaxial", "pneumatic", "glove"))
def test_quick_scene_has_the_full_scenes_geometry_and_poses(scenes, name):
    full, quick = scenes[name], scenes[f"{name}_quick"]
    np.testing.assert_array_equal(full.sheet_outline_mm, quick.sheet_outline_mm)
    assert full.poses[0].kind == quick.poses[0].kind
    assert [p.name for p in full.poses] == [p.name for p in quick.poses]
    if full.poses[0].kind == "glue":
        assert [p.generator_parameters for p in full.poses] == \
            [p.generator_parameters for p in quick.poses]
        for a, b in ((full.poses[0].object, quick.poses[0].object),):
            assert a.generator == b.generator
            np.testing.assert_array_equal(a.rest.uv, b.rest.uv)
            np.testing.assert_array_equal(a.rest.triangles, b.rest.triangles)
    else:
        assert full.poses == quick.poses
    assert full.layers == quick.layers  # [multistart]: tests/test_jobs.py (the quick one is smaller)
    for a, b in zip(full.layout.outlines, quick.layout.outlines):
        np.testing.assert_array_equal(a, b)
    assert quick.mesh.edge_length_outline_mm > full.mesh.edge_length_outline_mm
    assert (full.multistart.k_min, full.multistart.k_max) == (2, 6)


@pytest.mark.parametrize("name, training, outside", [("pneumatic", 60, 3), ("glove", 81, 4)])
def test_calibration_families(scenes, name, training, outside):
    for scene in (scenes[name], scenes[f"{name}_quick"]):
        calibration = scene.calibration
        assert len(calibration.training) == training
        assert (~calibration.in_range).sum() == outside


@pytest.mark.slow
def test_quick_biaxial_scene_takes_one_optimisation_step(scenes):
    # About 13 s on a busy 2-core machine (7 s idle): meshing, one evaluation with its
    # gradient and one accepted line-search step.
    pytest.importorskip("igl")
    from mscap.design.pipeline import build_design
    from mscap.geometry.layout import check_layout
    from mscap.design.optimizer import optimize

    scene = scenes["biaxial_quick"]
    result = optimize(build_design(scene), max_iterations=1, cascade_levels=0)
    events = [r.event for r in result.history]
    assert events[0] == "start" and events.count("step") == 1 and events[-1] == "max_iterations"
    assert result.history[1].J < result.history[0].J
    assert result.initial.min_l1_pF > 10.0           # the diamond tells x from y already
    check_layout(result.layout, scene.sheet_outline_mm, scene.min_gap_mm)
