"""How accurate is a result: its design re-simulated on a mesh one level finer.

Every multi-start run ends with this check (``[multistart] error_estimate``, on by
default): the optimised outlines are meshed afresh with every target edge length halved
(:func:`finer`) and all poses simulated again. The relative capacitance difference

    error_estimate = max over poses p and capacitors j of |C_pj − C'_pj| / |C'_pj|

(C on the run's own mesh, C' on the finer one) is stored beside the run's wall time
(docs/hdf5.md), so every result says what it cost and how far its numbers are from
converged. For a discretisation converging like h^p the true error of C is about
error_estimate · 2^p / (2^p − 1), i.e. between 1× and 2× the estimate for p ≥ 1.
The optimiser's C come from the initial mesh moved to the final outlines, so mesh
distortion is part of what the check measures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from mscap.design.history import min_pairwise_l1

if TYPE_CHECKING:
    from mscap.scene.settings import ElasticSettings, Scene, Sheet

__all__ = ["ErrorEstimate", "Equilibria", "finer", "estimate_error", "out_of_core", "OUT_OF_CORE_ABOVE_BYTES"]


@dataclass(frozen=True)
class ErrorEstimate:
    """``capacitance_pF`` ``(n_poses, k)`` on the finer mesh, ``error`` (relative, see
    the module), ``metric_pF`` (min pairwise L1 on the finer mesh), ``wall_s``."""

    capacitance_pF: np.ndarray
    error: float
    metric_pF: float
    wall_s: float


def finer(sheet: Sheet, elastic: ElasticSettings) -> tuple[Sheet, ElasticSettings]:
    """``sheet`` and ``elastic`` (``[elastic]``) one level finer: every target edge length
    of the mesh (its refinement zones' too) and of ``[elastic]`` halved; grading distances,
    slabs through the thickness and element orders kept (the field through a thin layer is
    resolved by the slabs already, docs/electrostatics.md)."""
    m = sheet.mesh
    mesh = replace(m, edge_length_mm=m.edge_length_mm / 2, edge_length_outline_mm=m.edge_length_outline_mm / 2,
                   zones=tuple((x, y, radius, size / 2) for x, y, radius, size in m.zones))
    fine_elastic = replace(elastic, edge_length_mm=elastic.edge_length_mm / 2,
                           edge_length_outline_mm=None if elastic.edge_length_outline_mm is None
                           else elastic.edge_length_outline_mm / 2)
    return replace(sheet, mesh=mesh), fine_elastic


#: Estimated peak (bytes, :mod:`mscap.mesh.budget`) above which the check keeps its factors
#: on disk. Only C is compared, so MUMPS may factorise out of core: biaxial's check 1,116 ->
#: 869 MB for 1.18x its time, pneumatic's 786 -> 674 MB for 1.29x (docs/performance.md §9).
#: Every paper scene's check is estimated above it (0.97-2.5 GB), jobs/quick.toml's below
#: (0.24 GB), where disk buys nothing but time.
OUT_OF_CORE_ABOVE_BYTES = 500e6


def out_of_core(sheet: Sheet, elastic: ElasticSettings, poses) -> bool:
    """Whether :func:`estimate_error` factorises ``sheet`` and ``elastic`` (already
    :func:`finer`) for ``poses`` out of core."""
    from mscap.mesh import budget

    sizes = (budget.estimate_electrostatic(sheet), budget.estimate_elastic(sheet, elastic, poses))
    return bool(max(size.memory_bytes for size in sizes if size is not None) > OUT_OF_CORE_ABOVE_BYTES)


def relative_difference(coarse_pF: np.ndarray, fine_pF: np.ndarray) -> float:
    """max |C − C'| / |C'| over all entries (the finer C' as the reference)."""
    coarse, fine = np.asarray(coarse_pF, dtype=float), np.asarray(fine_pF, dtype=float)
    if coarse.shape != fine.shape:
        raise ValueError(f"capacitance tables differ in shape: {coarse.shape} vs {fine.shape}")
    return float(np.max(np.abs(coarse - fine) / np.abs(fine))) if fine.size else float("nan")


@dataclass(frozen=True)
class Equilibria:
    """A run's final equilibria, to start the check's Newton solves from: its elastic mesh
    at the final rest positions (its own mesh, not the electrostatic one), the node table
    and element order, and each pose's displacement (``None`` for a free pose). Only what
    the interpolation needs is kept through the check, not the elastic problem (whose
    assembly tables are 50 MB on biaxial's P2 mesh)."""

    mesh: object
    nodes: np.ndarray
    order: int
    displacements: tuple

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.max()) + 1

    @classmethod
    def of(cls, evaluation) -> "Equilibria | None":
        """From a :class:`~mscap.design.pipeline.Evaluation`; ``None`` on a shared mesh
        (keeping it would keep the whole electrostatic mesh alive through the check)."""
        sim = evaluation.sim
        if sim is None or sim.elastic is None or sim.transfer is None:
            return None
        problem = sim.elastic
        return cls(problem.mesh, problem.nodes, problem.order, tuple(evaluation.displacements()))

    def on(self, problem) -> list:
        """The displacements interpolated at ``problem``'s rest nodes (the deformation map
        of the coarser mesh at the finer one's material points)."""
        from mscap.fem.transfer import interpolation_matrix

        mapping = interpolation_matrix(self, problem.rest)
        return [None if u is None else mapping @ u for u in self.displacements]


def estimate_error(scene: Scene, sheet: Sheet, capacitance_pF: np.ndarray,
                   warm: Equilibria | None = None, poses=None) -> ErrorEstimate:
    """Simulate ``sheet`` (a run's, its layout the design's) on :func:`finer` meshes
    and compare with ``capacitance_pF`` (the same layout's capacitances at ``sheet``'s own
    sizes), over ``poses`` (the design poses; default the scene's).

    ``warm``: the run's equilibria, interpolated onto the finer mesh as Newton starts
    (one load step instead of the pose's load path; the same equilibria to the Newton
    tolerance, at about half the check's Newton iterations on jobs/quick.toml,
    docs/results.md "make run's answer")."""
    from mscap.fem.simulate import simulate

    start = time.perf_counter()
    poses = scene.poses if poses is None else poses
    fine_sheet, fine_elastic = finer(sheet, scene.elastic)
    sim = simulate(scene, keep_fields=False, out_of_core=out_of_core(fine_sheet, fine_elastic, poses),
                   starts=None if warm is None else warm.on, poses=poses, sheet=fine_sheet, elastic=fine_elastic)
    fine = sim.capacitance_pF
    return ErrorEstimate(fine, relative_difference(capacitance_pF, fine), min_pairwise_l1(fine),
                         time.perf_counter() - start)
