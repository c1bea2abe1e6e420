"""Glued poses: the Clough–Tocher interpolant, the generators, scene reading, errors."""

from __future__ import annotations

import os
import tomllib

import meshio
import numpy as np
import pytest
from scipy.interpolate import CloughTocher2DInterpolator
from scipy.spatial import Delaunay

from mscap.scene._toml import Table
from mscap.errors import GeometryError, SceneError
from mscap.bodies.glue import (GENERATORS, CloughTocher, GlueObject, GluePose, ParameterError,
                               Placement, Surface, check_covers, register_generator)
from mscap.scene.glue import MAX_SURFACE_BYTES, read_glue_pose, read_objects
from tests.conftest import to_toml

R = 15.0            # cylinder radius (mm) of the convergence study
SCENE = "scene.toml"


def generated(edge_mm, generator="cylinder", width=40.0, height=20.0, **pose):
    """A generated object and one glue pose on it, read through the scene readers."""
    objects = read_objects(Table(SCENE, "objects", {"obj": {
        "generator": generator, "width_mm": width, "height_mm": height,
        "edge_length_mm": edge_mm}}), SCENE)
    keys = {"name": "p", "kind": "glue", "object": "obj", "radius_mm": R} | pose
    return read_glue_pose(Table(SCENE, "poses[0]", keys), objects)


def cylinder_exact(xy, radius=R, axis_u=20.0):
    """The isometric roll of the flat strip onto the cylinder (axis at u = 20, z = −R)."""
    phi = (xy[:, 0] - axis_u) / radius
    return np.column_stack([axis_u + radius * np.sin(phi), xy[:, 1],
                            radius * np.cos(phi) - radius])


