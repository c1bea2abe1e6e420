"""Mesh sizes from a capacitance tolerance (``[mesh] tolerance``).

A layered mesh overestimates each plate's capacitance by its fringe error, an amount per
unit of plate edge: the plate edge is a 270° corner of the dielectric, where the potential
behaves like r^(2/3) and the mesh (P1 or P2) resolves it only so far. Measured per unit
edge and divided by the permittivity, that error e/ε is a property of the mesh settings
alone — the same for a 6 mm, a 10 mm and a 20 mm square and a 10 mm disk once the edge
length grows gently away from the outlines (``benchmarks/plate_size.py``,
docs/electrostatics.md, "Meshes from a tolerance"). A plate of area A and perimeter P
over a dielectric gap d then has a relative error of about

    (e/ε) · P d / A,

the fringe overestimate e P over the parallel-plate capacitance ε A / d. Small plates
have the most edge per area: for 1 %, a 20 mm square allows e/ε ≤ 0.36, a 6 mm square
e/ε ≤ 0.11.

:data:`LADDER` lists mesh settings from the cheapest to the most accurate, each with its
measured e/ε (the largest over the four calibration plates); :func:`settings_for_tolerance`
takes the first that keeps every plate of a layout within the tolerance. Sizes are
multiples of the dielectric gap, so a stack of other thicknesses gets a mesh scaled with
it; the constants were measured on the paper's stack (0.14 / 0.07 / 0.14 / 0.07 / 0.14 mm,
gap 0.14 mm) and hold for stacks of those proportions.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from mscap.geometry import polygons as geometry
from mscap.geometry.layout import Layout
from mscap.scene.poses import PokePose
from mscap.scene.settings import Layer, MeshSettings, Scene, Sheet

__all__ = ["Rung", "LADDER", "STEEP", "FRINGE_STACKS", "FAR_EDGE_MM", "DEFAULT_TOLERANCE", "rung_settings",
           "predicted_errors", "rung_of", "settings_for_tolerance", "sized", "sheet_for", "poke_zones",
           "no_finer_than", "ZONE_RADII", "ZONE_EDGE", "CURVATURE_EDGE", "P2_ZONE_EDGE", "P2_ZONE_RADII",
           "HELD_STRIP_EDGE_MM", "HELD_STRIP_MM", "refines_pokes", "p2_poke_refinement", "bend_radius",
           "curvature_edge", "ElasticRung", "POKE_ELASTIC_LADDER", "BENDING_ELEMENT_ORDER", "elastic_for_signal",
           "COUPLING_RUNG", "POKE_FAR_EDGE_MM", "poke_far_edge", "for_couplings"]

log = logging.getLogger(__name__)

#: The fringe zone, where the edge length grows at a rung's slope, in stack thicknesses
#: from the outlines: the fringe field decays like exp(−π x / t) over a stack of thickness
#: t, to 4e-6 at 4 t. Beyond it the edge length grows at STEEP, as the hand-set meshes do
#: everywhere. Their steep ramp (0.075 → 5 mm over 2.5 mm) leaves 0.5 mm triangles 0.25 mm
#: from a plate edge, where the fringe still varies over a layer thickness, and their error
#: depends on where the nodes fall: a 10 mm square 3.6 % high, a 6 mm one 3.3 %, a 20 mm
#: one 0.9 %, where a slope of 0.5 gives 1.35, 2.25 and 0.69 %.
FRINGE_STACKS = 4.0
STEEP = 2.0
#: Edge length far from the outlines, where the field is uniform (under a plate) or zero.
FAR_EDGE_MM = 5.0
#: Refinement under a ball of radius R: edges of at most ZONE_EDGE · R within ZONE_RADII · R
#: of its centre, in the electrostatic mesh and a P1 elastic mesh (P2 needs no zones). On jobs/poking.toml's
#: four symmetric pokes (R = 10 mm) the pressed gains spread by 3.7 % with 5 mm edges
#: under the ball in both meshes, 15 % with the elastic mesh alone at 1.25 mm (the
#: electrostatic vertices then sample a deformation finer than their own mesh), 3.5 % with
#: 2.5 mm electrostatic edges and 0.74 % with both at 1.25 mm (docs/electrostatics.md,
#: "The pose-to-pose signal").
ZONE_RADII = 1.5
ZONE_EDGE = 0.125
#: On a sheet glued onto a curved object the electrostatic edge inside the plates must
#: follow the curvature: on the joystick's stick (R = 10 mm) six plates equal by
#: symmetry read 28.6–32.6 pF with 5 mm edges, agree to 0.3 % with 3 mm and 0.2 % with
#: 2 mm (docs/scenes.md, "Meshes: curvature needs small electrostatic elements"). The far
#: edge is at most CURVATURE_EDGE times the smallest radius any glued pose bends the sheet to.
CURVATURE_EDGE = 0.25
#: The capacitance tolerance of a scene that sets no mesh sizes.
DEFAULT_TOLERANCE = 0.01


@dataclass(frozen=True)
class Rung:
    """Mesh settings of the ladder: element ``order``, outline edge as a multiple of the
    dielectric gap, ``elements_per_layer``, growth ``slope`` of the edge length in the
    fringe zone, and the measured fringe error per unit edge over the permittivity,
    ``e_over_eps``."""

    order: int
    outline_over_gap: float
    elements_per_layer: int
    slope: float
    e_over_eps: float
    element: str = "tet"

    @property
    def label(self) -> str:
        shape = " prism" if self.element == "prism" else ""
        return f"P{self.order}{shape} h {self.outline_over_gap:g}d x{self.elements_per_layer} slope {self.slope:g}"


#: Tets only (a scene that gives ``element = "tet"``, or ``order = 2``), from the cheapest
#: to the most accurate (by unknowns on the 20 mm square, 13k to 600k); e/ε is the largest
#: over the four calibration plates, rounded up (``.venv/bin/python
#: benchmarks/plate_size.py``, docs/plate_size.csv). P1 with 2 elements per layer (0.14 at
#: 79k unknowns) is left out: P2 at 2d, slope 1 matches it at 52k.
TET_LADDER: tuple[Rung, ...] = (
    Rung(1, 1.0, 1, 1.0, 0.44),
    Rung(1, 1.0, 1, 0.5, 0.36),
    Rung(1, 0.5, 1, 1.0, 0.30),
    Rung(1, 0.5, 1, 0.5, 0.26),
    Rung(2, 2.0, 1, 1.0, 0.15),
    Rung(2, 2.0, 1, 0.5, 0.12),
    Rung(2, 1.5, 1, 0.5, 0.08),
    Rung(2, 1.0, 1, 0.5, 0.05),
    Rung(2, 0.5, 2, 0.5, 0.017),
)

#: The default ladder: P1 prisms (``[mesh] element = "prism"``, :mod:`mscap.fem.wedge`),
#: then the two most accurate P2 tet rungs. On the same vertices a prism errs about a third
#: of its three tets, so every P1 tet rung and the P2 ones down to e/ε = 0.08 have a prism
#: rung as accurate with 2.5–4.6× fewer unknowns (``benchmarks/plate_size.py
#: --only-prisms``, 2026-12-04: 4.5k–43k unknowns on the 20 mm square; docs/performance.md
#: §14). Prism rungs of slope 0.5 that a slope-1 rung beats at fewer unknowns are left out.
LADDER: tuple[Rung, ...] = (
    Rung(1, 3.0, 1, 1.0, 0.69, "prism"),
    Rung(1, 2.0, 1, 1.0, 0.38, "prism"),
    Rung(1, 1.5, 1, 1.0, 0.26, "prism"),
    Rung(1, 1.0, 1, 1.0, 0.17, "prism"),
    Rung(1, 1.0, 1, 0.5, 0.13, "prism"),
    Rung(1, 0.5, 1, 1.0, 0.09, "prism"),
    Rung(1, 0.5, 1, 0.5, 0.07, "prism"),
    Rung(2, 1.0, 1, 0.5, 0.05),
    Rung(2, 0.5, 2, 0.5, 0.017),
)


#: The mesh for Maxwell couplings (``mscap capacitance --maxwell`` on a scene sized by a
#: tolerance): the off-diagonal entries between neighbouring plates come from the fringe
#: fields across the gap, which the C ladder does not calibrate. Two 6 mm squares against
#: P2 Richardson references (benchmarks/maxwell_coupling.py, 2026-12-05; same-layer /
#: cross-layer coupling): the 1 % C mesh (P1 prisms, outline d/2) +2.8 / +2.8 % at a 2 mm
#: gap and +5.1 / +7.1 % at 0.5 mm; no P1 prism mesh got within 2 % at 0.5 mm (outline d/4
#: with two per layer: +2.2 / +2.2 %, 94k unknowns); this rung +0.40 / +0.42 % and
#: +1.54 / +0.90 %, at about 10× the unknowns of the C mesh (163k against 16.5k).
COUPLING_RUNG = Rung(2, 1.0, 2, 0.5, 0.05)


def for_couplings(mesh: MeshSettings, gap_mm: float, stack_mm: float) -> MeshSettings:
    """A tolerance-sized ``mesh`` on :data:`COUPLING_RUNG` (P2 is more accurate for C
    too: +0.34 % where the 6 mm squares' P1 prism rung reads +0.78 %), unless it is a P2
    mesh at least as fine already; its far edge, zones and curvature kept. Hand-set sizes
    come back as they are."""
    if mesh.tolerance is None or (mesh.order == 2 and mesh.elements_per_layer >= 2 and
                                  mesh.edge_length_outline_mm <= COUPLING_RUNG.outline_over_gap * gap_mm):
        return mesh
    fine = rung_settings(COUPLING_RUNG, gap_mm, stack_mm, mesh.edge_length_mm)
    return replace(mesh, order=2, element="tet", edge_length_outline_mm=fine.edge_length_outline_mm,
                   elements_per_layer=max(2, mesh.elements_per_layer), fringe_slope=COUPLING_RUNG.slope,
                   grading_distance_mm=fine.grading_distance_mm, fringe_distance_mm=fine.fringe_distance_mm,
                   zones=no_finer_than(mesh.zones, fine.edge_length_outline_mm))


def rung_settings(rung: Rung, gap_mm: float, stack_mm: float, far_mm: float = FAR_EDGE_MM) -> MeshSettings:
    """The mesh settings of ``rung`` for a dielectric gap of ``gap_mm`` in a stack ``stack_mm`` thick."""
    near = min(rung.outline_over_gap * gap_mm, far_mm)
    return MeshSettings(far_mm, near, max((far_mm - near) / STEEP, near), rung.elements_per_layer, rung.order,
                        fringe_distance_mm=FRINGE_STACKS * stack_mm, fringe_slope=rung.slope, element=rung.element)


def rung_of(mesh: MeshSettings, gap_mm: float) -> Rung | None:
    """The ladder rung ``mesh`` was sized on (order, element, slabs, slope and outline edge
    over ``gap_mm``), or ``None`` for sizes set by hand or overridden."""
    if mesh.tolerance is None:
        return None
    for rung in LADDER + TET_LADDER + (COUPLING_RUNG,):
        if (rung.order == mesh.order and rung.element == mesh.element
                and rung.elements_per_layer == mesh.elements_per_layer and rung.slope == mesh.fringe_slope
                and abs(rung.outline_over_gap * gap_mm - mesh.edge_length_outline_mm) <= 1e-9 * gap_mm):
            return rung
    return None


def predicted_errors(rung: Rung, outlines: Sequence[np.ndarray], gap_mm: float) -> np.ndarray:
    """Relative capacitance error of each plate on ``rung``'s mesh: (e/ε) P d / A."""
    perimeters = [np.linalg.norm(np.diff(geometry.edges(o), axis=1)[:, 0], axis=1).sum() for o in outlines]
    ratios = [p * gap_mm / abs(geometry.signed_area(o)) for p, o in zip(perimeters, outlines)]
    return rung.e_over_eps * np.array(ratios)


def settings_for_tolerance(tolerance: float, outlines: Sequence[np.ndarray], gap_mm: float, stack_mm: float,
                           far_mm: float = FAR_EDGE_MM, order: int | None = None,
                           elements_per_layer: int | None = None,
                           element: str | None = None) -> tuple[MeshSettings, Rung, float]:
    """The cheapest rung whose predicted error is within ``tolerance`` on every plate,
    among the rungs of ``order``, ``elements_per_layer`` and ``element`` when given (a
    scene that fixes them): :data:`LADDER`, or :data:`TET_LADDER` for tets or P2.

    Returns its settings, the rung and the largest predicted error. When no rung reaches
    the tolerance (plates much smaller than a few millimetres), the most accurate rung,
    with a warning naming the predicted error."""
    pool = TET_LADDER if element == "tet" or order == 2 else LADDER
    ladder = [rung for rung in pool if order in (None, rung.order) and element in (None, rung.element)
              and elements_per_layer in (None, rung.elements_per_layer)] or list(pool)
    for rung in ladder:
        worst = float(predicted_errors(rung, outlines, gap_mm).max())
        if worst <= tolerance:
            return rung_settings(rung, gap_mm, stack_mm, far_mm), rung, worst
    log.warning("mesh tolerance %.3g: the finest mesh of the ladder predicts %.3g on the smallest plate; "
                "using it", tolerance, worst)
    return rung_settings(rung, gap_mm, stack_mm, far_mm), rung, worst


def sized(mesh: MeshSettings, layers: Sequence[Layer], layout: Layout) -> tuple[MeshSettings, float]:
    """``mesh`` sized for its tolerance on ``layout``'s plates, its overrides applied; and
    the largest predicted error. Settings set by hand (no tolerance) come back as they are,
    with NaN."""
    if mesh.tolerance is None:
        return mesh, float("nan")
    stack = sum(layer.thickness_mm for layer in layers)
    given = dict(mesh.overrides)
    far = min(FAR_EDGE_MM, mesh.curvature_edge_mm or np.inf)  # a glued bend's curvature caps it
    settings, _, worst = settings_for_tolerance(mesh.tolerance, layout.outlines, layers[2].thickness_mm, stack,
                                                given.get("edge_length_mm", far), given.get("order"),
                                                given.get("elements_per_layer"), given.get("element"))
    settings = replace(settings, tolerance=mesh.tolerance, overrides=mesh.overrides, **given)
    return replace(settings, zones=no_finer_than(mesh.zones, settings.edge_length_outline_mm),
                   curvature_edge_mm=mesh.curvature_edge_mm, signal_tolerance=mesh.signal_tolerance), worst


def no_finer_than(zones, edge_mm: float) -> tuple[tuple[float, float, float, float], ...]:
    """``zones`` with no size below ``edge_mm`` (the outline edge): a tiny ball would
    otherwise ask gmsh for nanometre edges along any outline it touches."""
    return tuple((x, y, radius, max(size, edge_mm)) for x, y, radius, size in zones)


def poke_zones(poses) -> tuple[tuple[float, float, float, float], ...]:
    """The refinement zone under each poke's ball: ``(x, y, ZONE_RADII R, ZONE_EDGE R)``."""
    return tuple((float(p.center_mm[0]), float(p.center_mm[1]), ZONE_RADII * p.radius_mm, ZONE_EDGE * p.radius_mm)
                 for p in poses if isinstance(p, PokePose))


def bend_radius(poses, sheet_outline_mm: np.ndarray, spacing_mm: float = 3.0, step_mm: float = 0.5) -> float:
    """The smallest radius (mm) to which a glued pose bends the sheet (inf without one).

    The sheet is sampled every ``spacing_mm`` (points at least ``2 step_mm`` inside its
    outline); at each point the glued surface's normal n (from the exact Jacobian of the
    pose's map) is differenced over ``±step_mm`` along x, y and both diagonals, and
    |Δn| / |Δr| is the rate the normal turns along that direction, |S e| for the shape
    operator S: at least cos 22.5° = 0.92 of the largest principal curvature, which it
    equals along a principal direction."""
    glued = [p for p in poses if getattr(p, "kind", None) == "glue"]
    if not glued:
        return float("inf")
    outline = np.asarray(sheet_outline_mm, dtype=float)
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    xs, ys = (np.arange(a + 2 * step_mm, b - 2 * step_mm + 1e-9, spacing_mm) for a, b in zip(lo, hi))
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    directions = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, -1.0]]) / [[1.0], [1.0], [2 ** 0.5], [2 ** 0.5]]
    inside = np.ones(len(grid), bool)
    for d in directions:
        for sign in (-1, 1):
            inside &= geometry.points_in_polygon(grid + sign * step_mm * d, outline)
    grid = grid[inside]
    if not len(grid):
        return float("inf")
    # (2 signs, 4 directions, points): every end point of every pose in one evaluation
    ends = grid[None, None] + np.array([-1.0, 1.0])[:, None, None, None] * step_mm * directions[None, :, None, :]
    largest = 0.0
    for pose in glued:
        r, j = pose.positions_and_jacobian(ends.reshape(-1, 2))
        n = np.cross(j[:, :, 0], j[:, :, 1])
        n = (n / np.linalg.norm(n, axis=1, keepdims=True)).reshape(2, len(directions), -1, 3)
        r = r.reshape(2, len(directions), -1, 3)
        turn = np.linalg.norm(n[1] - n[0], axis=-1) / np.linalg.norm(r[1] - r[0], axis=-1)
        largest = max(largest, float(turn.max()))
    return 1.0 / largest if largest > 0 else float("inf")


