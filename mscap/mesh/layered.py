"""The layered sensor mesh: the 2D triangulation extruded through the 5-layer stack.

Vertex numbering is ``level * n2 + v`` for 2D vertex ``v`` on level ``level`` (level 0
is the bottom surface), so the 3D → (2D vertex, level) map is pure arithmetic.

Each prism is cut into 3 tets by the global-vertex-index rule: every quad side face is
split by the diagonal through its smallest-index vertex. Two prisms sharing a side face
see the same four vertices, so they cut it the same way and the tet mesh conforms
(Porumbescu et al. 2005, cited in paper §4.1). With the triangle's vertices sorted
a < b < c, the smallest vertex of each side face is its lower-left one, which gives the
three tets below.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mscap.errors import GeometryError
from mscap.profile import timed
from mscap.geometry.layout import Layout, check_layout
from mscap.geometry.polygons import coarsened
from mscap.mesh.triangulate import TriMesh

if TYPE_CHECKING:
    from mscap.scene.settings import ElasticSettings, MeshSettings, Sheet

log = logging.getLogger(__name__)

__all__ = ["LayeredMesh", "extrude", "prisms_of", "mesh_sheet", "extrude_sheet", "mesh_elastic", "elastic_sizes",
           "elastic_layout", "level_heights", "layer_fractions", "tet_values", "tet_volumes", "CONDUCTIVE_LAYERS",
           "BOTTOM_PLATE_LAYER", "TOP_PLATE_LAYER"]

#: Layer indices (bottom to top) of the two conductive layers.
BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER = 1, 3
CONDUCTIVE_LAYERS = (BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER)

#: Tets per block where per-tet work would otherwise make whole-mesh temporaries.
TET_BLOCK = 65536

# Local tets of a prism whose bottom triangle is (a, b, c), a < b < c, and whose top is
# (a', b', c'): indices 0..2 bottom, 3..5 top. The side faces' diagonals a-b', b-c', a-c'
# all start at the smaller bottom vertex. Orientation is fixed afterwards.
_PRISM_TETS = np.array([[0, 1, 2, 5], [0, 1, 5, 4], [0, 3, 4, 5]])


@dataclass(frozen=True)
class LayeredMesh:
    """Tetrahedral mesh of the sensor.

    Attributes
    ----------
    mesh2d
        The triangulation that was extruded.
    level_z_mm
        ``(L + 1,)`` heights of the vertex levels, bottom surface first.
    points
        ``(N, 3)`` rest positions, ``N = (L + 1) * n2``.
    tets
        ``(M, 4)`` positively oriented vertex indices.
    layer_of_tet
        ``(M,)`` stack layer 0..4, bottom to top.
    capacitor_of_tet
        ``(M,)`` capacitor index for conductor tets (inside an outline, in a conductive
        layer), -1 elsewhere.
    triangle_of_tet
        ``(M,)`` the 2D triangle the tet was extruded from.
    """

    mesh2d: TriMesh
    level_z_mm: np.ndarray
    points: np.ndarray
    tets: np.ndarray
    layer_of_tet: np.ndarray
    capacitor_of_tet: np.ndarray
    triangle_of_tet: np.ndarray

    def __post_init__(self):
        for name in ("level_z_mm", "points", "tets", "layer_of_tet", "capacitor_of_tet", "triangle_of_tet"):
            getattr(self, name).setflags(write=False)

    @property
    def n_capacitors(self) -> int:
        return int(self.mesh2d.capacitor_of_triangle.max()) + 1

    @property
    def vertex_2d(self) -> np.ndarray:
        """``(N,)`` the 2D vertex each 3D vertex sits above."""
        return np.arange(len(self.points)) % len(self.mesh2d.points)

    @property
    def vertex_level(self) -> np.ndarray:
        """``(N,)`` the level of each 3D vertex (0 = bottom surface)."""
        return np.arange(len(self.points)) // len(self.mesh2d.points)

    def volumes(self, points: np.ndarray | None = None) -> np.ndarray:
        """Signed tet volumes (mm³) at ``points`` (default: rest positions)."""
        return tet_volumes(self.points if points is None else points, self.tets)


def layer_fractions(mesh: LayeredMesh, thicknesses_mm, tets: slice = slice(None)) -> np.ndarray:
    """``(M, n_layers)`` exact volume fraction of each stack layer inside each tet.

    A tet of an extruded mesh has its vertices on the two levels of its slab, ``k`` of
    them on the lower one. Its cross-section at ``s = (z − z_lo)/(z_hi − z_lo)`` is a
    triangle shrinking to the top (k = 3), a parallelogram ∝ s(1 − s) (k = 2) or a triangle
    growing from the bottom (k = 1), so the volume fraction below ``s`` is 1 − (1 − s)³,
    3s² − 2s³ or s³. Slabs between layer interfaces give one-hot rows.

    ``tets`` selects a range of tets (the rows of the result).
    """
    z = mesh.points[mesh.tets[tets], 2]
    lo, hi = z.min(axis=1), z.max(axis=1)
    k = np.sum(np.isclose(z, lo[:, None], rtol=0, atol=1e-12 * max(1.0, float(hi.max()))), axis=1)
    interfaces = np.concatenate([[0.0], np.cumsum(np.asarray(thicknesses_mm, dtype=float))])
    s = np.clip((interfaces[None, :] - lo[:, None]) / (hi - lo)[:, None], 0.0, 1.0)  # (M, L + 1)
    below = np.select([k[:, None] == 3, k[:, None] == 2], [1 - (1 - s) ** 3, s * s * (3 - 2 * s)], s ** 3)
    return np.diff(below, axis=1)


def tet_values(mesh: LayeredMesh, layers, value) -> np.ndarray:
    """``value(material)`` of every tet, ``(M,)`` or ``(M, ...)``: the layer's material
    inside a plate (a wired sensor: inside that conductive layer's own conductors,
    ``mesh2d.conductor_of_layer``), its ``fill`` (conductive layers) or material elsewhere.
    A tet that spans several layers (an elastic mesh coarser than the stack) gets the
    volume-weighted mean, which for a constant-strain (P1) tet and an energy linear in the
    material constants is its exact energy.

    ``layers`` are :class:`mscap.scene.settings.Layer` objects, bottom to top."""
    from mscap.errors import MeshError

    if len(layers) <= mesh.layer_of_tet.max():
        raise MeshError(f"{len(layers)} layers given for a mesh with {mesh.layer_of_tet.max() + 1}")
    plate = np.array([value(layer.material) for layer in layers])
    fill = np.array([value(layer.fill or layer.material) for layer in layers])
    thicknesses = [layer.thickness_mm for layer in layers]
    out = np.empty((len(mesh.tets),) + plate.shape[1:])
    # A block of tets at a time: the fractions' temporaries are ~250 bytes per tet (350 MB
    # on a 1.46 M tet finer-mesh check, the peak of building its electrostatic problem).
    for start in range(0, len(mesh.tets), TET_BLOCK):
        block = slice(start, start + TET_BLOCK)
        fractions = layer_fractions(mesh, thicknesses, block)
        triangles = mesh.triangle_of_tet[block]
        by_layer = mesh.mesh2d.conductor_of_layer
        if by_layer is None:
            inside = mesh.mesh2d.capacitor_of_triangle[triangles] >= 0
            out[block] = np.where(inside.reshape((-1,) + (1,) * (plate.ndim - 1)),
                                  np.tensordot(fractions, plate, axes=1), np.tensordot(fractions, fill, axes=1))
        else:  # each conductive layer inside its own conductors: fill there, the plate's material in it
            out[block] = np.tensordot(fractions, fill, axes=1)
            for column, layer in enumerate((BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER)):
                inside = by_layer[triangles, column] >= 0
                out[block][inside] += np.multiply.outer(fractions[inside, layer], plate[layer] - fill[layer])
    return out


def tet_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes ``(M,)`` of the tets ``(M, 4)`` at ``points`` (det J / 6, positive:
    right-handed). On component rows ``(3, M)``, not ``np.cross`` on ``(M, 3)``: 1.4x faster."""
    x = np.asarray(points, dtype=float).T
    p0 = x[:, tets[:, 0]]
    e0, e1, e2 = x[:, tets[:, 1]] - p0, x[:, tets[:, 2]] - p0, x[:, tets[:, 3]] - p0
    c0, c1, c2 = e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]
    return (e0[0] * c0 + e0[1] * c1 + e0[2] * c2) / 6.0


