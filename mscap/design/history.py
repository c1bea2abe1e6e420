"""What an optimisation records: its history columns, one row per event, and the
paper's separation metric. Light on purpose (numpy only): the HDF5 store reads and
writes histories without loading the FEM stack."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

__all__ = ["HISTORY_FIELDS", "DEFAULT_TERMS", "Record", "history_fields", "min_pairwise_l1", "pairwise_l1"]

#: The terms of the default objective, by name (:class:`mscap.design.objective.LayoutObjective`):
#: d, the capacitance term (pF², noise units, or minus the read-back bound in mm), the
#: separation barrier and the Laplacian smoothing (mm²), unweighted. A scene with
#: ``max_plate_area_mm2`` adds ``area``; a new term adds its own column by its name.
DEFAULT_TERMS = ("d", "barrier", "smoothing")

#: The columns around the objective's terms: before them the iteration (accepted steps so
#: far), the cascade level and J; after them ‖dJ/dq‖ (2-norm), the step (largest control
#: displacement, mm), min pairwise L1 distance of the poses' capacitance vectors (pF), the
#: event ("start", "step", "remesh", "revive" (:mod:`mscap.design.revival`), "cascade",
#: "converged", "stalled", "resolved", "max_iterations", "pruned"), evaluations in the line search, Newton iterations of all
#: poses in the accepted evaluation, minimum 2D angle of the electrostatic mesh (deg), the
#: largest size ratio of two neighbouring triangles of it (:mod:`mscap.mesh.shape`; NaN in
#: files written before 2026-12-05), smallest gap between two outlines or an outline and
#: the sheet edge (mm, exact: the accepted layouts never overlap), wall time since the
#: start (s), the evaluation's estimated error of J and of min_l1_pF (pF) from
#: :mod:`mscap.design.resolution` (NaN in files written before 2026-12-05).
HEAD = ("iteration", "level", "J")
TAIL = ("grad_norm", "step_mm", "min_l1_pF", "event", "evaluations", "newton_iterations", "min_angle_deg",
        "size_ratio", "min_gap_mm", "time_s", "error_J", "margin_error_pF")


def history_fields(terms=DEFAULT_TERMS) -> tuple[str, ...]:
    """The history columns, in order, of an objective with these term names."""
    return HEAD + tuple(terms) + TAIL


#: The history columns of the default objective.
HISTORY_FIELDS = history_fields()


@dataclass(frozen=True)
class Record:
    """One history row: the columns of :data:`HEAD` and :data:`TAIL` by name and the
    objective's terms, unweighted, keyed by their names (:attr:`terms`)."""

    iteration: int
    level: int
    J: float
    terms: Mapping[str, float]
    grad_norm: float
    step_mm: float
    min_l1_pF: float
    event: str
    evaluations: int
    newton_iterations: int
    min_angle_deg: float
    min_gap_mm: float
    time_s: float
    size_ratio: float = float("nan")
    error_J: float = float("nan")
    margin_error_pF: float = float("nan")

    @property
    def fields(self) -> tuple[str, ...]:
        """This row's columns, in order."""
        return history_fields(self.terms)

    def value(self, name: str):
        """The value of column ``name`` (a term's, or one of :data:`HEAD`/:data:`TAIL`)."""
        return self.terms[name] if name in self.terms else getattr(self, name)

    def row(self) -> list:
        return [self.value(name) for name in self.fields]


def pairwise_l1(capacitance_pF: np.ndarray) -> np.ndarray:
    """L1 distances (pF) between the capacitance vectors of every two poses, pairs in
    ``np.triu_indices`` order."""
    c = np.asarray(capacitance_pF, dtype=float)
    a, b = np.triu_indices(len(c), 1)
    return np.abs(c[a] - c[b]).sum(axis=1)


def min_pairwise_l1(capacitance_pF: np.ndarray) -> float:
    """Smallest L1 distance (pF) between the capacitance vectors of two poses."""
    distances = pairwise_l1(capacitance_pF)
    return float(distances.min()) if len(distances) else 0.0
