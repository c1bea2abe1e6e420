"""The wrist and joystick generators: exact kinematics, parameter checks, the scenes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mscap.bodies.basic import _wrist_bend, cantilever, cylinder, wrist
from mscap.bodies.glue import _grid, check_covers
from mscap.scene.glue import read_glue_pose, read_objects
from mscap.bodies.kinematics import ParameterError
from mscap.bodies.registry import GENERATORS
from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene._toml import Table

JOBS = Path(__file__).resolve().parents[2] / "jobs"
SCENES = ("wrist", "wrist_quick", "joystick", "joystick_quick")
SCENE = "scene.toml"

R = 10.0            # stick / tube radius (mm) of the unit tests
WRIST = {"radius_mm": R, "joint_mm": 30.0, "blend_mm": 20.0}
STICK = {"radius_mm": R, "length_mm": 40.0}


def strip(width=50.0, height=60.0, corner=(-5.0, -10.0), edge=1.0):
    """The object's parameter points and triangles: a rectangle (corner off the origin,
    so that the contact line u = 20 is not u = 0)."""
    surface = _grid(width, height, corner, edge)
    return surface.uv, surface.triangles


def triangle_areas(points, triangles):
    a, b, c = (points[triangles[:, i]] for i in range(3))
    cross = np.cross(b - a, c - a)
    return 0.5 * (np.linalg.norm(cross, axis=1) if cross.ndim == 2 else np.abs(cross))


def circle_centres(points, per_section):
    """Centres of the circles through cross-sections given as consecutive blocks of
    ``per_section`` points that sample a full circle uniformly (the mean of the block)."""
    return points.reshape(-1, per_section, 3).mean(axis=1)


def full_circle(v, n_around=64):
    """uv points that go exactly once around a stick of radius R (u in [-πR, πR)) at
    each v; blocks of ``n_around`` points per cross-section."""
    u = -math.pi * R + 2 * math.pi * R * np.arange(n_around) / n_around
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


# --------------------------------------------------------------------------- t = 0 and zero angles

@pytest.mark.parametrize("generator, parameters", [
    (wrist, WRIST | {"flexion_deg": 40.0, "deviation_deg": -15.0}),
    (cantilever, STICK | {"tilt_deg": 45.0, "direction_deg": 30.0}),
])
def test_load_fraction_zero_is_the_flat_sheet_exactly(generator, parameters):
    uv, _ = strip()
    flat = generator(uv, 0.0, **parameters)
    np.testing.assert_array_equal(flat, np.column_stack([uv, np.zeros(len(uv))]))


def test_zero_angles_are_the_isometric_roll():
    uv, _ = strip()
    for t in (0.3, 1.0):
        rolled = cylinder(uv, t, radius_mm=R)
        np.testing.assert_array_equal(wrist(uv, t, **WRIST), rolled)
        np.testing.assert_array_equal(cantilever(uv, t, **STICK), rolled)
    # The roll itself, in closed form: every point at distance R from the axis
    # (u = 20, z = -R), at the angle (u - 20)/R from the top, v unchanged.
    p = cylinder(uv, 1.0, radius_mm=R)
    phi = (uv[:, 0] - 20.0) / R
    np.testing.assert_allclose(p, np.column_stack([20.0 + R * np.sin(phi), uv[:, 1],
                                                   R * np.cos(phi) - R]), atol=1e-12)
    np.testing.assert_allclose(np.hypot(p[:, 0] - 20.0, p[:, 2] + R), R, atol=1e-12)


# --------------------------------------------------------------------------- cantilever

def test_cantilever_axis_is_a_circle_arc_and_sections_stay_rigid():
    tilt, direction, length = 50.0, 120.0, STICK["length_mm"]
    v = np.linspace(0.0, length, 9)
    uv = full_circle(v)
    p = cantilever(uv, 1.0, **STICK, tilt_deg=tilt, direction_deg=direction)
    straight = cylinder(uv, 1.0, radius_mm=R)
    axis_u = 0.5 * (uv[:, 0].min() + uv[:, 0].max())
    base = np.array([axis_u, 0.0, -R])
    d = np.array([math.cos(math.radians(direction)), 0.0, math.sin(math.radians(direction))])
    bend_radius = length / math.radians(tilt)
    centres = circle_centres(p, 64)
    # The axis lies on the circle of radius length/tilt through the base, in the plane
    # of e_v and d, centred bend_radius towards d; the arc length to v is v.
    np.testing.assert_allclose(np.linalg.norm(centres - (base + bend_radius * d), axis=1),
                               bend_radius, rtol=1e-12)
    angle = v / bend_radius
    expected = (base + bend_radius * np.sin(angle)[:, None] * np.array([0.0, 1.0, 0.0])
                + bend_radius * (1 - np.cos(angle))[:, None] * d)
    np.testing.assert_allclose(centres, expected, atol=1e-10)
    # Rigid cross-sections: distances within each section are those of the straight stick,
    # and every section is perpendicular to the axis tangent.
    sections, rest_sections = p.reshape(len(v), 64, 3), straight.reshape(len(v), 64, 3)
    for section, rest in zip(sections, rest_sections):
        np.testing.assert_allclose(np.linalg.norm(section[:, None] - section[None], axis=-1),
                                   np.linalg.norm(rest[:, None] - rest[None], axis=-1),
                                   atol=1e-10)
    tangent = np.column_stack([np.zeros_like(angle), np.cos(angle), np.zeros_like(angle)]) \
        + np.sin(angle)[:, None] * d
    offsets = sections - centres[:, None]
    np.testing.assert_allclose(np.einsum("sni,si->sn", offsets, tangent), 0.0, atol=1e-10)


def test_cantilever_is_clamped_below_the_base_and_straight_beyond_the_tip():
    length = STICK["length_mm"]
    parameters = STICK | {"tilt_deg": 60.0, "direction_deg": 200.0}
    below = full_circle(np.array([-5.0, -1.0, 0.0]))
    np.testing.assert_allclose(cantilever(below, 1.0, **parameters),
                               cylinder(below, 1.0, radius_mm=R), atol=1e-12)
    # Beyond the tip each section is the tip section moved along the tip's tangent.
    tip, beyond = full_circle(np.array([length])), full_circle(np.array([length + 7.0]))
    tip_p, beyond_p = cantilever(tip, 1.0, **parameters), cantilever(beyond, 1.0, **parameters)
    angle = math.radians(60.0)
    d = np.array([math.cos(math.radians(200.0)), 0.0, math.sin(math.radians(200.0))])
    tangent = np.array([0.0, math.cos(angle), 0.0]) + math.sin(angle) * d
    np.testing.assert_allclose(beyond_p - tip_p, np.broadcast_to(7.0 * tangent, tip_p.shape),
                               atol=1e-10)
    # The axis is C1 across the clamp and the tip (one-sided difference quotients of the
    # section centres agree); the surface only C0: its stretch along v jumps from 1 to
    # 1 - kappa r.d where the curvature switches on (documented).
    h = 1e-5
    for v0 in (0.0, length):
        centre = [circle_centres(cantilever(full_circle(np.array([v])), 1.0, **parameters), 64)[0]
                  for v in (v0 - h, v0, v0 + h)]
        np.testing.assert_allclose((centre[2] - centre[1]) / h, (centre[1] - centre[0]) / h,
                                   atol=1e-4)


def test_cantilever_stretches_the_outside_and_compresses_the_inside_by_kappa_r():
    # Tilt towards +z (90°): the top line (u = 20) is on the inside of the bend.
    parameters = STICK | {"tilt_deg": 45.0, "direction_deg": 90.0}
    kappa = math.radians(45.0) / STICK["length_mm"]
    h = 1e-3
    uv = np.array([[20.0, 10.0], [20.0, 10.0 + h],                        # top
                   [20.0 + math.pi * R, 10.0], [20.0 + math.pi * R, 10.0 + h]])  # bottom
    bigger = np.vstack([uv, [[20.0 - math.pi * R, 0.0]]])   # keeps the centre at u = 20
    p = cantilever(bigger, 1.0, **parameters)
    top = np.linalg.norm(p[1] - p[0]) / h
    bottom = np.linalg.norm(p[3] - p[2]) / h
    assert top == pytest.approx(1 - kappa * R, rel=1e-9)
    assert bottom == pytest.approx(1 + kappa * R, rel=1e-9)


# --------------------------------------------------------------------------- wrist

def hand_rotation(flexion_deg, deviation_deg, t=1.0):
    """The documented hand rotation R_x(-t flexion) R_z(-t deviation), built by scipy."""
    return Rotation.from_euler("XZ", [-t * flexion_deg, -t * deviation_deg],
                               degrees=True).as_matrix()


def test_wrist_forearm_is_unchanged_and_hand_is_rigidly_rotated():
    uv, _ = strip()
    flexion, deviation = 35.0, -20.0
    for t in (0.5, 1.0):
        p = wrist(uv, t, **WRIST, flexion_deg=flexion, deviation_deg=deviation)
        rolled = cylinder(uv, t, radius_mm=R)
        joint, half = WRIST["joint_mm"], 0.5 * WRIST["blend_mm"]
        forearm, hand = uv[:, 1] <= joint - half, uv[:, 1] >= joint + half
        assert forearm.sum() > 100 and hand.sum() > 100
        np.testing.assert_array_equal(p[forearm], rolled[forearm])
        pivot = np.array([20.0, joint, -R])
        np.testing.assert_allclose(p[hand], (rolled[hand] - pivot)
                                   @ hand_rotation(flexion, deviation, t).T + pivot, atol=1e-12)


def test_wrist_sign_conventions():
    # Flexion > 0 bends the hand towards -z (away from the sheet on top), deviation > 0
    # towards +u; the top line of the forearm stays put.
    uv = np.array([[0.0, 0.0], [40.0, 0.0], [20.0, 0.0], [20.0, 60.0]])
    flexed = wrist(uv, 1.0, **WRIST, flexion_deg=30.0)
    deviated = wrist(uv, 1.0, **WRIST, deviation_deg=30.0)
    assert flexed[3, 2] < -10.0 and abs(flexed[3, 0] - 20.0) < 1e-12
    assert deviated[3, 0] > 30.0 and abs(deviated[3, 2]) < 1e-12
    np.testing.assert_array_equal(flexed[2], [20.0, 0.0, 0.0])


def test_wrist_area_check_is_the_surface_jacobian():
    # The refusal uses the analytic area ratio |dp/du x dp/dv|: central differences agree.
    uv = np.random.default_rng(0).uniform([-5.0, -10.0], [45.0, 50.0], (2000, 2))
    h = 1e-6
    for flexion, deviation in ((-30.0, 0.0), (20.0, 25.0), (-40.0, -30.0)):
        _, ratio = _wrist_bend(uv, uv[:, 0] - 20.0, 1.0, R, np.array([20.0, WRIST["joint_mm"], -R]),
                               flexion, deviation, WRIST["blend_mm"], need_ratio=True)
        parameters = WRIST | {"flexion_deg": flexion, "deviation_deg": deviation,
                              "center_mm": (20.0, 0.0)}
        d_u, d_v = ((wrist(uv + step, 1.0, **parameters) - wrist(uv - step, 1.0, **parameters))
                    / (2 * h) for step in (np.array([h, 0.0]), np.array([0.0, h])))
        np.testing.assert_allclose(ratio, np.linalg.norm(np.cross(d_u, d_v), axis=1), atol=1e-7)
    # 30° extension over a 20 mm blend compresses the top to 0.58 of its area (about
    # 1 - 1.5 R a / b = 0.61); 60° would leave 0.12 and is refused.
    uv, triangles = strip(edge=0.5)
    areas = triangle_areas(wrist(uv, 1.0, **WRIST, flexion_deg=-30.0), triangles)
    assert (areas / triangle_areas(uv, triangles)).min() == pytest.approx(0.58, abs=0.01)
    with pytest.raises(ParameterError) as error:
        wrist(uv, 1.0, **WRIST, flexion_deg=-60.0)
    assert error.value.parameter == "flexion_deg"
    assert "of its area" in str(error.value)


# --------------------------------------------------------------------------- parameters

PARAMETER_ERRORS = [
    ("wrist", WRIST | {"radius_mm": 0.0}, "radius_mm", "must be > 0"),
    ("wrist", WRIST | {"radius_mm": 5.0}, "radius_mm", "more than once around the tube"),
    ("wrist", WRIST | {"blend_mm": 0.0}, "blend_mm", "must be > 0"),
    ("wrist", WRIST | {"flexion_deg": 95.0}, "flexion_deg", r"must lie in \[-90, 90\]"),
    ("wrist", WRIST | {"deviation_deg": -91.0}, "deviation_deg", r"must lie in \[-90, 90\]"),
    ("wrist", WRIST | {"flexion_deg": -60.0}, "flexion_deg",
     "compress the surface to 0.1.* of its area"),
    ("wrist", WRIST | {"blend_mm": 5.0, "deviation_deg": 45.0}, "deviation_deg",
     r"fold the surface over \(signed area ratio -"),
    ("cantilever", STICK | {"radius_mm": -1.0}, "radius_mm", "must be > 0"),
    ("cantilever", STICK | {"length_mm": 0.0}, "length_mm", "must be > 0"),
    ("cantilever", STICK | {"tilt_deg": -190.0}, "tilt_deg", r"must lie in \[-180, 180\]"),
    ("cantilever", STICK | {"tilt_deg": 180.0, "length_mm": 30.0}, "tilt_deg",
     "curvature x radius = 1.05 >= 1"),
]


@pytest.mark.parametrize("generator, parameters, key, message", PARAMETER_ERRORS)
def test_out_of_range_parameters_name_the_key(generator, parameters, key, message):
    objects = read_objects(Table(SCENE, "objects", {"o": {
        "generator": generator, "width_mm": 50.0, "height_mm": 60.0,
        "corner_mm": [-5.0, -10.0], "edge_length_mm": 2.0}}), SCENE)
    keys = {"name": "p", "kind": "glue", "object": "o"} | parameters
    with pytest.raises(SceneError, match=rf"scene\.toml: poses\[0\]\.{key}: .*{message}"):
        read_glue_pose(Table(SCENE, "poses[0]", keys), objects)


def test_generators_are_registered():
    assert GENERATORS["wrist"] is wrist and GENERATORS["cantilever"] is cantilever


# --------------------------------------------------------------------------- scenes

@pytest.fixture(scope="module")
def scenes():
    return {name: load_scene(JOBS / f"{name}.toml") for name in SCENES}


@pytest.mark.parametrize("name", SCENES)
def test_scene_poses_cover_the_sheet_without_degenerate_triangles(scenes, name):
    scene = scenes[name]
    assert len(scene.poses) == 9 and all(p.kind == "glue" for p in scene.poses)
    objects = {p.object_name for p in scene.poses}
    assert len(objects) == 1                          # one object: one triangulation
    rest = scene.poses[0].object.rest
    rest_areas = triangle_areas(rest.uv, rest.triangles)
    for pose in scene.poses:
        check_covers(pose, scene.sheet_outline_mm)
        assert pose.object.rest is rest
        for t in (0.25, 0.5, 1.0):
            ratio = triangle_areas(pose.vertex_positions(t), rest.triangles) / rest_areas
            # The poses stay within 40 % compression (docs/scenes.md); 0.5 leaves margin.
            assert ratio.min() > 0.5, (pose.name, t, ratio.min())


@pytest.mark.parametrize("name", ("wrist", "joystick"))
def test_quick_scene_has_the_full_scenes_geometry_and_poses(scenes, name):
    full, quick = scenes[name], scenes[f"{name}_quick"]
    np.testing.assert_array_equal(full.sheet_outline_mm, quick.sheet_outline_mm)
    assert [p.name for p in full.poses] == [p.name for p in quick.poses]
    assert [p.generator_parameters for p in full.poses] == \
        [p.generator_parameters for p in quick.poses]
    np.testing.assert_array_equal(full.poses[0].object.rest.uv, quick.poses[0].object.rest.uv)
    assert full.layers == quick.layers  # [multistart]: tests/test_jobs.py (the quick one is smaller)
    assert len(full.layout.outlines) == len(quick.layout.outlines)
    assert quick.mesh.edge_length_outline_mm > full.mesh.edge_length_outline_mm