def level_heights(thicknesses_mm, elements_per_layer: int) -> tuple[np.ndarray, np.ndarray]:
    """Heights of the vertex levels and the layer of each slab between two levels."""
    thicknesses = np.asarray(thicknesses_mm, dtype=float)
    fractions = np.arange(elements_per_layer) / elements_per_layer
    bottoms = np.concatenate([[0.0], np.cumsum(thicknesses)[:-1]])
    z = (bottoms[:, None] + fractions[None, :] * thicknesses[:, None]).ravel()
    # The top level is the exact sum, so layer volumes are exact to round-off.
    z = np.append(z, np.sum(thicknesses))
    return z, np.repeat(np.arange(len(thicknesses)), elements_per_layer)


def extrude(mesh2d: TriMesh, thicknesses_mm, elements_per_layer: int = 1,
            slabs: int | None = None) -> LayeredMesh:
    """Extrude ``mesh2d`` through layers of the given thicknesses (bottom to top).

    With ``slabs``, the levels split the whole stack evenly instead of following the
    layer interfaces (an elastic mesh; ``layer_of_tet`` is then the layer at the slab's
    middle and :func:`layer_fractions` gives the exact mix)."""
    z, layer_of_slab = level_heights(thicknesses_mm, elements_per_layer)
    if slabs is not None:
        z = np.linspace(0.0, z[-1], slabs + 1)
        z[-1] = np.sum(thicknesses_mm)
        interfaces = np.cumsum(thicknesses_mm)[:-1]
        layer_of_slab = np.searchsorted(interfaces, 0.5 * (z[1:] + z[:-1]))
    n2, n_slabs = len(mesh2d.points), len(layer_of_slab)
    points = np.empty((len(z), n2, 3))
    points[:, :, :2] = mesh2d.points[None]
    points[:, :, 2] = z[:, None]
    points = points.reshape(-1, 3)

    tri = np.sort(mesh2d.triangles, axis=1)
    slab = np.arange(n_slabs)[:, None, None]
    prism = np.concatenate([tri[None] + slab * n2, tri[None] + (slab + 1) * n2], axis=2)  # (S, T, 6)
    tets = prism[:, :, _PRISM_TETS].reshape(-1, 4)  # slab-major, then triangle, then local tet
    n_tri = len(tri)
    # Narrow per-tet tags (22 MB less on a 1.46 M tet finer-mesh check, docs/performance.md §9).
    triangle_of_tet = np.tile(np.repeat(np.arange(n_tri, dtype=np.int32), 3), n_slabs)
    layer_of_tet = np.repeat(layer_of_slab.astype(np.int8), 3 * n_tri)

    negative = np.concatenate([tet_volumes(points, tets[start:start + TET_BLOCK]) < 0  # temporaries: a block's
                               for start in range(0, len(tets), TET_BLOCK)])  # (were 200 MB on 1.46 M tets)
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]

    capacitor_of_tet = mesh2d.capacitor_of_triangle.astype(np.int32)[triangle_of_tet]
    capacitor_of_tet[~np.isin(layer_of_tet, CONDUCTIVE_LAYERS)] = -1
    return LayeredMesh(mesh2d, z, points, tets, layer_of_tet, capacitor_of_tet, triangle_of_tet)


