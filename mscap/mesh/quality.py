"""Mesh quality measures, vectorised over all elements."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from mscap.mesh.layered import LayeredMesh, tet_volumes
from mscap.mesh.shape import MeshQuality, neighbour_size_ratios, triangle_angles_deg

__all__ = ["triangle_angles_deg", "dihedral_angles_deg", "aspect_ratios", "MeshReport", "mesh_report",
           "quality_verdict"]

# The 6 edges of a tet and, for each, the two faces meeting there (face f omits vertex f).
_TET_EDGE_FACES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]])  # edges 01,02,03,12,13,23


def _face_normals(p: np.ndarray) -> np.ndarray:
    """Outward (area-weighted) normals of the 4 faces; face f is opposite vertex f."""
    faces = np.array([[1, 3, 2], [0, 2, 3], [0, 3, 1], [0, 1, 2]])
    a, b, c = p[:, faces[:, 0]], p[:, faces[:, 1]], p[:, faces[:, 2]]
    return 0.5 * np.cross(b - a, c - a)


def dihedral_angles_deg(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``(M, 6)`` interior dihedral angles of positively oriented tets, degrees."""
    n = _face_normals(points[tets])
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    cos = -np.einsum("mek,mek->me", n[:, _TET_EDGE_FACES[:, 0]], n[:, _TET_EDGE_FACES[:, 1]])
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def aspect_ratios(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Longest edge over inradius, scaled so a regular tet scores 1."""
    p = points[tets]
    edge_pairs = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
    longest = np.linalg.norm(p[:, edge_pairs[:, 1]] - p[:, edge_pairs[:, 0]], axis=2).max(axis=1)
    area = np.linalg.norm(_face_normals(p), axis=2).sum(axis=1)
    volume = np.abs(tet_volumes(points, tets))
    inradius = 3.0 * volume / area
    return longest / (2.0 * np.sqrt(6.0) * inradius)


@dataclass(frozen=True)
class MeshReport:
    """Counts and quality of a layered mesh."""

    vertices_2d: int
    triangles: int
    vertices: int
    tets: int
    conductor_tets: int
    capacitors: int
    min_angle_2d_deg: float
    max_size_ratio_2d: float
    quality_2d: str
    min_dihedral_deg: float
    max_aspect_ratio: float
    time_s: float

    def as_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        return [
            f"2D mesh        {self.vertices_2d:>10d} vertices {self.triangles:>10d} triangles",
            f"3D mesh        {self.vertices:>10d} vertices {self.tets:>10d} tets",
            f"conductors     {self.capacitors:>10d} plates   {self.conductor_tets:>10d} tets",
            f"min 2D angle   {self.min_angle_2d_deg:>10.2f} deg",
            f"size ratio     {self.max_size_ratio_2d:>10.2f} (largest between neighbouring triangles)",
            f"2D quality     {self.quality_2d}",
            f"min dihedral   {self.min_dihedral_deg:>10.3f} deg",
            f"max aspect     {self.max_aspect_ratio:>10.1f} (longest edge / inradius, regular tet = 1)",
            f"time           {self.time_s:>10.2f} s",
        ]


def mesh_report(mesh: LayeredMesh, time_s: float) -> MeshReport:
    """Summarise ``mesh``; ``time_s`` is the time it took to build."""
    quality = mesh.mesh2d.quality
    verdict = "not measured" if quality is None else quality_verdict(quality)
    return MeshReport(
        vertices_2d=len(mesh.mesh2d.points), triangles=len(mesh.mesh2d.triangles),
        vertices=len(mesh.points), tets=len(mesh.tets),
        conductor_tets=int(np.count_nonzero(mesh.capacitor_of_tet >= 0)),
        capacitors=mesh.n_capacitors,
        min_angle_2d_deg=float(triangle_angles_deg(mesh.mesh2d.points, mesh.mesh2d.triangles).min())
        if quality is None else quality.min_angle_deg,
        max_size_ratio_2d=float(neighbour_size_ratios(mesh.mesh2d.points, mesh.mesh2d.triangles)[0].max(initial=1.0))
        if quality is None else quality.max_size_ratio,
        quality_2d=verdict,
        min_dihedral_deg=float(dihedral_angles_deg(mesh.points, mesh.tets).min()),
        max_aspect_ratio=float(aspect_ratios(mesh.points, mesh.tets).max()),
        time_s=time_s,
    )


def quality_verdict(quality: MeshQuality) -> str:
    """One line: does the 2D mesh meet the quality its error model assumes?"""
    if quality.meets:
        return "meets the kept quality" + (" (meshed again with a gentler size field)" if quality.repaired else "")
    return "BELOW the quality the error model assumes: " + quality.describe()
