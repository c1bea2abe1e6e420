"""Initial layouts informed by the pose family: sensitivity-map starts (issue 45 item 3).

Random and Lloyd starts spread plates over the sheet without looking at the poses; on the
glove, four Lloyd plates never reach the hand-placed layout (one plate per knuckle), and a
plate that reads nothing gets no gradient to move. A ``sensitivity`` start looks first.

**The map.** Every design pose is solved once, elastically, on the scene's own layout (no
capacitance). In the middle (dielectric) layer, each tet's deformation gradient F gives
the local parallel-plate capacitance density relative to rest,

    ρ = J_s² / J,     J = det F,   J_s = J |F⁻ᵀ e_z|,

since a plate's area grows by the in-plane areal stretch J_s and the dielectric's
thickness by J / J_s. Per triangle of the sheet (the volume-weighted mean of its tets),
the **signature** is log ρ over the design grid poses, tared against the reference pose
when the calibration names one: what a small plate there would read across the family.

**The layout.** Plates should sit where the family strains the sheet, and different
plates should read different things. Every triangle is a point in signature space,
weighted by its area times its signature's spread over the poses; a seeded, weighted
k-means (k-means++ seeding) groups them into k clusters of triangles that read alike. A
plate, a square of the scene's mean plate area as in the other starts, goes to the
strongest part of each cluster (the mean position of its triangles weighted by the square
of their sensitivity), and the squares shrink by 10 % until the layout is valid
(:func:`mscap.geometry.initial.lloyd_layout`'s rule). Clusters in signature space need not
be connected on the sheet; the weighting puts each plate on the cluster's hot spot. Where
hot spots lie too close for plates of half the mean size (two clusters sharing a region
of the sheet), each cluster's plate goes instead to its strongest triangle that leaves
room for it, the strongest cluster first.

The map costs one elastic solve per design pose (no electrostatics, no adjoint), about a
third of one optimiser evaluation, once per worker process and scene (cached).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mscap.errors import GeometryError
from mscap.geometry import polygons as geometry
from mscap.geometry.initial import (LAYOUT_INITS, Placement, initial_layout, square_fits, squares_at,
                                    valid_layout)
from mscap.geometry.layout import Layout

if TYPE_CHECKING:
    from mscap.scene.settings import Scene

__all__ = ["SensitivityMap", "sensitivity_map", "sensitivity_layout", "start_layout", "START_INITS",
           "capacitance_density", "start_design"]

#: Every ``init`` :func:`start_layout` accepts: the geometric ones and ``"sensitivity"``.
START_INITS = LAYOUT_INITS + ("sensitivity",)
#: The middle layer of the stack (dielectric between the two conductive layers).
DIELECTRIC_LAYER = 2
#: Sizes (10 % apart) tried for the squares on the clusters' hot spots before each cluster's
#: plate is moved to its strongest triangle with room instead (0.9⁷ ≈ half the mean plate size).
HOT_SPOT_SIZES = 8

_CACHE: dict[tuple, SensitivityMap] = {}


@dataclass(frozen=True, eq=False)
class SensitivityMap:
    """Per triangle of the elastic mesh's sheet triangulation: ``points`` ``(m, 2)`` rest
    centroids (mm), ``area`` ``(m,)`` (mm²), ``signature`` ``(m, n)`` log capacitance density
    over the design grid poses (tared against the reference pose when there is one, else
    against rest), and ``poses`` their names."""

    points: np.ndarray
    area: np.ndarray
    signature: np.ndarray
    poses: tuple[str, ...]

    @property
    def sensitivity(self) -> np.ndarray:
        """``(m,)`` standard deviation of each triangle's signature over the poses."""
        return self.signature.std(axis=1)