def prisms_of(mesh: LayeredMesh) -> np.ndarray:
    """``(M / 3, 6)`` the prisms ``mesh``'s tets were cut from, in the tets' order (prism
    ``p`` is tets ``3p .. 3p + 2``): bottom triangle then the vertices above it, turned so
    that the bottom runs counter-clockwise (a positive Jacobian at rest,
    :mod:`mscap.fem.wedge`)."""
    n2, n_slabs = len(mesh.mesh2d.points), len(mesh.level_z_mm) - 1
    tri = np.sort(mesh.mesh2d.triangles, axis=1)
    xy = mesh.mesh2d.points
    e1, e2 = xy[tri[:, 1]] - xy[tri[:, 0]], xy[tri[:, 2]] - xy[tri[:, 0]]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    tri[clockwise] = tri[clockwise][:, [0, 2, 1]]
    slab = np.arange(n_slabs)[:, None, None]
    prisms = np.concatenate([tri[None] + slab * n2, tri[None] + (slab + 1) * n2], axis=2).reshape(-1, 6)
    if 3 * len(prisms) != len(mesh.tets):
        raise ValueError(f"the mesh has {len(mesh.tets)} tets, not 3 per prism of its {len(prisms)} prisms")
    return prisms


@timed("meshing")
def mesh_sheet(sheet: Sheet) -> LayeredMesh:
    """Triangulate a :class:`~mscap.scene.settings.Sheet` (the sheet and its plates), then
    extrude it through its layers.

    Raises
    ------
    MeshError
        Before gmsh starts, when the mesh would not fit in memory
        (:func:`mscap.mesh.budget.check_fits`)."""
    from mscap.mesh.budget import check_fits, estimate_electrostatic
    from mscap.mesh.triangulate import triangulate

    check_fits(estimate_electrostatic(sheet), sheet.path)  # before gmsh: refuses what would not fit
    return extrude_sheet(sheet, triangulate(sheet.outline_mm, sheet.layout, sheet.mesh))