def curvature_edge(poses, sheet_outline_mm: np.ndarray) -> float | None:
    """The far edge the glued poses allow, :data:`CURVATURE_EDGE` · :func:`bend_radius`
    (``None`` when no pose bends the sheet)."""
    radius = bend_radius(poses, sheet_outline_mm)
    return CURVATURE_EDGE * radius if np.isfinite(radius) else None


@dataclass(frozen=True)
class ElasticRung:
    """Elastic settings for the signal of a poked scene: element ``order``, edge length as a
    multiple of the ball radius R, and the measured ``gain_error``."""

    order: int
    edge_over_radius: float
    gain_error: float


#: The pose-to-pose signal of a poke is elastic: how far the ball stretches the dielectric
#: over each plate. On jobs/poking.toml (R = 10 mm, 13 mm deep, the electrostatic mesh at
#: 1 % with its zones under the balls, one slab through the stack) the largest relative
#: error of any gain C_j(poke_i) − C_j(rest) against a P2 Richardson reference (P2 with the
#: zones at 5, 3.54, 2.5 mm, observed order 1.2; docs/electrostatics.md, "The pose-to-pose
#: signal"), cheapest first. The P1 rungs have the zones in the elastic mesh, the P2 ones
#: not (:func:`mscap.mesh.layered.mesh_elastic`; with them P2 reads 2.5 / 1.7 / 1.1 % at 4×
#: the time). P1 does not get below 6 % (0.0625 R: 6.0 %; one slab per layer at 0.25 R:
#: 7.3 %): its tets lock in the thin, nearly incompressible stack.
POKE_ELASTIC_LADDER: tuple[ElasticRung, ...] = (
    ElasticRung(1, 0.5, 0.20),
    ElasticRung(1, 0.25, 0.107),
    ElasticRung(1, 0.125, 0.072),
    ElasticRung(2, 0.5, 0.034),
    ElasticRung(2, 0.354, 0.019),
    ElasticRung(2, 0.25, 0.015),
)


