"""Conforming 2D triangulation of the sheet with every capacitor outline embedded (gmsh).

The sheet is one plane surface with the capacitor outlines as holes, and each capacitor
is a plane surface of its own sharing those curves, so the triangulation conforms to
every outline exactly and each triangle knows its capacitor. A Distance → Threshold
size field grades the edge length from ``edge_length_outline_mm`` on the outlines to
``edge_length_mm`` at ``grading_distance_mm`` from them: the field at plate edges
varies over the dielectric gap, so a uniform mesh overestimates capacitance. With a
``fringe_distance_mm``, the edge length grows no faster than ``fringe_slope`` within that
distance of the outlines (where the fringe field lives) and at the ``grading_distance_mm``
rate beyond it: the larger of two Threshold fields. Within ``zones`` (discs under poke
balls) the edge length is at most the zone's size, growing at ZONE_SLOPE beyond (gmsh Ball
fields, the smallest size wins); within ``strips`` (boxes along held sheet edges) the same
(gmsh Box fields).

Three more bounds make the mesh meet :mod:`mscap.mesh.shape`'s quality whatever the
plate, edge and gap geometry (gmsh's Frontal-Delaunay inserts points only in triangles
too large for the size field, so a field that jumps leaves needles):

- the edge length grows at most :data:`MAX_SLOPE` mm per mm anywhere (a hand-set
  ``grading_distance_mm`` shorter than ``edge_length_mm − edge_length_outline_mm`` is
  lengthened: the paper scenes' 0.075 → 5 mm over 2.5 mm left 6–10° triangles at the
  plate corners);
- around each outline corner it grows at most :data:`CORNER_SLOPE` (the distance field is
  radial there, and a ramp that is gentle along an edge is steep around a corner);
- it is at most :data:`FEATURE_FRACTION` of the width of the strip between an outline and
  the sheet edge (the distances to both, added), and never below the outline edge: a 3 mm
  strip beside a 6 mm plate got a fan of 0.07 × 3 mm needles and +52 % capacitance.

Every mesh is then measured (:func:`mscap.mesh.shape.assess`); one that misses the quality
is made again with every slope and the feature fraction halved, and one that still misses
it is kept with a warning naming the worst triangle's place and the outline it is near.
"""

from __future__ import annotations

import logging
import signal
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field as dataclass_field

import numpy as np

from mscap.errors import MeshError
from mscap.geometry import polygons as geometry
from mscap.geometry.layout import Layout
from mscap.mesh.shape import MeshQuality, assess
from mscap.scene.settings import MeshSettings

__all__ = ["TriMesh", "triangulate", "generate_2d", "quality_grading_mm", "MAX_SLOPE", "CORNER_SLOPE", "CORNER_REACH",
           "FEATURE_FRACTION"]

log = logging.getLogger(__name__)

#: Growth of the edge length away from a refinement zone (mm per mm).
ZONE_SLOPE = 0.5
#: Growth of the edge length away from the outlines, at most (mm per mm).
MAX_SLOPE = 1.0
#: Growth of the edge length away from an outline corner, at most (mm per mm).
CORNER_SLOPE = 0.5
#: ... over this many outline edges from the corner, then at most MAX_SLOPE.
CORNER_REACH = 10.0
#: A vertex where an outline turns by more than this is a corner (degrees).
CORNER_TURN_DEG = 20.0
#: The edge length is at most this fraction of the distance to the nearest outline plus
#: the distance to the sheet edge (the width of the strip between them).
FEATURE_FRACTION = 0.5


