"""The sensor as it is wired: its routed nets, not its plates, through the same elastic
and electrostatic simulation.

In the multiplexed array a reading is the capacitance between row net i and column net
j: plates, leads and pads together. The routed nets differ between the two conductive
layers (rows below, columns above), so the sheet is triangulated conforming to both
layers' outlines at once: gmsh's OpenCASCADE kernel fragments the sheet by every net
region of either layer, and each triangle takes the net of each layer its centroid lies
in. Extruded, a bottom-layer tet belongs to its row net and a top-layer tet to its column
net; the Maxwell matrix over the nets (bottom plate i = row net i, top plate j = column
net j) gives every reading at once, ``c_ij = −C(R_i, C_j)``.

The plate-only design is meshed on the very mesh of the wired one (both conform to the nets
and the plates), with its plates as the conductors of both layers, so that the two differ
by the wiring alone. The elastic problem is the scene's own with the nets in place of the
plates (:func:`wired_elastic_mesh`): a lead is carbon-black silicone in its own layer, as
stiff as a plate.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, replace

import numpy as np
import shapely
import shapely.ops
from scipy.spatial import cKDTree
from shapely.geometry import Polygon

from mscap.errors import FabricationError, MeshError
from mscap.mesh.layered import BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER, LayeredMesh, extrude
from mscap.mesh.triangulate import TriMesh, generate_2d, gmsh_model, quality_grading_mm
from mscap.scene.settings import ElasticSettings, Scene, Sheet

__all__ = ["Wiring", "wiring_of", "plates_only", "read_wiring_dir", "net_mesh", "wired_mesh", "wired_elastic_mesh",
           "readings"]

log = logging.getLogger(__name__)

#: A fabrication.json is some kB (the plates' outlines): at most this much of one is read.
MAX_JSON_BYTES = 64 * 2**20
#: Outline points closer than this to the one before are dropped before meshing.
_MIN_EDGE_MM = 1e-5
#: Net outline vertices this close to a plate's edge are moved onto it (mm).
_SNAP_MM = 1e-3


@dataclass(frozen=True, eq=False)
class Wiring:
    """How a design's plates become readings: ``bottom[i]`` and ``top[j]``, the conductor
    regions of each conductive layer (shapely), and ``slots[c] = (i, j)``, the row and
    column whose mutual capacitance is capacitor c's reading. The plate-only design
    (:func:`plates_only`) has capacitor c's plate as conductor c of both layers."""

    label: str
    bottom: tuple
    top: tuple
    slots: tuple[tuple[int, int], ...]
    plates: tuple
    #: Every region the mesh conforms to, conductors or not (default: the conductors):
    #: a wired design's nets and plates, and the same for its plates alone, so that the two
    #: are meshed alike and differ by the wiring only (:func:`plates_only`).
    geometry: tuple = ()

    @property
    def regions(self) -> tuple:
        """The regions the mesh conforms to."""
        return self.geometry or self.bottom + self.top

    @property
    def key(self) -> str:
        """A hash of the conductors and slots: a different wiring is a different design
        (salted with how it is simulated: a cache of readings without the leads' stiffness
        is stale)."""
        h = hashlib.sha256(b"leads in the elastic mesh;" + self.label.encode())
        for region in self.bottom + self.top + (None,) + self.regions:
            h.update(b"|" if region is None else shapely.to_wkb(region))
        h.update(np.asarray(self.slots, dtype=np.int64).tobytes())
        return h.hexdigest()[:16]


def wiring_of(routing) -> Wiring:
    """The wiring of a :class:`mscap.fabrication.router.Routing` (as routed)."""
    return _wired(tuple(n.conductor for n in routing.layer("bottom")), tuple(n.conductor for n in routing.layer("top")),
                  routing.array.slots, routing.plates)


def _wired(bottom: tuple, top: tuple, slots, plates: tuple) -> Wiring:
    """Nets ``bottom`` and ``top`` meshed with the plates' outlines in them."""
    return Wiring("wired", bottom, top, tuple(slots), plates, geometry=bottom + top + plates)