#: The elastic order of a scene with pokes or glued poses that gives none: the sheet bends
#: there, and linear tets one element thick bend poorly. Against P2 at a quarter of the
#: 5 mm edge (benchmarks/element_bias.py, ν = 0.30 / 0.47 / 0.49), P1 at 5 mm reads a
#: 5 mm ball's gain +22 / +34 / +48 % and a glued 15 mm cylinder's +0.5 / −6.9 / −10.7 %;
#: P2 at 5 mm +5.9 / +8.3 / +11.6 % and +0.9 / +1.2 / +1.3 %, at 1.5–2× P1's wall (the poke's
#: P1 refines under the ball, P2 does not); P2 refined for the poke
#: (:func:`p2_poke_refinement`) +0.6 / +1.7 / +2.4 % at 2.7–3× P1's wall. On
#: jobs/poking.toml's hand-set meshes P2 reads the 16 gains within 2.2 % where P1 is
#: 8–16 % high, at 25× P1's elastic time (docs/elastic.md, "Pokes and bends: P1 locks").
BENDING_ELEMENT_ORDER = 2


#: A P2 elastic mesh of its own under a poke (``[elastic] refine_pokes``): edges of at most
#: P2_ZONE_EDGE · R within P2_ZONE_RADII · R of each ball's centre, and of at most
#: HELD_STRIP_EDGE_MM (half the far edge, if less) within HELD_STRIP_MM of every edge a
#: poke holds, both growing at 0.5 mm per mm beyond. P2's error at a 5 mm edge sits about
#: half under the ball and half at the clamped edges, whose bending boundary layer is a few
#: stack thicknesses wide (benchmarks/poke_zone_p2.py, docs/elastic.md "Where P2 errs under
#: a poke"; a sweep of 108 zone/strip/far-edge combinations): on issue 44's 5 mm ball
#: uniform P2 reads +9.3 % at 5 mm and +4.3 % at 2.5 mm; this +2.7 % (ν = 0.47; +0.6 / +2.4 %
#: at 0.30 / 0.49 against P2 at 1.25 mm) at 0.58× the wall of 2.5 mm; on jobs/poking.toml
#: +3.7 % → +1.9 % at 0.32×. Strips of 2.5 mm and a zone of 1.5 R read +3.5 % / +2.2 %.
#: With the poke-only far edge :data:`POKE_FAR_EDGE_MM` a zone edge of 0.35 R read issue
#: 44's ball +2.9 %, 0.30 R +2.6 % (one process, CPU 0.47× uniform P2 at 2.5 mm; at a 5 mm
#: far edge 0.30 R reads +2.4 %): 0.30 R, for a margin under 3 %.
P2_ZONE_EDGE = 0.30
P2_ZONE_RADII = 1.0
HELD_STRIP_EDGE_MM = 2.0
HELD_STRIP_MM = 1.0


