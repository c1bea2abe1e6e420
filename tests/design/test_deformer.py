"""The skinning deformer: exact handle and boundary values, linearity, adjoint, refinement."""

from __future__ import annotations

import time

import numpy as np
import pytest

from mscap.geometry import polygons as geometry
from mscap.design.deformer import (build_deformer, cotangent_stiffness, outer_boundary_vertices,
                            skinning_weights)
from mscap.errors import MeshError
from mscap.geometry.layout import Layout
from mscap.mesh.layered import extrude
from mscap.mesh.triangulate import triangulate
from mscap.scene.settings import MeshSettings
from tests.conftest import SMALL_SCENE, grid_trimesh

igl = pytest.importorskip("igl")

SHEET = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 20.0], [0.0, 20.0]])
LAYOUT = Layout(tuple(np.array(o) for o in SMALL_SCENE["capacitors"]["outlines_mm"]))
STACK_MM = [layer["thickness_mm"] for layer in SMALL_SCENE["layers"]]


@pytest.fixture(scope="module")
def mesh():
    return triangulate(SHEET, LAYOUT, MeshSettings(**SMALL_SCENE["mesh"]))  # 641 vertices


@pytest.fixture(scope="module", params=["bbw", "bbw_fine", "harmonic"])
def deformer(request, mesh):
    method = "harmonic" if request.param == "harmonic" else "bbw"
    return build_deformer(mesh, LAYOUT, spacing_mm=4.0, method=method, coarse=request.param == "bbw")


def random_q(deformer, scale, seed=0):
    return scale * np.random.default_rng(seed).uniform(-1, 1, (deformer.n_controls, 2))


def control_arc_gaps(deformer, i):
    """Arc lengths between consecutive controls along outline ``i``, whether each gap starts at
    a control of ``deformer``'s own, and the longest mesh edge on that outline."""
    chain = deformer.outline_vertices[i]
    points = deformer.rest2d[chain]
    edge = np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)
    arc = np.concatenate([[0.0], np.cumsum(edge[:-1])])[np.isin(chain, deformer.control_vertex)]
    return np.diff(arc, append=arc[0] + edge.sum()), chain[np.isin(chain, deformer.control_vertex)], edge.max()


def test_controls_are_evenly_spaced_outline_vertices(deformer, mesh):
    assert deformer.n_controls == 20  # perimeters 44 and ~37.8 mm at 4 mm: 11 + 9
    for i, outline in enumerate(LAYOUT.outlines):
        controls = deformer.controls[deformer.control_outline == i]
        assert geometry.point_segment_distance(controls, geometry.edges(outline)).min(axis=1).max() < 1e-12
        gaps, _, edge = control_arc_gaps(deformer, i)
        # each control is the outline vertex nearest its sample: off by at most half an edge
        assert np.abs(gaps - gaps.sum() / len(gaps)).max() <= edge + 1e-9


def test_zero_q_gives_rest_mesh_exactly(deformer, mesh):
    layered = extrude(mesh, STACK_MM)
    assert np.array_equal(deformer.points2d(deformer.zeros()), mesh.points)
    assert np.array_equal(deformer.points3d(layered, deformer.zeros()), layered.points)


def test_control_moves_by_its_own_translation(deformer):
    q = random_q(deformer, 1.0)
    assert np.abs(deformer.points2d(q)[deformer.control_vertex] - deformer.controls - q).max() < 1e-14
    assert np.array_equal(deformer.weights[deformer.control_vertex], np.eye(deformer.n_controls))


def test_outer_boundary_stays_fixed(deformer, mesh):
    boundary = outer_boundary_vertices(mesh)
    on_edge = np.isin(mesh.points[boundary, 0], [0, 30]) | np.isin(mesh.points[boundary, 1], [0, 20])
    assert len(boundary) > 20 and on_edge.all()
    assert np.array_equal(deformer.weights[boundary], np.zeros((len(boundary), deformer.n_controls)))
    assert np.array_equal(deformer.points2d(random_q(deformer, 1.0))[boundary], mesh.points[boundary])


def test_weights_are_a_partition_of_unity_with_the_boundary_handle(deformer):
    w = deformer.weights
    assert w.min() >= 0.0 and w.max() <= 1.0
    assert deformer.boundary_weight.min() >= -1e-12  # Σ_j W_ij ≤ 1
    # a control's weight peaks at its control point
    assert np.array_equal(np.argmax(w, axis=0), deformer.control_vertex)