@dataclass(frozen=True)
class TriMesh:
    """A triangulation of the sheet (mm).

    Attributes
    ----------
    points
        ``(n, 2)`` vertex positions.
    triangles
        ``(m, 3)`` counter-clockwise vertex indices.
    capacitor_of_triangle
        ``(m,)`` index of the capacitor a triangle lies in, or -1.
    quality
        How it measured against :mod:`mscap.mesh.shape`'s quality when it was made
        (``None`` for a mesh mscap did not triangulate).
    conductor_of_layer
        ``(m, 2)`` the conductor a triangle lies in in the bottom and in the top conductive
        layer (-1: none), where the two layers differ (a wired sensor's nets,
        :mod:`mscap.fabrication.wired`); ``None``: ``capacitor_of_triangle`` in both.
    """

    points: np.ndarray
    triangles: np.ndarray
    capacitor_of_triangle: np.ndarray
    quality: MeshQuality | None = dataclass_field(default=None, compare=False)
    conductor_of_layer: np.ndarray | None = dataclass_field(default=None, compare=False)

    def __post_init__(self):
        for array in (self.points, self.triangles, self.capacitor_of_triangle, self.conductor_of_layer):
            if array is not None:
                array.setflags(write=False)

    def areas(self) -> np.ndarray:
        """Signed triangle areas (positive: counter-clockwise)."""
        a, b, c = (self.points[self.triangles[:, i]] for i in range(3))
        return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))

    def edges(self) -> np.ndarray:
        """``(e, 2)`` unique undirected edges, sorted vertex pairs."""
        pairs = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        return np.unique(pairs, axis=0)


def _add_loop(geo, polygon: np.ndarray, spacing: float | None = None, zones=()) -> tuple[int, list[int]]:
    """A closed polyline as a gmsh curve loop; with ``spacing``, each segment gets
    uniform nodes at most ``spacing`` apart (transfinite), so gmsh's 1D mesher does not
    integrate the size field along it (that cost ~10 s at 0.075 mm on grid3x3); a segment
    that comes within a zone's radius gets at most the zone's size."""
    points = [geo.addPoint(float(x), float(y), 0.0) for x, y in polygon]
    lines = [geo.addLine(points[i], points[(i + 1) % len(points)]) for i in range(len(points))]
    if spacing is not None:
        segments = geometry.edges(polygon)
        lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
        spacings = np.full(len(polygon), float(spacing))
        for x, y, radius, size in zones:
            near = geometry.point_segment_distance(np.array([[x, y]]), segments)[0] < radius
            spacings[near] = np.minimum(spacings[near], size)
        for line, length, step in zip(lines, lengths, spacings):
            geo.mesh.setTransfiniteCurve(line, int(np.ceil(length / step - 1e-9)) + 1)
    return geo.addCurveLoop(lines), lines


def _threshold(field, distance: int, near: float, far: float, start: float, stop: float) -> int:
    """A gmsh Threshold field: ``near`` up to ``start`` from the outlines, linear to ``far`` at ``stop``."""
    threshold = field.add("Threshold")
    field.setNumber(threshold, "InField", distance)
    field.setNumber(threshold, "SizeMin", near)
    field.setNumber(threshold, "SizeMax", far)
    field.setNumber(threshold, "DistMin", start)
    field.setNumber(threshold, "DistMax", stop)
    return threshold


#: Signals whose handling gmsh.initialize/finalize reset to the default (measured: a worker's
#: ignored SIGTERM became deadly after its first mesh, so srun's TERM to a job step killed the
#: workers; mscap/farm.py's workers now pass it on to the master, a handler kept here too).
_KEPT_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGUSR1") if hasattr(signal, name))


def _signal_dispositions() -> dict:
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {s: signal.getsignal(s) for s in _KEPT_SIGNALS}


def _restore(dispositions: dict) -> None:
    for s, handler in dispositions.items():
        if handler is not None:
            signal.signal(s, handler)


@contextmanager
def gmsh_model(name: str):
    """gmsh initialised with one empty model ``name``, quiet and single-threaded; finalised
    after, with the signal handlers it replaced put back (:data:`_KEPT_SIGNALS`)."""
    import gmsh  # imported here: loading gmsh costs ~0.2 s that non-meshing commands skip

    kept = _signal_dispositions()
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(name)
        yield gmsh
    finally:
        gmsh.finalize()
        _restore(kept)


def quality_grading_mm(settings: MeshSettings, slope: float = MAX_SLOPE) -> float:
    """The grading distance the mesher uses: ``settings.grading_distance_mm``, or longer
    where that would make the edge length grow faster than ``slope`` mm per mm."""
    return max(settings.grading_distance_mm, (settings.edge_length_mm - settings.edge_length_outline_mm) / slope)