#: The far edge (mm) of a refined P2 elastic mesh (:func:`p2_poke_refinement`) in a scene
#: whose every loaded pose is a poke and that gives no ``[elastic] edge_length_mm``: once
#: the zones under the balls and the strips along the held edges are in, the far edge
#: moves a poke's gain by a few tenths of a point and sets the cost (benchmarks/poke_zone_p2.py,
#: docs/elastic.md). At 10 mm instead of 5 (zone edge 0.30 R): issue 44's 5 mm ball +2.58 %
#: at 0.47× the CPU of uniform P2 at 2.5 mm (+2.42 % at 0.57×); jobs/poking.toml's 16 gains
#: within 2.0 % of the P2 Richardson reference (the hand-set P1 meshes: 17.6 %). Scenes
#: that stretch or glue the sheet keep the 5 mm edge: their strain is not where a poke's is.
POKE_FAR_EDGE_MM = 10.0


def poke_far_edge(elastic, mesh: MeshSettings, poses, given: dict) -> float | None:
    """:data:`POKE_FAR_EDGE_MM` when the elastic mesh is a refined P2 mesh of its own (as
    :func:`refines_pokes`) for a scene whose loaded poses are all pokes and whose
    ``[elastic]`` table ``given`` sets no edge; else ``None`` (the edge stays)."""
    loaded = [p for p in poses if getattr(p, "kind", None) != "free"]
    if "edge_length_mm" in given or not loaded or not all(isinstance(p, PokePose) for p in loaded):
        return None
    return POKE_FAR_EDGE_MM if refines_pokes(elastic, mesh) else None