def perturbed_grid(n=9, size=10.0, seed=0):
    """Irregular points (a jittered grid) and their Delaunay triangles."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0.0, size, n)
    uv = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    inner = np.all((uv > 0) & (uv < size), axis=1)
    uv[inner] += rng.uniform(-0.3, 0.3, (inner.sum(), 2)) * size / (n - 1)
    return uv, Delaunay(uv).simplices


# --------------------------------------------------------------------------- interpolant

def test_is_scipys_clough_tocher_on_a_delaunay_triangulation():
    rng = np.random.default_rng(0)
    p = rng.uniform(0.0, 10.0, (200, 2))
    f = np.column_stack([np.sin(p[:, 0] / 3) * np.cos(p[:, 1] / 4), p[:, 0] ** 2 / 10,
                         np.exp(p[:, 1] / 10)])
    # scipy's Gauss-Seidel gradient estimate, converged far past its default 1e-6 (at
    # which the two differ by 6e-8; this is an exact solve)
    scipy_ct = CloughTocher2DInterpolator(p, f, tol=1e-13, maxiter=20_000)
    triangles = scipy_ct.tri.simplices
    weights = rng.dirichlet(np.ones(3), 3000)                   # points in random triangles
    q = np.einsum("pk,pkd->pd", weights, p[triangles[rng.integers(len(triangles), size=3000)]])
    ct = CloughTocher(p, triangles)
    mine = ct.evaluate(f, ct.gradients(f), *ct.locate(q))
    np.testing.assert_allclose(mine, scipy_ct(q), rtol=0, atol=1e-13 * np.abs(f).max())


def test_affine_surface_is_reproduced_exactly():
    uv, triangles = perturbed_grid()
    a = np.array([[1.1, 0.2], [-0.3, 0.9], [0.4, -0.5]])        # (3, 2), not a rotation
    c = np.array([1.0, -2.0, 3.0])
    obj = GlueObject("plane", Surface(np.column_stack([uv, np.zeros(len(uv))]), triangles, uv))
    posed = Surface(uv @ a.T + c, triangles, uv)
    placement = Placement((4.0, 1.0), 30.0)
    pose = GluePose("tilted", object=obj, placement=placement, posed=posed)
    xy = np.random.default_rng(1).uniform(0.0, 5.0, (500, 2))
    positions, jacobian = pose.positions_and_jacobian(xy)
    r = placement.rotation
    p = placement.to_parameter(xy) @ a.T + c
    expected = np.column_stack([(p[:, :2] - placement.origin_mm) @ r, p[:, 2]])
    np.testing.assert_allclose(positions, expected, rtol=0, atol=1e-12)
    expected_jacobian = np.vstack([r.T @ a[:2], a[2:]]) @ r
    np.testing.assert_allclose(jacobian, np.broadcast_to(expected_jacobian, jacobian.shape),
                               rtol=0, atol=1e-12)


def test_jacobian_is_the_derivative_and_continuous_across_edges():
    pose = generated(4.0, "dome", radius_mm=30.0, rotation_deg=20.0, origin_mm=[12.0, 2.0])
    rng = np.random.default_rng(2)
    xy = rng.uniform([0.0, 0.0], [18.0, 12.0], (300, 2))
    jacobian = pose.jacobian(xy)
    h = 1e-6
    for d in range(2):
        step = np.zeros(2)
        step[d] = h
        central = (pose.positions(xy + step) - pose.positions(xy - step)) / (2 * h)
        np.testing.assert_allclose(jacobian[:, :, d], central, rtol=0, atol=1e-8)
    # C1: the derivative has no jump across triangle edges nor across the Clough-Tocher
    # split (vertex to centroid), whereas a piecewise-linear surface would jump by O(1).
    ct = pose.object.interpolant
    tri = ct.triangles[ct.neighbors.min(axis=1) >= 0]                  # interior triangles
    p = ct.points[tri]
    mids = np.concatenate([(p[:, 0] + p[:, 1]) / 2,                           # edge
                           (p[:, 0] + (p[:, 0] + p[:, 1] + p[:, 2]) / 3) / 2])  # split
    along = np.concatenate([p[:, 1] - p[:, 0], (p[:, 1] + p[:, 2]) / 2 - p[:, 0]])
    normal = np.column_stack([-along[:, 1], along[:, 0]])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    sheet = pose.placement.to_sheet(mids)
    offset = pose.placement.to_sheet(mids + 1e-7 * normal) - sheet
    inside = np.all((sheet > 0.1) & (sheet < [18.0, 12.0]), axis=1)
    sheet, offset = sheet[inside], offset[inside]
    jump = pose.jacobian(sheet + offset) - pose.jacobian(sheet - offset)
    assert len(sheet) > 20 and np.abs(jump).max() < 1e-6


# --------------------------------------------------------------------------- generators

def test_cylinder_converges_to_the_isometric_roll():
    hs = np.array([2.0, 1.0, 0.5])
    xy = np.random.default_rng(3).uniform([0.0, 0.0], [40.0, 20.0], (3000, 2))
    interior = np.all((xy > [10.0, 5.0]) & (xy < [30.0, 15.0]), axis=1)
    s = np.linspace(0.0, 40.0, 2001)
    lines = [np.column_stack([s, np.full_like(s, y)]) for y in (2.0, 10.0, 18.0)]
    everywhere, inside, arc = [], [], []
    for h in hs:
        pose = generated(h)
        error = np.linalg.norm(pose.positions(xy) - cylinder_exact(xy), axis=1)
        everywhere.append(error.max())
        inside.append(error[interior].max())
        lengths = [np.linalg.norm(np.diff(pose.positions(line), axis=0), axis=1).sum()
                   for line in lines]
        arc.append(np.abs(np.array(lengths) - 40.0).max())
    rate = {name: np.polyfit(np.log(hs), np.log(e), 1)[0]
            for name, e in (("everywhere", everywhere), ("inside", inside), ("arc", arc))}
    # Measured (h = 2, 1, 0.5 mm): max error 1.5e-2, 3.6e-3, 8.6e-4 mm, rate 2.05 (the
    # curvature-minimising gradients are first order at the object's boundary); 5 mm
    # inside it 3.5e-4, 2.1e-5, 2.6e-6 mm, rate 3.5 (cubic element, O(h^3) or better).
    assert rate["everywhere"] > 1.9 and everywhere[-1] < 1e-3
    assert rate["inside"] > 3.0 and inside[-1] < 5e-6
    # Isometric: arc length along the bend preserved (measured 1.2e-3, 1.5e-4, 2.2e-5 mm,
    # rate 2.9).
    assert rate["arc"] > 2.5 and arc[-1] < 5e-5
    # and the metric J^T J is the identity up to the same accuracy
    jacobian = generated(0.5).jacobian(xy[interior])
    metric = np.einsum("pai,paj->pij", jacobian, jacobian)
    np.testing.assert_allclose(metric, np.broadcast_to(np.eye(2), metric.shape),
                               atol=2e-4)                            # measured 1.3e-4


def test_dome_stretches_radially_by_the_spheres_slope():
    radius = 30.0
    pose = generated(0.5, "dome", width=30.0, height=30.0, radius_mm=radius)
    rng = np.random.default_rng(4)
    angle = rng.uniform(0, 2 * np.pi, 200)
    r = rng.uniform(1.0, 10.0, 200)
    e_r = np.column_stack([np.cos(angle), np.sin(angle)])
    e_t = np.column_stack([-np.sin(angle), np.cos(angle)])
    jacobian = pose.jacobian(15.0 + r[:, None] * e_r)
    stretch_r = np.linalg.norm(np.einsum("pad,pd->pa", jacobian, e_r), axis=1)
    stretch_t = np.linalg.norm(np.einsum("pad,pd->pa", jacobian, e_t), axis=1)
    # a vertical lift onto the sphere: |d/dr (r, R - sqrt(R^2 - r^2))| = R / sqrt(R^2 - r^2)
    np.testing.assert_allclose(stretch_r, radius / np.sqrt(radius**2 - r**2), rtol=1e-4)
    np.testing.assert_allclose(stretch_t, 1.0, rtol=1e-4)
    assert stretch_r.max() > 1.04                                     # really stretches


def test_load_fraction_morphs_flat_sheet_into_pose():
    xy = np.random.default_rng(5).uniform([0.0, 0.0], [20.0, 12.0], (400, 2))
    flat = np.column_stack([xy, np.zeros(len(xy))])
    for generator in ("cylinder", "dome"):
        pose = generated(2.0, generator, width=40.0, height=40.0, radius_mm=30.0,
                         origin_mm=[10.0, 5.0], rotation_deg=35.0)
        np.testing.assert_allclose(pose.positions(xy, 0.0), flat, rtol=0, atol=1e-12)
        np.testing.assert_allclose(pose.jacobian(xy, 0.0)[:, :2], np.broadcast_to(
            np.eye(2), (len(xy), 2, 2)), rtol=0, atol=1e-12)
    # t scales the curvature: at t = 1/2 the sheet lies on a cylinder of radius 2R.
    pose = generated(0.5, width=40.0, height=20.0)
    strip = np.random.default_rng(6).uniform([10.0, 5.0], [30.0, 15.0], (300, 2))
    for t, radius in ((0.5, 2 * R), (1.0, R)):
        np.testing.assert_allclose(pose.positions(strip, t), cylinder_exact(strip, radius),
                                   rtol=0, atol=1e-5)


@pytest.fixture
def registry():
    """Register test generators; the registry is restored afterwards."""
    saved = dict(GENERATORS)
    yield register_generator
    GENERATORS.clear()
    GENERATORS.update(saved)


def read_generated(generator, pose):
    objects = read_objects(Table(SCENE, "objects", {"o": {
        "generator": generator, "width_mm": 20.0, "height_mm": 10.0}}), SCENE)
    return read_glue_pose(Table(SCENE, "poses[0]", {"name": "s", "kind": "glue", "object": "o"}
                                | pose), objects)


def test_custom_generator_is_read_with_its_parameters(registry):
    def shear(uv, t, *, slope: float, pivot_mm: tuple[float, float] | None = None):
        if slope == 0:
            raise ParameterError("slope", "must not be 0")
        pivot = np.zeros(2) if pivot_mm is None else np.asarray(pivot_mm)
        return np.column_stack([uv, t * slope * (uv[:, 0] - pivot[0])])

    def lifted(uv, t, *, height_mm: float):            # breaks the contract: t = 0 not flat
        return np.column_stack([uv, np.full(len(uv), height_mm)])

    registry("shear", shear)
    registry("lifted", lifted)
    pose = read_generated("shear", {"slope": 0.5, "pivot_mm": [10.0, 0.0]})
    assert dict(pose.generator_parameters) == {"slope": 0.5, "pivot_mm": (10.0, 0.0)}
    xy = np.array([[4.0, 3.0], [12.0, 7.0]])
    np.testing.assert_allclose(pose.positions(xy)[:, 2], 0.5 * (xy[:, 0] - 10.0), atol=1e-12)
    with pytest.raises(SceneError, match=r"poses\[0\]\.slope: must not be 0"):
        read_generated("shear", {"slope": 0})
    with pytest.raises(SceneError, match=r"poses\[0\]\.slope: missing \(required\)"):
        read_generated("shear", {})
    with pytest.raises(SceneError, match=r"poses\[0\]\.radius_mm: unknown key"):
        read_generated("shear", {"slope": 0.5, "radius_mm": 3.0})
    with pytest.raises(SceneError, match=r"poses\[0\]\.object: generator 'lifted' does not "
                       r"return the flat sheet \(u, v, 0\) at load fraction 0"):
        read_generated("lifted", {"height_mm": 1.0})
    with pytest.raises(TypeError, match="annotated float"):
        registry("untyped", lambda uv, t, *, k: uv)
    def clash(uv, t, *, origin_mm: float):
        return uv

    with pytest.raises(ValueError, match="'origin_mm' is a glue-pose key"):
        registry("clash", clash)
    with pytest.raises(ValueError, match="already registered"):
        registry("cylinder", GENERATORS["cylinder"])


# --------------------------------------------------------------------------- files

def write_surface(path, points, triangles, **point_data):
    meshio.write(path, meshio.Mesh(points, [("triangle", triangles)], point_data=point_data))
    return path.name


def scene_tables(tmp_path, data):
    """``(objects table, pose tables)`` of the scene ``data`` written as TOML."""
    path = tmp_path / SCENE
    path.write_text(to_toml(data))
    root = Table(str(path), "", tomllib.loads(path.read_text()))
    return root.table("objects", required=False), root.tables("poses"), str(path)


@pytest.fixture
def bent_files(tmp_path):
    """A cylinder object's rest and posed surfaces as files (VTU and OBJ), and its pose."""
    pose = generated(2.0)
    rest = pose.object.rest
    posed = pose.vertex_positions(1.0)
    # the rest file is an arbitrary curved object, to show that only its uv matters
    rest_points = np.column_stack([rest.uv, 0.01 * rest.uv[:, 0] ** 2])
    write_surface(tmp_path / "rest.vtu", rest_points, rest.triangles, uv=rest.uv)
    write_surface(tmp_path / "bent.vtu", posed, rest.triangles)
    write_surface(tmp_path / "rest.obj", rest_points, rest.triangles, **{"obj:vt": rest.uv})
    write_surface(tmp_path / "bent.obj", posed, rest.triangles)
    return pose