def plates_only(outlines, meshed_like: Wiring | None = None) -> Wiring:
    """The design without wiring: each capacitor's plate its conductor in both layers. With
    ``meshed_like`` (the design as wired) on the very mesh of that wiring, so that the two
    readings differ by the leads alone; a lead's share of a reading is then free of the
    two meshes' discretisation errors, which on the small test scene at 1 mm outline edges
    are ten times that share (docs/fabrication.md)."""
    plates = tuple(Polygon(np.asarray(o, dtype=float)) for o in outlines)
    geometry = meshed_like.regions if meshed_like is not None else ()
    return Wiring("plates", plates, plates, tuple((c, c) for c in range(len(plates))), plates, geometry=geometry)


def read_wiring_dir(directory, outlines=None) -> Wiring:
    """The wiring of an ``mscap fabricate`` output directory, as built: each net's region
    read back from ``bottom.dxf`` and ``top.dxf``, the slots (and, without ``outlines``,
    the plates) from ``fabrication.json``; the design's plates must each lie in their
    net of each layer.

    Raises
    ------
    FabricationError
        Not such a directory, or a wiring of another design.
    """
    import json
    from pathlib import Path

    from mscap.fabrication.stencil import read_stencil, regions
    from mscap.infile import read_regular

    directory = Path(directory)
    try:
        document = json.loads(read_regular(directory / "fabrication.json", MAX_JSON_BYTES, "a fabrication.json"))
        slots = {int(s["capacitor"]): (int(s["row"]), int(s["column"])) for s in document["array"]["slots"]}
        rows, columns = int(document["array"]["rows"]), int(document["array"]["columns"])
        if outlines is None:
            outlines = [np.asarray(s["outline_mm"], dtype=float) for s in
                        sorted(document["array"]["slots"], key=lambda s: int(s["capacitor"]))]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise FabricationError(f"{directory}: not an `mscap fabricate` output directory "
                               f"(fabrication.json: {type(exc).__name__} {exc})") from None
    plates = tuple(Polygon(np.asarray(o, dtype=float)) for o in outlines)
    if sorted(slots) != list(range(len(plates))):
        raise FabricationError(f"{directory}: wires capacitors {sorted(slots)}, the design has {len(plates)}")
    layers = {}
    for layer, prefix, count in (("bottom", "NET_R", rows), ("top", "NET_C", columns)):
        groups = read_stencil(directory / f"{layer}.dxf")
        layers[layer] = tuple(regions(groups.get(f"{prefix}{i}", [])) for i in range(count))
    for c, (i, j) in enumerate(slots[c] for c in range(len(plates))):
        for layer, n in (("bottom", i), ("top", j)):
            if not layers[layer][n].buffer(1e-3).contains(plates[c]):
                raise FabricationError(f"{directory}: capacitor {c}'s plate is not in net "
                                       f"{'R' if layer == 'bottom' else 'C'}{n} of {layer}.dxf: "
                                       f"the stencils are of another design")
    return _wired(layers["bottom"], layers["top"], tuple(slots[c] for c in range(len(plates))), plates)