def refines_pokes(elastic, mesh: MeshSettings) -> bool:
    """Whether the elastic mesh of ``elastic`` (``[elastic]``) gets :func:`p2_poke_refinement`:
    a P2 mesh of its own with ``refine_pokes``, beside an electrostatic mesh (``mesh``)
    refined under the balls too (its ``zones``: a tolerance or a signal tolerance). A finer deformation under a ball
    sampled by a coarse electrostatic mesh moves the signal away from converged:
    jobs/quick.toml's hand-set mesh has no zones, and the refined elastic mesh put its
    initial layout's min L1 at 0.632 pF against 0.600 uniform, its finer-mesh check
    reading 0.573 / 0.583 pF (docs/elastic.md)."""
    return elastic.order == 2 and elastic.mesh == "own" and elastic.refine_pokes and bool(mesh.zones)


def p2_poke_refinement(poses, sheet_outline_mm: np.ndarray, far_mm: float):
    """The refinement a P2 elastic mesh with far edge ``far_mm`` gets for ``poses``: zones
    ``(x, y, radius, size)`` under the balls and strips ``(x_min, y_min, x_max, y_max,
    size)`` along the held edges (sizes not below what the far edge already gives)."""
    pokes = [p for p in poses if isinstance(p, PokePose)]
    zones = tuple((float(p.center_mm[0]), float(p.center_mm[1]), P2_ZONE_RADII * p.radius_mm,
                   P2_ZONE_EDGE * p.radius_mm) for p in pokes if P2_ZONE_EDGE * p.radius_mm < far_mm)
    size = min(HELD_STRIP_EDGE_MM, 0.5 * far_mm)
    (x0, y0), (x1, y1) = np.min(sheet_outline_mm, axis=0), np.max(sheet_outline_mm, axis=0)
    w = HELD_STRIP_MM
    boxes = {"x_min": (x0 - w, y0 - w, x0 + w, y1 + w), "x_max": (x1 - w, y0 - w, x1 + w, y1 + w),
             "y_min": (x0 - w, y0 - w, x1 + w, y0 + w), "y_max": (x0 - w, y1 - w, x1 + w, y1 + w)}
    held = sorted({edge for p in pokes for edge in p.held_edges})
    strips = tuple((*map(float, boxes[edge]), size) for edge in held)
    return zones, strips