@pytest.mark.parametrize("suffix, field", [(".vtu", "uv"), (".obj", "obj:vt")])
def test_file_round_trip_matches_the_generated_pose(tmp_path, bent_files, suffix, field):
    objects_table, poses, path = scene_tables(tmp_path, {
        "objects": {"arm": {"rest": "rest" + suffix, "uv_field": field}},
        "poses": [{"name": "bent", "kind": "glue", "object": "arm", "surface": "bent" + suffix,
                   "align": False},
                  {"name": "aligned", "kind": "glue", "object": "arm",
                   "surface": "bent" + suffix}]})
    objects = read_objects(objects_table, path)
    assert objects["arm"].source.endswith("rest" + suffix) and objects["arm"].generator is None
    exact, aligned = (read_glue_pose(t, objects) for t in poses)
    xy = np.random.default_rng(7).uniform([0.0, 0.0], [40.0, 20.0], (500, 2))
    reference, reference_jacobian = bent_files.positions_and_jacobian(xy)
    np.testing.assert_allclose(exact.positions(xy), reference, rtol=0, atol=1e-12)
    np.testing.assert_allclose(exact.jacobian(xy), reference_jacobian, rtol=0, atol=1e-12)
    # align = true moves K_i rigidly: same shape, and object_frame() undoes the move
    positions = aligned.positions(xy)
    np.testing.assert_allclose(aligned.object_frame(positions), reference, rtol=0, atol=1e-10)
    assert not np.allclose(positions, reference, atol=1e-3)
    # t = 0 is the flat sheet whatever the files; a blend stays a blend
    flat = np.column_stack([xy, np.zeros(len(xy))])
    for pose in (exact, aligned):
        np.testing.assert_allclose(pose.positions(xy, 0.0), flat, rtol=0, atol=1e-12)
    np.testing.assert_allclose(exact.positions(xy, 0.25), 0.75 * flat + 0.25 * reference,
                               rtol=0, atol=1e-12)


