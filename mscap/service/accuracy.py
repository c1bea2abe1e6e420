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
    from mscap.scene.settings import Scene

__all__ = ["ErrorEstimate", "finer", "estimate_error"]


@dataclass(frozen=True)
class ErrorEstimate:
    """``capacitance_pF`` ``(n_poses, k)`` on the finer mesh, ``error`` (relative, see
    the module), ``metric_pF`` (min pairwise L1 on the finer mesh), ``wall_s``."""

    capacitance_pF: np.ndarray
    error: float
    metric_pF: float
    wall_s: float


def finer(scene: Scene):
    """``scene`` one level finer: every target edge length of ``[mesh]`` (its refinement
    zones' too) and ``[elastic]`` halved; grading distances, slabs through the thickness and element
    orders kept (the field through a thin layer is resolved by the slabs already,
    docs/electrostatics.md)."""
    mesh = replace(scene.mesh, edge_length_mm=scene.mesh.edge_length_mm / 2,
                   edge_length_outline_mm=scene.mesh.edge_length_outline_mm / 2,
                   zones=tuple((x, y, radius, size / 2) for x, y, radius, size in scene.mesh.zones))
    el = scene.elastic
    elastic = replace(el, edge_length_mm=el.edge_length_mm / 2,
                      edge_length_outline_mm=None if el.edge_length_outline_mm is None
                      else el.edge_length_outline_mm / 2)
    return replace(scene, mesh=mesh, elastic=elastic)


def relative_difference(coarse_pF: np.ndarray, fine_pF: np.ndarray) -> float:
    """max |C − C'| / |C'| over all entries (the finer C' as the reference)."""
    coarse, fine = np.asarray(coarse_pF, dtype=float), np.asarray(fine_pF, dtype=float)
    if coarse.shape != fine.shape:
        raise ValueError(f"capacitance tables differ in shape: {coarse.shape} vs {fine.shape}")
    return float(np.max(np.abs(coarse - fine) / np.abs(fine))) if fine.size else float("nan")


def estimate_error(scene: Scene, layout, capacitance_pF: np.ndarray) -> ErrorEstimate:
    """Simulate ``layout`` on :func:`finer` ``(scene)`` and compare with
    ``capacitance_pF`` (the same layout's capacitances at the scene's own settings)."""
    from mscap.fem.simulate import simulate

    start = time.perf_counter()
    # Only C is compared; the factors go to disk (biaxial's check: 1,116 -> 869 MB for 1.18x
    # its time; pneumatic's: 786 -> 674 MB for 1.29x; docs/performance.md §9).
    sim = simulate(replace(finer(scene), layout=layout), keep_fields=False, out_of_core=True)
    fine = sim.capacitance_pF
    return ErrorEstimate(fine, relative_difference(capacitance_pF, fine), min_pairwise_l1(fine),
                         time.perf_counter() - start)