def test_uniform_translation_moves_plates_almost_rigidly(deformer, mesh):
    t = np.array([0.3, -0.2])
    displacement = deformer.points2d(np.tile(t, (deformer.n_controls, 1))) - mesh.points
    total = deformer.weights.sum(axis=1)
    assert np.abs(displacement - total[:, None] * t).max() < 1e-14
    # Plate interiors are enclosed by controls and follow t up to the boundary handle's share
    # leaking through the 4 mm gaps between them. Measured min/mean: coarse bbw 0.892/0.987,
    # bbw on the mesh 0.912/0.993, harmonic 0.660/0.794 (point handles: the weights are spiky).
    # Outline corners between controls sag most (min 0.71 bbw).
    outline = np.concatenate(deformer.outline_vertices)
    plate = np.setdiff1d(mesh.triangles[mesh.capacitor_of_triangle >= 0], outline)
    least, mean = (0.85, 0.95) if deformer.method == "bbw" else (0.6, 0.75)
    assert total[plate].min() > least and total[plate].mean() > mean


def test_deformation_is_linear_in_q(deformer, mesh):
    q1, q2 = random_q(deformer, 1.0, 1), random_q(deformer, 1.0, 2)
    u = deformer.points2d(0.7 * q1 - 1.3 * q2) - mesh.points
    expected = 0.7 * (deformer.points2d(q1) - mesh.points) - 1.3 * (deformer.points2d(q2) - mesh.points)
    assert np.abs(u - expected).max() < 1e-13


def test_vjp_is_the_adjoint_of_the_jacobian(deformer, mesh):
    rng = np.random.default_rng(3)
    q = rng.normal(size=(deformer.n_controls, 2))
    g2 = rng.normal(size=mesh.points.shape)
    lhs, rhs = np.sum(deformer.displacement2d(q) * g2), np.sum(q * deformer.vjp(g2))
    assert abs(lhs - rhs) < 1e-12 * abs(lhs)
    layered = extrude(mesh, STACK_MM)
    g3 = rng.normal(size=layered.points.shape)
    lhs = np.sum((deformer.points3d(layered, q) - layered.points) * g3)
    assert abs(lhs - np.sum(q * deformer.vjp(g3))) < 1e-12 * abs(lhs)


def test_every_level_follows_its_2d_vertex(deformer, mesh):
    layered = extrude(mesh, STACK_MM)
    q = random_q(deformer, 0.5)
    moved = deformer.points3d(layered, q)
    assert np.abs(moved[:, :2] - deformer.points2d(q)[layered.vertex_2d]).max() < 1e-14
    assert np.array_equal(moved[:, 2], layered.points[:, 2])


def test_small_translations_invert_no_triangle(deformer, mesh):
    # controls 4 mm apart, outline edges 0.5 mm: random ±0.1 mm moves shrink no triangle below
    # 0.8 of its area (measured: 0.923 coarse bbw, 0.933 bbw on the mesh, 0.893 harmonic;
    # at ±0.5 mm 0.617, 0.668, 0.468)
    q = random_q(deformer, 0.1, 4)
    moved = type(mesh)(deformer.points2d(q), mesh.triangles, mesh.capacitor_of_triangle)
    assert (moved.areas() / mesh.areas()).min() > 0.8


def test_moved_outlines_are_the_image_of_the_rest_outlines(deformer):
    rest = deformer.outlines(deformer.zeros())
    for polygon, outline in zip(rest, LAYOUT.outlines):
        assert geometry.point_segment_distance(outline, geometry.edges(polygon)).min(axis=1).max() < 1e-12
        assert abs(geometry.signed_area(polygon) - geometry.signed_area(outline)) < 1e-9
    q = random_q(deformer, 0.2, 5)
    moved = deformer.layout(q)
    points = deformer.points2d(q)
    assert np.array_equal(moved.outlines[0], points[deformer.outline_vertices[0]])