def generate_2d(gmsh) -> tuple[np.ndarray, np.ndarray]:
    """Mesh the current gmsh model in 2D by its background size field alone, Frontal-Delaunay;
    return the index of each node tag and the nodes' (x, y) (mm)."""
    for option in ("MeshSizeExtendFromBoundary", "MeshSizeFromPoints", "MeshSizeFromCurvature"):
        gmsh.option.setNumber(f"Mesh.{option}", 0)
    # Frontal-Delaunay: gmsh's Delaunay (5) is 10 % faster but follows the size ramp off the
    # outlines worse: up to 22 % capacitance error where this has 5 % (docs/electrostatics.md).
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.model.mesh.generate(2)
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    index_of_tag = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    index_of_tag[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    return index_of_tag, coords.reshape(-1, 3)[:, :2].copy()


def triangulate(sheet_outline_mm: np.ndarray, layout: Layout, settings: MeshSettings,
                auxiliary: bool = False) -> TriMesh:
    """Mesh the sheet with the layout's outlines embedded, to :mod:`mscap.mesh.shape`'s
    quality (made again with a gentler size field when the first mesh misses it; kept
    with a warning when that one misses it too). An ``auxiliary`` mesh (the skinning
    weights' of :mod:`mscap.design.deformer`, whose outlines are the control points, unevenly
    spaced) says so at the info level only: no capacitance is computed on it.

    Raises
    ------
    MeshError
        When gmsh fails or returns a mesh that does not cover the sheet.
    """
    mesh = _triangulate(sheet_outline_mm, layout, settings, 1.0)
    quality = assess(mesh.points, mesh.triangles, layout.outlines, sheet_outline_mm)
    if not quality.meets:
        log.info("2D mesh: %s; meshing again with a gentler size field", quality.describe())
        mesh = _triangulate(sheet_outline_mm, layout, settings, 0.5)
        quality = assess(mesh.points, mesh.triangles, layout.outlines, sheet_outline_mm, repaired=True)
        if not quality.meets:
            log.log(logging.INFO if auxiliary else logging.WARNING,
                    "2D mesh below the quality its error model assumes: %s", quality.describe())
    log.info("2D mesh: %d vertices, %d triangles, %s", len(mesh.points), len(mesh.triangles), quality.describe())
    return TriMesh(mesh.points, mesh.triangles, mesh.capacitor_of_triangle, quality)


def _triangulate(sheet_outline_mm: np.ndarray, layout: Layout, settings: MeshSettings, gentle: float) -> TriMesh:
    """One gmsh triangulation, every slope and the feature fraction scaled by ``gentle``."""
    with gmsh_model("sheet") as gmsh:
        try:
            geo = gmsh.model.geo
            loops, outline_curves = [], []
            for outline in layout.outlines:
                loop, lines = _add_loop(geo, outline, settings.edge_length_outline_mm, settings.zones)
                loops.append(loop)
                outline_curves.extend(lines)
            sheet_loop, sheet_curves = _add_loop(geo, sheet_outline_mm)
            sheet_surface = geo.addPlaneSurface([sheet_loop] + loops)
            plate_surfaces = [geo.addPlaneSurface([loop]) for loop in loops]
            corner_points = [geo.addPoint(float(x), float(y), 0.0)
                             for o in layout.outlines for x, y in o[geometry.turning(o, CORNER_TURN_DEG)]]
            geo.synchronize()

            field = gmsh.model.mesh.field
            distance = field.add("Distance")
            field.setNumbers(distance, "CurvesList", outline_curves)
            longest = max(float(np.max(np.linalg.norm(np.roll(o, -1, 0) - o, axis=1))) for o in layout.outlines)
            field.setNumber(distance, "Sampling", int(np.ceil(4 * longest / settings.edge_length_outline_mm)) + 1)
            near, far = settings.edge_length_outline_mm, settings.edge_length_mm
            grading = quality_grading_mm(settings, gentle * MAX_SLOPE)
            ramp = _threshold(field, distance, near, far, 0.0, grading)
            if settings.fringe_distance_mm > 0:
                # gentle within the fringe zone, then the steeper ramp: it starts late enough to
                # cross the gentle one at fringe_distance_mm
                slope = gentle * min(settings.fringe_slope, MAX_SLOPE)
                gentle_ramp = _threshold(field, distance, near, far, 0.0, (far - near) / slope)
                steep = (far - near) / grading
                start = settings.fringe_distance_mm * (1.0 - slope / steep) if steep > slope \
                    else settings.fringe_distance_mm
                late = _threshold(field, distance, near, far, start, start + grading)
                ramp = field.add("Max")
                field.setNumbers(ramp, "FieldsList", [gentle_ramp, late])
            bounds = [ramp]
            if corner_points:
                to_corner = field.add("Distance")
                field.setNumbers(to_corner, "PointsList", corner_points)
                # slope CORNER_SLOPE up to CORNER_REACH outline edges from the corner, then MAX_SLOPE
                slope, steep, reach = gentle * CORNER_SLOPE, gentle * MAX_SLOPE, CORNER_REACH * near
                around = field.add("MathEval")
                field.setString(around, "F", f"max({near!r} + {slope!r} * F{to_corner}, "
                                             f"{near!r} + {steep!r} * F{to_corner} - {(steep - slope) * reach!r})")
                bounds.append(around)
            to_sheet = field.add("Distance")
            field.setNumbers(to_sheet, "CurvesList", sheet_curves)
            sheet_length = float(np.linalg.norm(np.diff(geometry.edges(np.asarray(sheet_outline_mm, float)), axis=1),
                                                axis=-1).max())
            field.setNumber(to_sheet, "Sampling", int(np.ceil(4 * sheet_length / near)) + 1)
            strip = field.add("MathEval")
            # never below the outline edge: a coarse (elastic) mesh would otherwise be refined
            # beside every plate near the sheet edge
            field.setString(strip, "F", f"max({near!r}, {gentle * FEATURE_FRACTION!r} * (F{distance} + F{to_sheet}))")
            bounds.append(strip)
            for x, y, radius, size in settings.zones:
                ball = field.add("Ball")
                for key, value in dict(XCenter=x, YCenter=y, ZCenter=0.0, Radius=radius, VIn=min(size, far), VOut=far,
                                       Thickness=max(far - size, 0.0) / (gentle * ZONE_SLOPE)).items():
                    field.setNumber(ball, key, value)
                bounds.append(ball)
            for x0, y0, x1, y1, size in settings.strips:
                box = field.add("Box")
                for key, value in dict(XMin=x0, YMin=y0, XMax=x1, YMax=y1, ZMin=-1.0, ZMax=1.0, VIn=min(size, far),
                                       VOut=far, Thickness=max(far - size, 0.0) / (gentle * ZONE_SLOPE)).items():
                    field.setNumber(box, key, value)
                bounds.append(box)
            smallest = field.add("Min")
            field.setNumbers(smallest, "FieldsList", bounds)
            field.setAsBackgroundMesh(smallest)
            index_of_tag, points = generate_2d(gmsh)
            triangles, owner = [], []
            for capacitor, surface in [(-1, sheet_surface)] + list(enumerate(plate_surfaces)):
                types, _, element_nodes = gmsh.model.mesh.getElements(2, surface)
                if len(types) != 1 or types[0] != 2:
                    raise MeshError(f"gmsh returned non-triangle elements on surface {surface}")
                tri = index_of_tag[element_nodes[0].astype(np.int64)].reshape(-1, 3)
                triangles.append(tri)
                owner.append(np.full(len(tri), capacitor, dtype=np.int64))
        except Exception as exc:
            if isinstance(exc, MeshError):
                raise
            raise MeshError(f"gmsh failed to mesh the sheet: {exc}") from exc

    triangles = np.concatenate(triangles)
    owner = np.concatenate(owner)
    used = np.zeros(len(points), dtype=bool)
    used[triangles] = True
    if not used.all():  # drop geometry points gmsh kept but no triangle uses
        renumber = np.cumsum(used) - 1
        points, triangles = points[used], renumber[triangles]
    mesh = TriMesh(points, triangles, owner)
    area = mesh.areas()
    flipped = area < 0
    if flipped.any():
        fixed = triangles.copy()
        fixed[flipped] = fixed[flipped][:, [0, 2, 1]]
        mesh = TriMesh(points, fixed, owner)
    return mesh