def net_mesh(sheet_outline: np.ndarray, bottom: list, top: list, settings, thicknesses_mm,
             elements_per_layer: int = 1, snap_to=None, slabs: int | None = None, geometry=None) -> LayeredMesh:
    """The layered mesh whose bottom conductive layer holds the regions ``bottom`` (shapely
    polygons, conductor i each) and whose top layer holds ``top``: triangulated conforming
    to the regions ``geometry`` (default: both layers'), ``edge_length_outline_mm`` on every
    outline graded to ``edge_length_mm``; the regions' vertices within 1e-3 mm of
    ``snap_to`` (the plates) moved onto it; extruded layer by layer, or in ``slabs`` even
    slabs (an elastic mesh, :func:`mscap.mesh.layered.extrude`). The same ``geometry``
    makes the same mesh whatever its conductors.

    Raises
    ------
    MeshError
        When gmsh fails, or a triangle lies in no region it was meant to.
    """
    sheet = Polygon(np.asarray(sheet_outline, dtype=float))
    # Where the two layers' outlines run together (a plate's edge, in both) they must be
    # one curve, not two 1e-5 apart with needles between them: a fillet's closing moves a
    # plate's edge by that much next to a junction. Snapped onto the plates' edges.
    geometry = list(bottom) + list(top) if geometry is None else list(geometry)
    if snap_to is not None:
        bottom = [shapely.snap(net, snap_to, _SNAP_MM) for net in bottom]
        top = [shapely.snap(net, snap_to, _SNAP_MM) for net in top]
        geometry = [shapely.snap(region, snap_to, _SNAP_MM) for region in geometry]
    plate_edges = snap_to.boundary if snap_to is not None else None
    plate_vertices = shapely.get_coordinates(plate_edges) if snap_to is not None else None
    spacing = 0.5 * settings.edge_length_outline_mm

    def resampled(polygon):
        rings = [_resampled(np.asarray(r.coords)[:-1], plate_edges, plate_vertices, spacing)
                 for r in [polygon.exterior] + list(polygon.interiors)]
        thinned = Polygon(rings[0], rings[1:])
        return thinned if thinned.is_valid else polygon  # a narrow place the thinning crossed: keep it all

    bottom = [shapely.ops.unary_union([resampled(p) for p in getattr(n, "geoms", [n])]) for n in bottom]
    top = [shapely.ops.unary_union([resampled(p) for p in getattr(n, "geoms", [n])]) for n in top]
    parts = [resampled(part) for region in geometry for part in getattr(region, "geoms", [region])]
    points, triangles = _triangulated(sheet, parts, settings)
    areas = np.abs(TriMesh(points, triangles, np.full(len(triangles), -1)).areas())
    centroid = points[triangles].mean(axis=1)
    label = {}
    for layer, nets in (("bottom", bottom), ("top", top)):
        label[layer] = np.full(len(triangles), -1, dtype=np.int64)
        for i, net in enumerate(nets):
            label[layer][shapely.contains_xy(net.buffer(1e-6), centroid[:, 0], centroid[:, 1])] = i
    for layer, nets in (("bottom", bottom), ("top", top)):
        area = np.bincount(label[layer][label[layer] >= 0], minlength=len(nets))
        for i, net in enumerate(nets):
            mesh_area = areas[label[layer] == i].sum()
            if not abs(mesh_area - net.area) <= 1e-3 * net.area + 1e-3:
                raise MeshError(f"the wired mesh covers {mesh_area:.6g} mm2 of {layer} conductor {i}, "
                                f"whose outline holds {net.area:.6g} mm2 ({int(area[i])} triangles)")
    mesh2d = TriMesh(points, triangles, np.where(label["bottom"] >= 0, label["bottom"], label["top"]),
                     conductor_of_layer=np.column_stack([label["bottom"], label["top"]]))
    mesh = extrude(mesh2d, thicknesses_mm, elements_per_layer, slabs=slabs)
    layer = mesh.layer_of_tet
    conductor = np.full(len(mesh.tets), -1, dtype=np.int32)
    on_bottom, on_top = layer == BOTTOM_PLATE_LAYER, layer == TOP_PLATE_LAYER
    conductor[on_bottom] = label["bottom"][mesh.triangle_of_tet[on_bottom]]
    conductor[on_top] = label["top"][mesh.triangle_of_tet[on_top]]
    log.info("wired mesh: %d triangles, %d tets", len(triangles), len(mesh.tets))
    return replace(mesh, capacitor_of_tet=conductor)


#: The last few triangulations of the wired mesher, by their geometry and sizes: a design as
#: wired and its plates alone conform to the same curves and are one triangulation (gmsh's
#: fragmenting and meshing was 8 of the glove design's 30 s of readings, its elastic mesh 4).
_TRIANGULATIONS: dict = {}
_KEEP = 4


