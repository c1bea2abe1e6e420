"""The 2D mesh quality mscap keeps (mscap/mesh/shape.py) wherever plates go: near the sheet
edge, near each other, in the corners, any shape; and the capacitance it buys."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

from mscap.fem.electrostatic import build_problem, solve
from mscap.geometry.layout import Layout, check_layout
from mscap.mesh.layered import extrude
from mscap.mesh.shape import MAX_SIZE_RATIO, MIN_ANGLE_DEG, assess, neighbour_size_ratios, outline_angles_deg
from mscap.mesh.triangulate import triangulate
from mscap.scene.settings import Layer, MeshSettings
from mscap.scene.sizing import predicted_errors, settings_for_tolerance
from tests.scenes import CARBON, CLEAR, KINDS, STACK_MM

LAYERS = [Layer(f"l{i}", kind, t, CARBON if kind == "conductive" else CLEAR, CLEAR if kind == "conductive" else None)
          for i, (kind, t) in enumerate(zip(KINDS, STACK_MM))]
GAP_MM, STACK = STACK_MM[2], sum(STACK_MM)


def rectangle(w, h, x0=0.0, y0=0.0):
    return np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + h], [x0, y0 + h]], dtype=float)


def default_settings(outlines) -> MeshSettings:
    """The sizes a scene without ``[mesh]`` gets: the 1 % tolerance rung for these plates."""
    return settings_for_tolerance(0.01, outlines, GAP_MM, STACK)[0]


def capacitance(sheet, outlines, settings):
    mesh2d = triangulate(sheet, Layout(tuple(outlines)), settings)
    mesh = extrude(mesh2d, STACK_MM, settings.elements_per_layer)
    return np.asarray(solve(build_problem(mesh, LAYERS, settings.order, settings.element)).capacitance_pF), mesh2d


def test_measures_of_known_triangles():
    # a unit square split along its diagonal (areas 0.5, 0.5) and a triangle of area 1
    # beside it (size ratio √2).
    points = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [3.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    ratios, pairs = neighbour_size_ratios(points, triangles)
    by_pair = {tuple(sorted(p)): r for p, r in zip(pairs.tolist(), ratios)}
    assert by_pair == {(0, 1): pytest.approx(1.0), (0, 2): pytest.approx(np.sqrt(2.0))}  # areas 0.5, 0.5, 1
    np.testing.assert_allclose(outline_angles_deg(rectangle(2, 1)), 90.0)
    spike = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 1.0]])
    np.testing.assert_allclose(outline_angles_deg(spike).min(), np.degrees(np.arctan(0.1)))


def test_a_sliver_fan_is_found_and_named():
    # gmsh's old mesh beside a 6 mm plate 3 mm from the sheet edge: a 0.07 mm outline
    # segment joined to a sheet-edge node 3 mm away (1.19 deg), next to a better triangle;
    # the worst is named by its centroid ((3 + 4.1 + 3.07) / 3, (3 + 0 + 3) / 3).
    points = np.array([[3.0, 3.0], [3.07, 3.0], [4.1, 0.0], [3.0, 2.0]])
    quality = assess(points, np.array([[0, 2, 1], [0, 3, 2]]), [rectangle(6, 6, 3, 3)], rectangle(12, 12))
    assert not quality.meets and quality.min_angle_deg < 1.5
    assert quality.worst_near == "outline 0" and "(3.390, 2.000)" in quality.describe()


@pytest.mark.parametrize("plate, margin", [(6.0, 3.0), (6.0, 3.5), (12.0, 4.0), (20.0, 3.0)])
def test_plates_near_the_sheet_edge_get_a_good_mesh_and_their_capacitance(plate, margin):
    """The cases of issue 44: at the default sizes a 6 mm square 3 mm from the sheet edge
    read +52 % (min angle 0.96 deg), a 12 mm one at 4 mm +22 %. Now every angle ≥ 15 deg,
    neighbours within 3× in size, and C within 1 % of the plate alone (the P2 Richardson
    references of docs/plate_size.csv, 10 mm from everything: at 3 mm the fringe has
    decayed to exp(−π 3 / 0.56) ≈ 5e-8; the 6 mm square's own reference at 3 mm,
    6.8942 pF, is 0.1 % lower: benchmarks/mesh_quality.py --check-margin)."""
    alone = {6.0: 6.90142, 12.0: None, 20.0: 73.2813}[plate]
    outline = rectangle(plate, plate, margin, margin)
    sheet = rectangle(plate + 2 * margin, plate + 2 * margin)
    settings = default_settings([outline])
    c, mesh2d = capacitance(sheet, [outline], settings)
    assert mesh2d.quality.meets, mesh2d.quality.describe()
    assert mesh2d.quality.min_angle_deg >= MIN_ANGLE_DEG and mesh2d.quality.max_size_ratio <= MAX_SIZE_RATIO
    bound = float(predicted_errors(replace_rung(settings), [outline], GAP_MM)[0])
    if alone is not None:
        assert 0.0 < c[0] / alone - 1 < min(0.01, bound + 0.002), (c[0], alone)


def replace_rung(settings):
    """The ladder rung of ``settings`` (its predicted error per plate)."""
    from mscap.scene.sizing import LADDER

    return next(r for r in LADDER if r.order == settings.order and r.element == settings.element
                and abs(r.outline_over_gap * GAP_MM - settings.edge_length_outline_mm) < 1e-12
                and r.slope == settings.fringe_slope)


def random_layout(rng, sheet_w=30.0, sheet_h=24.0, tries=200):
    """2–4 random star-shaped plates (5–12 vertices, radii 1.5–6 mm), anywhere they fit:
    0.25–2 mm from each other and 1–4 mm from the sheet edge included."""
    sheet = rectangle(sheet_w, sheet_h)
    for _ in range(tries):
        outlines = []
        for _ in range(rng.integers(2, 5)):
            n = rng.integers(5, 13)
            angle = np.sort(rng.uniform(0, 2 * np.pi, n))
            radius = rng.uniform(1.5, 6.0) * rng.uniform(0.6, 1.0, n)
            centre = rng.uniform([3.0, 3.0], [sheet_w - 3.0, sheet_h - 3.0])
            outlines.append(centre + np.c_[radius * np.cos(angle), radius * np.sin(angle)])
        try:
            check_layout(Layout(tuple(outlines)), sheet, 0.25)
        except Exception:
            continue
        if min(outline_angles_deg(o).min() for o in outlines) > 8.0:
            return sheet, outlines
    raise AssertionError("no random layout fitted")


def test_random_layouts_keep_the_quality(caplog):
    """40 random layouts at the default sizes and at the paper's hand-set sizes: every mesh
    keeps the quality (angles ≥ min(15 deg, the outlines' sharpest vertex), neighbours
    within 3×), without a warning."""
    rng = np.random.default_rng(44)
    hand_set = MeshSettings(5.0, 0.075, 2.5, 1, 1)
    caplog.set_level(logging.WARNING, logger="mscap.mesh.triangulate")
    for _ in range(20):
        sheet, outlines = random_layout(rng)
        for settings in (default_settings(outlines), hand_set):
            mesh2d = triangulate(sheet, Layout(tuple(outlines)), settings)
            assert mesh2d.quality.meets, mesh2d.quality.describe()
    assert not caplog.records


def test_random_layouts_stay_within_their_error_bound():
    """Two random layouts: the default mesh's C and the finest ladder rung's (P2, outline
    d/2, two elements per layer, e/ε = 0.017) differ by no more than the tolerance model
    predicts for the two (about 35 s; the P2 rung at outline d, e/ε = 0.05, read these
    star-shaped plates 0.4-0.7 % above the default prisms: too rough to judge them)."""
    from mscap.scene.sizing import TET_LADDER, rung_settings

    rng = np.random.default_rng(7)
    finest = TET_LADDER[-1]
    for _ in range(2):
        sheet, outlines = random_layout(rng, 20.0, 16.0)
        settings = default_settings(outlines)
        c, _ = capacitance(sheet, outlines, settings)
        c_fine, _ = capacitance(sheet, outlines, rung_settings(finest, GAP_MM, STACK))
        bound = predicted_errors(replace_rung(settings), outlines, GAP_MM) + predicted_errors(finest, outlines, GAP_MM)
        assert np.all(np.abs(c / c_fine - 1) <= bound), (c / c_fine - 1, bound)


def test_a_mesh_that_misses_the_quality_is_made_again_or_named(monkeypatch, caplog):
    """Without its feature and corner bounds the mesher leaves the 6 mm plate's needles:
    the first mesh misses the quality, the second (every slope halved) meets it; and one
    that cannot be repaired is kept with a warning naming where."""
    from mscap.mesh import triangulate as module

    outline, sheet = rectangle(6, 6, 3, 3), rectangle(12, 12)
    settings = default_settings([outline])
    caplog.set_level(logging.INFO, logger="mscap.mesh.triangulate")
    monkeypatch.setattr(module, "FEATURE_FRACTION", 1e6)
    monkeypatch.setattr(module, "MAX_SLOPE", 4.0)
    monkeypatch.setattr(module, "CORNER_SLOPE", 4.0)
    mesh2d = triangulate(sheet, Layout((outline,)), settings)
    assert mesh2d.quality.repaired and "meshing again" in caplog.text
    real = module._triangulate
    monkeypatch.setattr(module, "_triangulate", lambda s, layout, m, gentle: real(s, layout, m, 1.0))
    caplog.clear()
    mesh2d = triangulate(sheet, Layout((outline,)), settings)
    assert not mesh2d.quality.meets
    warning = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warning) == 1 and "near outline 0" in warning[0] and "worst triangle at (" in warning[0]
    # the skinning weights' mesh (no capacitance on it) says the same at the info level only
    caplog.clear()
    mesh2d = triangulate(sheet, Layout((outline,)), settings, auxiliary=True)
    assert not mesh2d.quality.meets and "below the quality" in caplog.text
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
