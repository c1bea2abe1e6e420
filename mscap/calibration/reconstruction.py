"""Pose reconstruction from capacitance read-outs: an RBF map fitted on simulated
training poses, scored on an evaluation sequence under the noise model.

The map is scipy's :class:`~scipy.interpolate.RBFInterpolator` from capacitance vectors
(pF) to targets: flattened ``(n_points, dim)`` point sets (the posed object's vertices,
``dim = 3``, or the pose parameters, ``dim = 1``). Interpolation is linear in the data,
so the map is fitted once to the identity — ``weights(c)`` gives the ``n_train``
weights of the training targets — and any target set is ``weights(c) @ targets``; the
large vertex targets are never handed to scipy. Training poses with identical
capacitance vectors (a symmetric design cannot tell them apart) are merged into one
sample with the mean target, the least-squares answer, since an interpolant through both
does not exist.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator

from mscap.scene.calibration import NoiseModel

__all__ = ["Reconstructor", "fit", "PoseErrors", "point_errors", "score"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Reconstructor:
    """A fitted capacitance → target map.

    ``groups[i]`` lists the training poses merged into sample ``i``; ``targets`` are the
    merged samples' ``(n_samples, n_out)`` targets.
    """

    interpolator: RBFInterpolator
    targets: np.ndarray
    groups: tuple[np.ndarray, ...]

    def weights(self, capacitance_pF: np.ndarray) -> np.ndarray:
        """``(n, n_samples)`` weights of the training samples at ``(n, k)`` read-outs."""
        return self.interpolator(np.atleast_2d(np.asarray(capacitance_pF, dtype=float)))

    def predict(self, capacitance_pF: np.ndarray) -> np.ndarray:
        """``(n, n_out)`` reconstructed targets."""
        return self.weights(capacitance_pF) @ self.targets


def fit(capacitance_pF: np.ndarray, targets: np.ndarray, kernel: str = "thin_plate_spline",
        smoothing: float = 0.0) -> Reconstructor:
    """Fit the map on ``(n_train, k)`` capacitances and ``(n_train, n_out)`` targets.

    Raises
    ------
    ValueError
        Shapes disagree, non-finite data, or too few distinct samples for the kernel's
        polynomial part.
    """
    c = np.asarray(capacitance_pF, dtype=float)
    y = np.asarray(targets, dtype=float).reshape(len(c), -1)
    if c.ndim != 2 or len(c) != len(y) or not (np.isfinite(c).all() and np.isfinite(y).all()):
        raise ValueError(f"need finite (n, k) capacitances and (n, m) targets, got {c.shape} and {y.shape}")
    _, first, inverse = np.unique(c, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)                       # keep the training order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    label = rank[inverse.ravel()]
    groups = tuple(np.flatnonzero(label == g) for g in range(len(order)))
    if len(groups) < len(c):
        log.info("merged %d training poses with identical capacitances into %d samples",
                 len(c), len(groups))
    merged_c = c[first[order]]
    merged_y = np.array([y[g].mean(axis=0) for g in groups])
    n = len(merged_c)
    interpolator = RBFInterpolator(merged_c, np.eye(n), kernel=kernel, smoothing=smoothing)
    return Reconstructor(interpolator, merged_y, groups)


def point_errors(predicted: np.ndarray, truth: np.ndarray, dim: int) -> np.ndarray:
    """Distance of each point: ``(..., n_points * dim)`` arrays → ``(..., n_points)``."""
    d = np.asarray(predicted) - np.asarray(truth)
    return np.linalg.norm(d.reshape(*d.shape[:-1], -1, dim), axis=-1)


@dataclass(frozen=True, eq=False)
class PoseErrors:
    """Per run and sequence pose, the mean and max point error ``(runs, n_seq)``
    (mm for vertices, the parameter's unit for parameters)."""

    mean: np.ndarray
    max: np.ndarray

    def summary(self) -> dict[str, np.ndarray]:
        """Per sequence pose: mean and std over runs of the mean and max errors."""
        return {"mean_error": self.mean.mean(axis=0), "mean_error_std": self.mean.std(axis=0),
                "max_error": self.max.mean(axis=0), "max_error_std": self.max.std(axis=0)}


def score(reconstructor: Reconstructor, sequence_pF: np.ndarray, truth: np.ndarray, dim: int,
          noise: NoiseModel, rng: np.random.Generator | None = None,
          reference_pF: np.ndarray | None = None) -> PoseErrors:
    """Reconstruct the ``(n_seq, k)`` sequence read-outs under ``noise.runs`` noisy runs
    and compare with the ``(n_seq, n_out)`` true targets.

    With ``reference_pF`` (``(k,)``, the reference pose's clean capacitances; the
    reconstructor must then have been fitted on read-outs divided by it) each run also
    reads the reference once, with the run's shift and its own offset, and the map gets
    the sequence read-outs divided by that reading.

    ``rng`` defaults to one seeded with ``noise.seed``: every design scored with the same
    k then sees the same noise draws.
    """
    if reference_pF is None:
        noisy = noise.apply(sequence_pF, rng)                 # (runs, n_seq, k)
    else:
        both = noise.apply(np.vstack([sequence_pF, np.reshape(reference_pF, (1, -1))]), rng)
        noisy = both[:, :-1] / both[:, -1:]
    truth = np.asarray(truth, dtype=float).reshape(len(sequence_pF), -1)
    means, maxes = [], []
    for run in noisy:                                         # one (n_seq, n_out) block at a time
        e = point_errors(reconstructor.predict(run), truth, dim)
        means.append(e.mean(axis=1))
        maxes.append(e.max(axis=1))
    return PoseErrors(np.array(means), np.array(maxes))