def test_alignment_brings_a_far_away_pose_onto_the_sheet(tmp_path, bent_files):
    """An object given in some world frame: aligned, the blend path stays near the sheet."""
    rest = bent_files.object.rest
    turn = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    world = bent_files.vertex_positions(1.0) @ turn.T + [500.0, -200.0, 80.0]
    write_surface(tmp_path / "rest.vtu", np.column_stack([rest.uv, np.zeros(len(rest.uv))]),
                  rest.triangles)
    write_surface(tmp_path / "world.vtu", world, rest.triangles)
    objects_table, poses, path = scene_tables(tmp_path, {
        "objects": {"arm": {"rest": "rest.vtu"}},
        "poses": [{"name": "world", "kind": "glue", "object": "arm", "surface": "world.vtu"}]})
    pose = read_glue_pose(poses[0], read_objects(objects_table, path))
    xy = np.random.default_rng(8).uniform([0.0, 0.0], [40.0, 20.0], (300, 2))
    # K_i is the rolled strip, so its best fit to the flat strip is the generator's frame
    # up to a shift along z (a shallow arc's best-fit plane) and tiny rotations.
    moved = pose.positions(xy) - bent_files.positions(xy)
    assert np.abs(moved).max() < 0.5 * R
    np.testing.assert_allclose(pose.object_frame(pose.positions(xy)),
                               bent_files.positions(xy) @ turn.T + [500.0, -200.0, 80.0],
                               rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- coverage

def test_positions_outside_the_object_are_an_error_not_nan():
    pose = generated(2.0)
    inside = pose.positions(np.array([[0.0, 0.0], [40.0, 20.0], [40.0 + 1e-12, 10.0]]))
    assert np.isfinite(inside).all()                      # the boundary itself is covered
    with pytest.raises(GeometryError, match=r"glue pose 'p': 1 of 2 sheet points lie outside "
                       r"the parameter domain of object 'obj'.*first: sheet point \[41\.0, 3\.0\]"):
        pose.positions(np.array([[3.0, 3.0], [41.0, 3.0]]))
    with pytest.raises(ValueError, match="load fraction"):
        pose.positions(np.array([[3.0, 3.0]]), 1.5)


def test_check_covers():
    pose = generated(2.0, origin_mm=[5.0, 2.0], rotation_deg=10.0)
    check_covers(pose, np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 10.0], [0.0, 10.0]]))
    with pytest.raises(GeometryError, match=r"glue pose 'p'.*object 'obj'.*the outline leaves "
                       r"it at sheet point \[\d"):
        check_covers(pose, np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 10.0], [0.0, 10.0]]))
    # the sheet around a hole in the object: the outline is covered, its inside is not
    uv, triangles = perturbed_grid(n=9, size=16.0, seed=1)
    middle = uv[triangles].mean(axis=1)
    keep = np.linalg.norm(middle - 8.0, axis=1) > 1.5
    obj = GlueObject("holed", Surface(np.column_stack([uv, np.zeros(len(uv))]),
                                      triangles[keep], uv))
    holed = GluePose("around_hole", object=obj,
                     posed=Surface(obj.flat_points, triangles[keep], uv))
    with pytest.raises(GeometryError, match=r"'around_hole'.*hole or notch"):
        check_covers(holed, np.array([[4.0, 4.0], [12.0, 4.0], [12.0, 12.0], [4.0, 12.0]]))
    check_covers(holed, np.array([[0.5, 0.5], [5.0, 0.5], [5.0, 5.0], [0.5, 5.0]]))


