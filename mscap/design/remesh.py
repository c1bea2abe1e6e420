"""Remeshing during an optimisation: when a 2D angle of either mesh degrades, the sheet
is meshed afresh from the current outlines (resampled at the mesh's outline spacing,
corners kept) and each pose's displacement is interpolated onto the new elastic mesh
for the warm start."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from mscap.design.pipeline import Design, Evaluation, build_design
from mscap.geometry.layout import Layout, check_layout
from mscap.geometry.polygons import turning
from mscap.mesh.shape import neighbour_size_ratios, triangle_angles_deg
from mscap.fem.transfer import interpolation_matrix

__all__ = ["remesh", "resample_outline", "resampled_layout", "needs_remesh", "min_angle", "size_ratio",
           "control_counts"]

log = logging.getLogger(__name__)


def resample_outline(polygon: np.ndarray, spacing_mm: float, corner_deg: float = 20.0) -> np.ndarray:
    """A closed polyline resampled at about ``spacing_mm`` along its arc, keeping the
    vertices where it turns by more than ``corner_deg`` (the plate corners)."""
    polygon = np.asarray(polygon, dtype=float)
    corner = np.flatnonzero(turning(polygon, corner_deg))
    if not len(corner):
        corner = np.array([0])
    pieces = []
    for a, b in zip(corner, np.roll(corner, -1)):
        idx = np.arange(a, (b if b > a else b + len(polygon)) + 1) % len(polygon)
        chain = polygon[idx]
        seg = np.linalg.norm(np.diff(chain, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        n = max(1, int(np.ceil(arc[-1] / spacing_mm - 1e-9)))
        s = arc[-1] * np.arange(n) / n
        pieces.append(np.c_[np.interp(s, arc, chain[:, 0]), np.interp(s, arc, chain[:, 1])])
    return np.vstack(pieces)


def resampled_layout(outlines, spacing_mm: float, finest_mm: float, scene) -> Layout:
    """``outlines`` resampled at ``spacing_mm``, and an outline whose resampling makes the
    layout invalid resampled again at half the spacing, down to ``finest_mm``, then taken
    as it is.

    A chord of an optimised outline can cut across a narrow neck of it: a poking paper
    start at k = 6 failed after 467 s at a remesh whose 1.2 mm chords made outline 3 cross
    itself (edges 0 and 10), though the outline itself was valid. The outlines as they
    are always pass (the optimiser's barrier keeps them valid); a layout that still fails
    raises :class:`~mscap.errors.GeometryError`, as before."""
    from mscap.errors import GeometryError

    outlines = [np.asarray(o, dtype=float) for o in outlines]
    spacings = [spacing_mm] * len(outlines)
    current = [resample_outline(o, spacing_mm) for o in outlines]
    while True:
        layout = Layout(tuple(current))
        try:
            check_layout(layout, scene.sheet_outline_mm, scene.min_gap_mm)
            return layout
        except GeometryError as exc:
            j = exc.capacitor
            if j is not None and current[j] is not outlines[j]:
                spacings[j] *= 0.5
                current[j] = resample_outline(outlines[j], spacings[j]) if spacings[j] >= finest_mm else outlines[j]
                log.info("remesh: %s; resampling outline %d at %.3g mm", exc, j, spacings[j])
            elif any(c is not o for c, o in zip(current, outlines)):  # another outline's chords
                log.info("remesh: %s; taking every outline as it is", exc)
                current = list(outlines)
            else:
                raise


def control_counts(design: Design) -> np.ndarray:
    """The number of controls on each outline of ``design`` (what a remesh keeps)."""
    return np.bincount(design.deformer.control_outline, minlength=len(design.sheet.layout.outlines))


def remesh(design: Design, evaluation: Evaluation, outlines=None) -> tuple[Design, list]:
    """A new design meshed from the outlines at ``evaluation.q`` (or from ``outlines``: a
    revived plate's, :mod:`mscap.design.revival`), resampled at the scene's outline edge
    length, the same number of controls per outline, and each pose's displacement
    interpolated onto the new elastic mesh (the warm start)."""
    scene = design.scene
    # Polygon vertices about every half elastic outline edge: each vertex is also embedded
    # in the elastic mesh, so resampling at the fine outline spacing would refine the
    # elastic mesh to it (16× the elements on the poking scene). The chordal error of
    # 1.2 mm chords on a 10 mm radius is 0.02 mm. The chord is a whole number of fine
    # outline edges: gmsh splits each chord into ceil(chord / edge) pieces, and shorter
    # edges than the scene's would change the capacitance (by 4 % on a 1 mm mesh).
    elastic, edge = scene.elastic, design.sheet.mesh.edge_length_outline_mm  # the run's sizes
    half = 0.5 * min(elastic.edge_length_outline_mm or 0.5 * elastic.edge_length_mm, elastic.edge_length_mm)
    spacing = edge * max(1, int(np.floor(half / edge + 1e-9)))
    outlines = design.deformer.outlines(evaluation.q) if outlines is None else outlines
    layout = resampled_layout(outlines, spacing, edge, scene)
    new = replace(build_design(scene, sheet=replace(design.sheet, layout=layout), count=control_counts(design),
                               objective=design.objective, poses=design.designed),
                  wiring=design.wiring)  # re-routed by the optimiser
    warm = [None] * len(design.poses)
    old = evaluation.sim.elastic
    if old is not None and new.base.elastic is not None:
        mapping = interpolation_matrix(old, new.base.elastic.rest)
        warm = [None if u is None else mapping @ u for u in evaluation.displacements()]
    return new, warm


def min_angle(design: Design, q) -> tuple[float, float]:
    fine = design.deformer.points2d(q)
    angle_fine = float(triangle_angles_deg(fine, design.deformer.mesh2d.triangles).min())
    angle_el = np.inf
    if design.elastic_weights is not None:
        m = design.base.elastic.mesh.mesh2d
        el = m.points + design.elastic_weights @ design.deformer._q(q)
        angle_el = float(triangle_angles_deg(el, m.triangles).min())
    return angle_fine, angle_el


def size_ratio(design: Design, q) -> float:
    """The largest size ratio of two neighbouring triangles of the electrostatic mesh at ``q``
    (the quality :mod:`mscap.mesh.shape` keeps at ≤ 3 on a fresh mesh)."""
    ratios, _ = neighbour_size_ratios(design.deformer.points2d(q), design.deformer.mesh2d.triangles)
    return float(ratios.max(initial=1.0))


def needs_remesh(design: Design, q, fresh: tuple[float, float], limit_deg: float) -> bool:
    """Has a 2D angle of either mesh dropped below ``limit_deg``, or below half the fresh
    mesh's own minimum when that is smaller (gmsh's graded meshes start near 9°)?"""
    angle = min_angle(design, q)
    return any(a < min(limit_deg, 0.5 * f) for a, f in zip(angle, fresh))