def extrude_sheet(sheet: Sheet, mesh2d: TriMesh) -> LayeredMesh:
    """``mesh2d`` extruded through ``sheet``'s layers (:func:`mesh_sheet`'s second half;
    the same mesh again from the same triangulation)."""
    return extrude(mesh2d, sheet.thicknesses_mm, sheet.mesh.elements_per_layer)


def elastic_layout(layout: Layout, sheet_outline_mm: np.ndarray, spacing_mm: float) -> Layout:
    """``layout`` with every outline :func:`~mscap.geometry.polygons.coarsened` to the
    elastic mesh's outline spacing, or ``layout`` itself if that would make the outlines
    cross.

    An optimised outline passes through every outline vertex of the electrostatic mesh
    (0.075 mm apart), and gmsh keeps every polygon vertex as a mesh node: embedded as it
    is, poking_cross's best k = 6 design gave a 21,070-node elastic mesh where 1,752 were
    meant, and biaxial's finer-mesh check (P2) needed 2.8 GB (docs/performance.md §9).
    """
    coarse = Layout(tuple(coarsened(o, spacing_mm) for o in layout.outlines))
    if all(len(c) == len(o) for c, o in zip(coarse.outlines, layout.outlines)):
        return layout
    try:
        check_layout(coarse, sheet_outline_mm, 0.0)
    except GeometryError as exc:
        log.info("elastic mesh: the outlines coarsened to %g mm would not be valid (%s); "
                 "embedding them as they are", spacing_mm, exc)
        return layout
    return coarse


def elastic_sizes(sheet: Sheet, elastic: ElasticSettings, poses) -> MeshSettings:
    """The 2D sizes of the elastic mesh of its own (``elastic``: ``[elastic]``) beside
    ``sheet``'s electrostatic mesh: ``edge_length_mm`` (outlines:
    ``edge_length_outline_mm``, default half), no fringe grading; P1 refines under the balls
    as the electrostatic mesh does (its ``zones``), P2 under the balls and along the held
    edges of ``poses`` where :func:`mscap.scene.sizing.refines_pokes`
    (:func:`~mscap.scene.sizing.p2_poke_refinement`)."""
    from dataclasses import replace

    from mscap.scene.sizing import p2_poke_refinement, refines_pokes

    h = elastic.edge_length_mm
    outline = min(elastic.edge_length_outline_mm or 0.5 * h, h)
    zones, strips = sheet.mesh.zones, ()
    if elastic.order != 1:
        zones, strips = p2_poke_refinement(poses, sheet.outline_mm, h) if refines_pokes(elastic, sheet.mesh) \
            else ((), ())
    return replace(sheet.mesh, edge_length_mm=h, edge_length_outline_mm=outline, fringe_distance_mm=0.0,
                   zones=zones, strips=strips)


@timed("meshing")
def mesh_elastic(sheet: Sheet, elastic: ElasticSettings, mesh: LayeredMesh, poses) -> LayeredMesh:
    """The elastic mesh (``elastic``: ``[elastic]``) beside ``mesh``, ``sheet``'s
    electrostatic mesh: ``mesh`` itself when ``mesh = "shared"``, else a triangulation with
    the outlines embedded (:func:`elastic_layout`), so every tet lies inside or outside a
    plate, at ``edge_length_mm`` (outlines: ``edge_length_outline_mm``, default half),
    extruded in ``elements_through_thickness`` even slabs (0: the levels of ``mesh``),
    refined for ``poses`` (:func:`elastic_sizes`)."""
    from mscap.mesh.budget import check_fits, estimate_elastic
    from mscap.mesh.triangulate import triangulate

    if elastic.mesh == "shared":
        return mesh
    check_fits(estimate_elastic(sheet, elastic, poses), sheet.path)  # before gmsh
    sizes = elastic_sizes(sheet, elastic, poses)
    mesh2d = triangulate(sheet.outline_mm, elastic_layout(sheet.layout, sheet.outline_mm,
                                                          sizes.edge_length_outline_mm), sizes)
    return extrude(mesh2d, sheet.thicknesses_mm, sheet.mesh.elements_per_layer,
                   slabs=elastic.elements_through_thickness or None)