# --------------------------------------------------------------------------- errors

def read_one(tmp_path, objects, pose=None):
    objects_table, poses, path = scene_tables(
        tmp_path, {"objects": objects, "poses": [pose or {"name": "x", "kind": "free"}]})
    read = read_objects(objects_table, path)
    return read_glue_pose(poses[0], read) if pose else read


@pytest.fixture
def files(tmp_path):
    uv, triangles = perturbed_grid(n=5)
    points = np.column_stack([uv, np.zeros(len(uv))])
    write_surface(tmp_path / "rest.vtu", points, triangles, uv=uv)
    write_surface(tmp_path / "fewer.vtu", points[:-1], triangles[triangles.max(axis=1) < len(uv) - 1])
    write_surface(tmp_path / "flipped.vtu", points, triangles[:, [0, 2, 1]])
    quads = meshio.Mesh(points[:4], [("quad", np.array([[0, 1, 2, 3]]))])
    meshio.write(tmp_path / "quads.vtu", quads)
    collinear = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]])
    write_surface(tmp_path / "flat.vtu", collinear, np.array([[0, 1, 3], [1, 2, 3], [0, 1, 2]]))
    fold = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.3, 0]])
    write_surface(tmp_path / "fold.vtu", fold, np.array([[0, 1, 2], [0, 1, 3]]))
    seam = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0]])
    write_surface(tmp_path / "seam.vtu", seam, np.array([[0, 1, 2], [3, 2, 1]]))
    fan = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, -1, 0], [0.5, 2, 0]])
    write_surface(tmp_path / "fan.vtu", fan, np.array([[0, 1, 2], [0, 1, 3], [1, 0, 4]]))
    write_surface(tmp_path / "unused.vtu", fan, np.array([[0, 1, 2]]))
    os.mkfifo(tmp_path / "pipe.vtu")  # meshio would wait on it for ever
    with open(tmp_path / "huge.vtu", "wb") as f:
        f.truncate(MAX_SURFACE_BYTES + 1)  # sparse: nothing written
    return tmp_path