def _triangulated(sheet: Polygon, parts: list, settings) -> tuple[np.ndarray, np.ndarray]:
    """The sheet triangulated conforming to the polygons ``parts`` (gmsh's OpenCASCADE
    fragments), ``edge_length_outline_mm`` on every inner curve graded to
    ``edge_length_mm``: counter-clockwise triangles on the used points (read-only arrays,
    shared by every caller with the same geometry and sizes)."""
    h = hashlib.sha256(repr((settings.edge_length_outline_mm, settings.edge_length_mm,
                             quality_grading_mm(settings))).encode())
    for polygon in [sheet] + list(parts):
        h.update(shapely.to_wkb(polygon))
    digest = h.hexdigest()
    if digest in _TRIANGULATIONS:
        return _TRIANGULATIONS[digest]
    with gmsh_model("wired") as gmsh:
        try:
            occ = gmsh.model.occ

            def surface(polygon):
                loops = []
                for ring in [polygon.exterior] + list(polygon.interiors):
                    xy = np.asarray(ring.coords)[:-1]
                    points = [occ.addPoint(float(x), float(y), 0.0) for x, y in xy]
                    lines = [occ.addLine(points[i], points[(i + 1) % len(points)]) for i in range(len(points))]
                    loops.append(occ.addCurveLoop(lines))
                return occ.addPlaneSurface(loops)

            sheet_tag = surface(sheet)
            tags = [surface(part) for part in parts]
            occ.fragment([(2, sheet_tag)], [(2, t) for t in tags])
            occ.synchronize()
            inner = []
            for _, curve in gmsh.model.getEntities(1):  # every curve but the sheet's edge
                x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(1, curve)
                middle = shapely.Point(0.5 * (x0 + x1), 0.5 * (y0 + y1))
                if sheet.exterior.distance(middle) > 1e-6:
                    inner.append(curve)
            field = gmsh.model.mesh.field
            distance = field.add("Distance")
            field.setNumbers(distance, "CurvesList", inner)
            field.setNumber(distance, "Sampling", 200)
            ramp = field.add("Threshold")
            for key, value in dict(InField=distance, SizeMin=settings.edge_length_outline_mm,
                                   SizeMax=settings.edge_length_mm, DistMin=0.0,
                                   DistMax=quality_grading_mm(settings)).items():
                field.setNumber(ramp, key, value)
            field.setAsBackgroundMesh(ramp)
            index, points = generate_2d(gmsh)
            types, _, element_nodes = gmsh.model.mesh.getElements(2)
            triangles = np.concatenate([index[n.astype(np.int64)].reshape(-1, 3)
                                        for t, n in zip(types, element_nodes) if t == 2])
        except Exception as exc:
            raise MeshError(f"gmsh failed to mesh the wired sheet: {exc}") from exc
    used = np.zeros(len(points), dtype=bool)
    used[triangles] = True
    renumber = np.cumsum(used) - 1
    points, triangles = points[used], renumber[triangles]
    signed = TriMesh(points.copy(), triangles.copy(), np.full(len(triangles), -1)).areas()
    triangles[signed < 0] = triangles[signed < 0][:, [0, 2, 1]]
    points.setflags(write=False)
    triangles.setflags(write=False)
    while len(_TRIANGULATIONS) >= _KEEP:
        _TRIANGULATIONS.pop(next(iter(_TRIANGULATIONS)))
    _TRIANGULATIONS[digest] = points, triangles
    return points, triangles


def _resampled(xy: np.ndarray, plate_edges, plate_vertices, spacing: float) -> np.ndarray:
    """A ring's points without those closer than ``spacing`` to the last one kept, except
    the points on a plate's edge (``plate_edges``), all of which stay: a lead's round ends
    are 32-gons of 0.05–0.1 mm sides, below the mesh size, and gmsh cuts across such
    corners with needle triangles that a pose turns inside out; a plate's edge is the same
    polyline in both layers only if both keep every one of its points."""
    xy = xy.copy()
    if plate_edges is None:
        on_plate = np.ones(len(xy), dtype=bool)
    else:  # a point a hair off a plate's edge (the files' 1e-6 mm rounding) goes onto it
        distance = shapely.distance(plate_edges, shapely.points(xy))
        near = (distance > 0) & (distance < _SNAP_MM)
        if near.any():
            along = shapely.line_locate_point(plate_edges, shapely.points(xy[near]))
            xy[near] = shapely.get_coordinates(shapely.line_interpolate_point(plate_edges, along))
        on_plate = distance < _SNAP_MM
        # and a point on an edge next to one of its vertices onto that vertex: two points
        # 1e-4 mm apart are a needle's base
        corner_distance, corner = cKDTree(plate_vertices).query(xy)
        merge = on_plate & (corner_distance > 0) & (corner_distance < 0.1 * spacing)
        xy[merge] = plate_vertices[corner[merge]]
    keep = [0]
    for p in range(1, len(xy)):
        gap = np.linalg.norm(xy[p] - xy[keep[-1]])
        if gap > _MIN_EDGE_MM and (on_plate[p] or gap >= spacing):
            keep.append(p)
    if len(keep) > 1 and np.linalg.norm(xy[keep[-1]] - xy[0]) <= _MIN_EDGE_MM:
        keep.pop()
    return xy[keep] if len(keep) >= 3 else xy


