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

from dataclasses import dataclass

import numpy as np

from .mesh2d import TriMesh

__all__ = ["LayeredMesh", "extrude", "mesh_scene", "level_heights", "tet_values", "tet_volumes", "CONDUCTIVE_LAYERS", "BOTTOM_PLATE_LAYER", "TOP_PLATE_LAYER"]

#: Layer indices (bottom to top) of the two conductive layers.
BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER = 1, 3
CONDUCTIVE_LAYERS = (BOTTOM_PLATE_LAYER, TOP_PLATE_LAYER)

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


def tet_values(mesh: LayeredMesh, layers, value) -> np.ndarray:
    """``value(material)`` of every tet, ``(M,)`` or ``(M, ...)``: the layer's material
    inside a plate, its ``fill`` (conductive layers) or material elsewhere.

    ``layers`` are :class:`mscap.scene.Layer` objects, bottom to top."""
    from .errors import MeshError

    if len(layers) <= mesh.layer_of_tet.max():
        raise MeshError(f"{len(layers)} layers given for a mesh with {mesh.layer_of_tet.max() + 1}")
    plate = np.array([value(layer.material) for layer in layers])
    fill = np.array([value(layer.fill or layer.material) for layer in layers])
    inside = (mesh.capacitor_of_tet >= 0).reshape((-1,) + (1,) * (plate.ndim - 1))
    return np.where(inside, plate[mesh.layer_of_tet], fill[mesh.layer_of_tet])


def tet_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes of the tets ``(M, 4)`` at ``points`` (positive: right-handed)."""
    p = points[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def level_heights(thicknesses_mm, elements_per_layer: int) -> tuple[np.ndarray, np.ndarray]:
    """Heights of the vertex levels and the layer of each slab between two levels."""
    thicknesses = np.asarray(thicknesses_mm, dtype=float)
    fractions = np.arange(elements_per_layer) / elements_per_layer
    bottoms = np.concatenate([[0.0], np.cumsum(thicknesses)[:-1]])
    z = (bottoms[:, None] + fractions[None, :] * thicknesses[:, None]).ravel()
    # The top level is the exact sum, so layer volumes are exact to round-off.
    z = np.append(z, np.sum(thicknesses))
    return z, np.repeat(np.arange(len(thicknesses)), elements_per_layer)


def extrude(mesh2d: TriMesh, thicknesses_mm, elements_per_layer: int = 1) -> LayeredMesh:
    """Extrude ``mesh2d`` through layers of the given thicknesses (bottom to top)."""
    z, layer_of_slab = level_heights(thicknesses_mm, elements_per_layer)
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
    triangle_of_tet = np.tile(np.repeat(np.arange(n_tri), 3), n_slabs)
    layer_of_tet = np.repeat(layer_of_slab, 3 * n_tri)

    negative = tet_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]

    capacitor_of_tet = mesh2d.capacitor_of_triangle[triangle_of_tet].copy()
    capacitor_of_tet[~np.isin(layer_of_tet, CONDUCTIVE_LAYERS)] = -1
    return LayeredMesh(mesh2d, z, points, tets, layer_of_tet, capacitor_of_tet, triangle_of_tet)


def mesh_scene(scene) -> LayeredMesh:
    """Triangulate a :class:`~mscap.scene.Scene`'s sheet and layout, then extrude it."""
    from .mesh2d import triangulate

    mesh2d = triangulate(scene.sheet_outline_mm, scene.layout, scene.mesh)
    return extrude(mesh2d, [layer.thickness_mm for layer in scene.layers], scene.mesh.elements_per_layer)