OBJECT_ERRORS = [
    ({"generator": "twist", "width_mm": 1.0, "height_mm": 1.0},
     r"objects\.o\.generator: unknown generator 'twist'; known: .*cylinder, dome"),
    ({"width_mm": 1.0}, r"objects\.o\.generator: give exactly one of 'generator'"),
    ({"generator": "cylinder", "rest": "rest.vtu"}, r"objects\.o\.generator: give exactly one"),
    ({"generator": "cylinder", "width_mm": -2.0, "height_mm": 1.0},
     r"objects\.o\.width_mm: must be > 0, got -2\.0"),
    ({"generator": "cylinder", "width_mm": 1000.0, "height_mm": 1000.0, "edge_length_mm": 0.5},
     r"objects\.o\.edge_length_mm: 0\.5 mm makes 4000000 cells"),
    ({"generator": "cylinder", "width_mm": 1.0, "height_mm": 1.0, "corner_mm": [1.0]},
     r"objects\.o\.corner_mm\[0\]: expected a point \[x, y\]"),
    ({"rest": "missing.obj"}, r"objects\.o\.rest: cannot read surface file '.*missing\.obj'"),
    ({"rest": "pipe.vtu"}, r"objects\.o\.rest: cannot read surface file '.*pipe\.vtu': not a regular file"),
    ({"rest": "huge.vtu"}, r"objects\.o\.rest: surface file '.*huge\.vtu' has 268435457 bytes; at most 268435456"),
    ({"rest": "quads.vtu"}, r"objects\.o\.rest: '.*quads\.vtu' has quad cells; only triangles"),
    ({"rest": "rest.vtu", "uv_field": "texture"},
     r"objects\.o\.uv_field: '.*rest\.vtu' has no point data 'texture' \(it has: uv\)"),
    ({"rest": "flat.vtu"}, r"objects\.o\.rest: '.*flat\.vtu': unusable parameter-plane "
     r"triangulation: 1 triangles have zero area .*first: triangle 2, vertices \[0, 1, 2\]"),
    ({"rest": "fold.vtu"}, r"objects\.o\.rest: .*folds over at edge \(0, 1\)"),
    ({"rest": "seam.vtu"}, r"objects\.o\.rest: .*points \[1, 3\] share the parameter "
     r"coordinates \[1\.0, 0\.0\]"),
    ({"rest": "fan.vtu"}, r"objects\.o\.rest: .*edge \(0, 1\) is shared by 3 triangles"),
    ({"rest": "unused.vtu"}, r"objects\.o\.rest: .*2 points are in no triangle \(first: "
     r"point 3\)"),
    ({"rest": "rest.vtu", "uv_feild": "uv"},
     r"objects\.o\.uv_feild: unknown key; did you mean 'uv_field'"),
]


@pytest.mark.parametrize("table, message", OBJECT_ERRORS)
def test_object_errors_name_file_key_and_value(files, table, message):
    with pytest.raises(SceneError, match=r"scene\.toml: " + message):
        read_one(files, {"o": table})