def wired_mesh(sheet: Sheet, wiring: Wiring) -> LayeredMesh:
    """``wiring``'s conductors meshed on ``sheet``'s outline, stack and mesh sizes: bottom
    conductor i, top conductor j."""
    return _meshed(sheet, wiring, sheet.mesh)


def wired_elastic_mesh(sheet: Sheet, elastic: ElasticSettings, wiring: Wiring, poses) -> LayeredMesh | None:
    """The elastic mesh of ``wiring`` on ``elastic``'s sizes and slabs (``[elastic]``):
    the elastic mesh of ``sheet`` with the nets in place of the plates, so that every lead
    is carbon-black silicone in its own conductive layer (the leads' stiffness); ``None``
    when the elastic mesh is the electrostatic one (``mesh = "shared"``: the wired mesh
    holds the nets already) or no pose of ``poses`` deforms the sheet."""
    from mscap.mesh.layered import elastic_sizes

    if elastic.mesh == "shared" or all(p.kind == "free" for p in poses):
        return None
    return _meshed(sheet, wiring, elastic_sizes(sheet, elastic, poses),
                   slabs=elastic.elements_through_thickness or None)


def _meshed(sheet: Sheet, wiring: Wiring, sizes, slabs: int | None = None) -> LayeredMesh:
    """:func:`net_mesh` of ``wiring`` on ``sheet``'s outline and stack at ``sizes``."""
    return net_mesh(sheet.outline_mm, list(wiring.bottom), list(wiring.top), sizes,
                    sheet.thicknesses_mm, sheet.mesh.elements_per_layer,
                    snap_to=shapely.ops.unary_union(wiring.plates), geometry=wiring.regions, slabs=slabs)


def readings(scene: Scene, sheet: Sheet, wiring: Wiring, mesh: LayeredMesh | None = None, progress=None,
             stiffness: Wiring | None = None, poses=None) -> tuple[np.ndarray, np.ndarray]:
    """Every pose of ``scene`` (or ``poses``) simulated on the wired mesh of ``wiring`` on
    ``sheet`` (whose layout is the design's plates and whose sizes are the design's,
    :func:`mscap.scene.sizing.sheet_for`): ``(n_poses, k)`` readings, capacitor c's the
    mutual capacitance of its row and column conductors, ``−C(bottom i, top j)`` of the
    Maxwell matrix (pF); and each pose's wall time (s). The elastic problem holds the nets
    (:func:`wired_elastic_mesh`), or those of ``stiffness`` (e.g. the plates alone meshed
    like ``wiring``: the leads as soft as the silicone around them)."""
    from mscap.fem.simulate import simulate

    poses = scene.poses if poses is None else poses
    mesh = mesh or wired_mesh(sheet, wiring)
    elastic = wired_elastic_mesh(sheet, scene.elastic, stiffness or wiring, poses)
    sim = simulate(scene, mesh=mesh, keep_fields=False, progress=progress, every_plate=False, maxwell=True,
                   elastic_mesh=elastic, poses=poses, sheet=sheet)
    k = mesh.n_capacitors
    out = np.array([[-pose.capacitances.maxwell_pF[i, k + j] for i, j in wiring.slots] for pose in sim.poses])
    wall = np.array([r.elastic_s + r.electrostatic_s for r in sim.poses])
    return out, wall