def capacitance_density(problem, nodes: np.ndarray, layer: int = DIELECTRIC_LAYER) -> np.ndarray:
    """``(n_triangles,)`` J_s² / J of ``layer`` per sheet triangle of the elastic mesh at
    node positions ``nodes`` (1 at rest); triangles without a tet of the layer give NaN."""
    mesh = problem.mesh
    tets = np.flatnonzero(mesh.layer_of_tet == layer)
    vertices = problem.nodes[tets, :4]
    x = nodes[vertices]                                       # (t, 4, 3)
    deformed = (x[:, 1:] - x[:, :1]).transpose(0, 2, 1)       # columns x_i − x_0
    f = deformed @ problem.rest_inv[tets]                     # ∂x/∂X
    j = np.linalg.det(f)
    normal = np.linalg.solve(f.transpose(0, 2, 1), np.broadcast_to([0.0, 0.0, 1.0], (len(tets), 3)))
    j_s = j * np.linalg.norm(normal, axis=1)
    density = j_s**2 / j
    weight = problem.rest_vol[tets]
    triangle = mesh.triangle_of_tet[tets]
    n = len(mesh.mesh2d.triangles)
    total = np.bincount(triangle, weights=weight * density, minlength=n)
    volume = np.bincount(triangle, weights=weight, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / volume


def sensitivity_map(scene: Scene) -> SensitivityMap:
    """The :class:`SensitivityMap` of ``scene``'s design poses (its calibration family's
    grid when it designs on one, else its listed poses), cached per process and scene."""
    from mscap.design.readback import design_poses
    from mscap.fem.petsc import Operator
    from mscap.fem.simulate import Simulation, elastic_setup, equilibria
    from mscap.mesh.layered import mesh_sheet

    designed = design_poses(scene)
    fam = designed.family
    key = (scene.path, scene.name, designed.names, tuple(map(tuple, np.round(
        np.concatenate(scene.layout.outlines), 6))))
    if key in _CACHE:
        return _CACHE[key]
    mesh = mesh_sheet(scene.sheet)
    problem, _ = elastic_setup(scene.sheet, scene.elastic, mesh, designed.poses, transfer=False)
    if problem is None:
        raise GeometryError(f"{scene.path}: every design pose is free; a sensitivity start has nothing to read")
    operator = Operator(problem)
    try:
        states, _ = equilibria(Simulation(scene.name, mesh, problem, None, (), {}), designed.poses, scene.elastic,
                               operator)
    finally:
        operator.destroy()
    density = np.array([np.ones(len(problem.mesh.mesh2d.triangles)) if s is None
                        else capacitance_density(problem, s.nodes) for s in states])   # (poses, m)
    if fam is not None:
        rows, names = fam.rows, tuple(designed.names[r] for r in fam.rows)
        base = density[fam.reference_row] if fam.reference_row is not None else 1.0
    else:
        rows, names, base = np.arange(len(states)), designed.names, 1.0
    signature = np.log(density[rows] / base).T                 # (m, n)
    tri = problem.mesh.mesh2d
    corners = tri.points[tri.triangles]
    area = 0.5 * np.abs(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    ok = np.isfinite(signature).all(axis=1)
    result = SensitivityMap(corners.mean(axis=1)[ok], area[ok], signature[ok], names)
    _CACHE[key] = result
    return result


def _weighted_kmeans(x: np.ndarray, weight: np.ndarray, k: int, rng: np.random.Generator,
                     iterations: int = 100) -> np.ndarray:
    """Labels of a weighted k-means of the rows of ``x`` (k-means++ seeding)."""
    p = weight / weight.sum()
    centres = [x[rng.choice(len(x), p=p)]]
    for _ in range(1, k):
        d2 = np.min([((x - c) ** 2).sum(axis=1) for c in centres], axis=0)
        q = p * d2
        centres.append(x[rng.choice(len(x), p=q / q.sum())] if q.sum() > 0 else x[rng.choice(len(x), p=p)])
    centres = np.array(centres)
    labels = np.zeros(len(x), dtype=int)
    for _ in range(iterations):
        labels = np.argmin(((x[:, None, :] - centres[None]) ** 2).sum(axis=2), axis=1)
        new = np.array([np.average(x[labels == c], axis=0, weights=weight[labels == c])
                        if weight[labels == c].sum() > 0 else centres[c] for c in range(k)])
        if np.allclose(new, centres, rtol=0, atol=1e-12):
            break
        centres = new
    return labels


def sensitivity_layout(scene: Scene, k: int, seed: int, smap: SensitivityMap | None = None,
                       clearance: float = 2.0) -> Layout:
    """k squares on the hot spots of k clusters of the sheet that read alike across the
    design poses (module docstring)."""
    smap = smap if smap is not None else sensitivity_map(scene)
    strength = smap.sensitivity
    weight = smap.area * strength
    if not weight.sum() > 0:
        raise GeometryError(f"{scene.path}: no design pose strains the sheet's middle layer; "
                            "a sensitivity start has nothing to read")
    if k > np.count_nonzero(weight):
        raise GeometryError(f"{scene.path}: {np.count_nonzero(weight)} strained triangles for k = {k} plates")
    rng = np.random.default_rng(seed)
    labels = _weighted_kmeans(smap.signature, weight, k, rng)
    score = smap.area * strength**2
    sites = np.array([np.average(smap.points[labels == c], axis=0, weights=score[labels == c] + 1e-300)
                      for c in range(k)])
    placement = Placement.of(scene)
    layout = squares_at(placement, sites, clearance, HOT_SPOT_SIZES)  # on the hot spots, smaller until they fit
    if layout is not None:
        return layout
    # Hot spots too close for plates half the mean size: each cluster's plate on its
    # strongest triangle that leaves room, the clusters taken strongest first.
    order = np.argsort([-weight[labels == c].sum() for c in range(k)], kind="stable")
    gap, sheet, size = clearance * placement.min_gap_mm, placement.sheet_outline_mm, placement.size_mm
    for _ in range(60):
        placed: dict[int, np.ndarray] = {}
        for c in order:
            members = np.flatnonzero(labels == c)
            for point in np.vstack([sites[c:c + 1], smap.points[members[np.argsort(-score[members])]]]):
                square = geometry.square(point, size)
                if square_fits(square, list(placed.values()), sheet, gap):
                    placed[c] = square
                    break
            else:
                break
        if len(placed) == k:
            layout = Layout(tuple(placed[c] for c in range(k)))
            if valid_layout(layout, placement, clearance):
                return layout
        size *= 0.9
    raise GeometryError(f"no valid squares at the sensitivity sites of {scene.path} for k = {k}")


def start_layout(scene: Scene, k: int | None, seed: int, init: str) -> Layout:
    """The initial layout of one start: :func:`mscap.geometry.initial.initial_layout`, or a
    :func:`sensitivity_layout` for ``init = "sensitivity"``."""
    if init == "sensitivity":
        if k is None or k < 1:
            raise GeometryError(f"k must be a positive number of capacitors, got {k!r}")
        return sensitivity_layout(scene, k, seed)
    if init not in START_INITS:
        raise GeometryError(f"unknown init {init!r}; expected one of {', '.join(START_INITS)}")
    return initial_layout(scene, k, seed, init)


def start_design(scene: Scene, k: int | None, seed: int, init: str):
    """One start, as ``mscap optimize`` and every start of the multi-start begin: its
    initial layout (:func:`start_layout`) and the :class:`~mscap.design.pipeline.Design` of
    ``scene`` on that layout, its meshes sized for its plates
    (:func:`mscap.scene.sizing.sheet_for`: ``design.sheet``). Returns ``(layout, design)``;
    ``design.poses`` are the design poses."""
    from mscap.design.pipeline import build_design
    from mscap.scene.sizing import sheet_for

    layout = start_layout(scene, k, seed, init)
    return layout, build_design(scene, sheet=sheet_for(scene, layout))