POSE_ERRORS = [
    ({"object": "o"}, r"poses\[0\]\.radius_mm: missing \(required\)"),
    ({"object": "o", "radius_mm": 0}, r"poses\[0\]\.radius_mm: must be > 0, got 0\.0"),
    ({"object": "o", "radius_mm": 3.0}, r"poses\[0\]\.radius_mm: radius_mm = 3\.0 wraps the "
     r"object \(10 mm either side of the axis\) .*need radius_mm >= 3\.183"),
    ({"object": "o", "radius_mm": 30.0, "center_mm": [1, 2, 3]},
     r"poses\[0\]\.center_mm\[0\]: expected a point \[x, y\] of two numbers, got \[1, 2, 3\]"),
    ({"object": "o", "radius_mm": 30.0, "surface": "rest.vtu"},
     r"poses\[0\]\.surface: object 'o' is generated by 'cylinder'; give its parameters"),
    ({"object": "arm", "radius_mm": 30.0},
     r"poses\[0\]\.object: unknown object 'arm'; defined: f, o"),
    ({"object": "o", "radius_mm": 30.0, "rotation": 3.0},
     r"poses\[0\]\.rotation: unknown key; did you mean 'rotation_deg'"),
    ({"object": "o", "radius_mm": 30.0, "origin_mm": "middle"},
     r"poses\[0\]\.origin_mm: expected an array, got 'middle'"),
    ({"object": "f"}, r"poses\[0\]\.surface: missing \(required\)"),
    ({"object": "f", "surface": "gone.vtu"},
     r"poses\[0\]\.surface: cannot read surface file '.*gone\.vtu'"),
    ({"object": "f", "surface": "fewer.vtu"}, r"poses\[0\]\.surface: '.*fewer\.vtu' has 24 "
     r"points and \d+ triangles; the rest surface '.*rest\.vtu' has 25 and \d+"),
    ({"object": "f", "surface": "flipped.vtu"}, r"poses\[0\]\.surface: '.*flipped\.vtu' has "
     r"the rest surface's counts but different triangles \(\d+ differ; first: triangle 0"),
    ({"object": "f", "surface": "rest.vtu", "align": "yes"},
     r"poses\[0\]\.align: expected a boolean, got 'yes'"),
    ({"object": "f", "surface": "rest.vtu", "radius_mm": 3.0},
     r"poses\[0\]\.radius_mm: unknown key"),
]


@pytest.mark.parametrize("pose, message", POSE_ERRORS)
def test_pose_errors_name_file_key_and_value(files, pose, message):
    objects = {"o": {"generator": "cylinder", "width_mm": 20.0, "height_mm": 5.0,
                     "edge_length_mm": 5.0},
               "f": {"rest": "rest.vtu", "uv_field": "uv"}}
    with pytest.raises(SceneError, match=r"scene\.toml: " + message):
        read_one(files, objects, {"name": "p", "kind": "glue"} | pose)


def test_pose_of_another_kind_and_no_objects(files):
    with pytest.raises(SceneError, match=r"poses\[0\]\.kind: expected 'glue', got 'poke'"):
        read_glue_pose(Table(SCENE, "poses[0]", {"name": "p", "kind": "poke"}), {})
    with pytest.raises(SceneError, match=r"unknown object 'arm'; defined: none; add an "
                       r"\[objects\.NAME\] table"):
        read_glue_pose(Table(SCENE, "poses[0]", {"name": "p", "kind": "glue", "object": "arm"}),
                       read_objects(None, SCENE))
    with pytest.raises(SceneError, match=r"objects\.o: expected a table, got 3"):
        read_objects(Table(SCENE, "objects", {"o": 3}), SCENE)


def test_dome_radius_must_exceed_the_object(files):
    with pytest.raises(SceneError, match=r"poses\[0\]\.radius_mm: radius_mm = 10\.0 is not "
                       r"larger than the object's largest distance from the centre \(14\.14"):
        generated(5.0, "dome", width=20.0, height=20.0, radius_mm=10.0)


def test_surface_arrays_are_read_only():
    pose = generated(5.0)
    with pytest.raises(ValueError):
        pose.object.rest.uv[0, 0] = 1.0
    with pytest.raises(ValueError):
        pose.alignment[0, 0] = 2.0