def elastic_for_signal(tolerance: float, poses, order: int | None = None) -> tuple[ElasticRung, float] | None:
    """The cheapest :data:`POKE_ELASTIC_LADDER` rung (of ``order``, when the scene fixes it)
    whose gain error is within ``tolerance``, and its edge length (mm) for the smallest
    ball; ``None`` without a poke. When none reaches the tolerance, the most accurate,
    with a warning."""
    radii = [p.radius_mm for p in poses if isinstance(p, PokePose)]
    if not radii:
        return None
    ladder = [rung for rung in POKE_ELASTIC_LADDER if order in (None, rung.order)] or list(POKE_ELASTIC_LADDER)
    rung = next((r for r in ladder if r.gain_error <= tolerance), None)
    if rung is None:
        rung = ladder[-1]
        log.warning("signal tolerance %.3g: the most accurate elastic setting for pokes, P%d at %.3g R, was "
                    "measured at %.3g; using it", tolerance, rung.order, rung.edge_over_radius, rung.gain_error)
    return rung, rung.edge_over_radius * min(radii)


def sheet_for(scene: Scene, layout: Layout) -> Sheet:
    """The mesh stage's input for ``layout`` on ``scene``'s sheet: its mesh re-sized for
    that layout's plates when the scene gives a tolerance (each multi-start run is sized
    for its own initial layout; a remesh keeps its run's sizes)."""
    return replace(scene.sheet, layout=layout, mesh=sized(scene.mesh, scene.layers, layout)[0])