def test_refined_doubles_controls_on_the_moved_outlines(deformer):
    q = random_q(deformer, 0.3, 6)
    fine = deformer.refined(q)
    assert fine.n_controls == 2 * deformer.n_controls
    assert np.isin(deformer.control_vertex, fine.control_vertex).all()
    assert np.array_equal(fine.rest2d, deformer.points2d(q))
    old = np.isin(fine.control_vertex, deformer.control_vertex)
    order = np.argsort(deformer.control_vertex)
    assert np.abs(fine.controls[old] - (deformer.controls + q)[order][
        np.searchsorted(deformer.control_vertex[order], fine.control_vertex[old])]).max() < 1e-14
    for i, polygon in enumerate(deformer.outlines(q)):
        controls = fine.controls[fine.control_outline == i]
        assert geometry.point_segment_distance(controls, geometry.edges(polygon)).min(axis=1).max() < 1e-12
        # old and new controls alternate, each new one at the arc midpoint up to half an edge
        gaps, vertex, edge = control_arc_gaps(fine, i)
        old = np.isin(vertex, deformer.control_vertex)
        starts = np.flatnonzero(old)
        assert np.array_equal(np.flatnonzero(~old), (starts + 1) % len(vertex))
        assert np.abs(gaps[starts] - gaps[(starts + 1) % len(vertex)]).max() <= edge + 1e-9
    assert np.array_equal(fine.weights[fine.control_vertex], np.eye(fine.n_controls))
    assert np.array_equal(fine.points2d(fine.zeros()), deformer.points2d(q))


def test_count_per_outline(mesh):
    d = build_deformer(mesh, LAYOUT, count=[4, 6], method="harmonic")
    assert np.bincount(d.control_outline).tolist() == [4, 6]
    assert d.controls[0].tolist() == [3.0, 4.0]  # samples start at each polygon's first vertex


def test_harmonic_weights_match_libigl(mesh):
    d = build_deformer(mesh, LAYOUT, spacing_mm=4.0, method="harmonic")
    stiffness = cotangent_stiffness(mesh.points, mesh.triangles)
    assert np.abs(stiffness + igl.cotmatrix(mesh.points, mesh.triangles)).max() < 1e-12
    handles = np.concatenate([d.control_vertex, outer_boundary_vertices(mesh)])
    values = np.zeros((len(handles), d.n_controls))
    values[np.arange(d.n_controls), np.arange(d.n_controls)] = 1.0
    assert np.abs(d.weights - igl.harmonic(mesh.points, mesh.triangles, handles, values, 1)).max() < 1e-10


def test_coarse_bbw_is_close_to_bbw_on_the_mesh(mesh):
    fine = build_deformer(mesh, LAYOUT, spacing_mm=4.0, coarse=False)
    coarse = build_deformer(mesh, LAYOUT, spacing_mm=4.0)
    # measured: max 0.105, mean 0.0024 (weights solved on 418 vs 641 vertices)
    difference = np.abs(fine.weights - coarse.weights)
    assert difference.mean() < 0.01 and difference.max() < 0.2


def test_outline_not_in_the_mesh_is_an_error():
    grid = grid_trimesh(6, 4, 30.0, 20.0, lambda c: np.full(len(c), -1))
    with pytest.raises(MeshError, match="not embedded"):
        build_deformer(grid, [np.array([[3.0, 4.0], [13.0, 4.0], [13.0, 16.0], [3.0, 16.0]])], count=4)
    with pytest.raises(MeshError, match="outer boundary"):
        skinning_weights(grid, np.array([0, 8]), method="harmonic")


def test_weights_for_10k_vertices():
    # 100 × 100 grid of 0.3 mm cells, one 15 × 15 mm plate on grid lines, 30 controls
    inside = lambda c: np.where((np.abs(c[:, 0] - 15) < 7.5) & (np.abs(c[:, 1] - 15) < 7.5), 0, -1)
    grid = grid_trimesh(100, 100, 30.0, 30.0, inside)
    plate = [np.array([[7.5, 7.5], [22.5, 7.5], [22.5, 22.5], [7.5, 22.5]])]
    times = {}
    for method in ("bbw", "harmonic"):
        start = time.perf_counter()
        d = build_deformer(grid, plate, count=30, method=method)
        times[method] = time.perf_counter() - start
        assert d.weights.shape == (10201, 30) and d.weights.min() >= 0.0
    # Timings are for a reader (about 1 s bbw, 0.3 s harmonic on 2 cores); a test asserts no wall time.
    print(f"10,201 vertices, 30 controls: {times}")
