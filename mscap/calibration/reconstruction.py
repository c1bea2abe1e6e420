"""Pose reconstruction from capacitance read-outs: an RBF map fitted on simulated
training poses, scored on an evaluation sequence under the noise model.

The map is scipy's :class:`~scipy.interpolate.RBFInterpolator` from read-out features to
targets: flattened ``(n_points, dim)`` point sets (the posed object's vertices,
``dim = 3``, or the pose parameters, ``dim = 1``). Interpolation is linear in the data,
so the map is fitted once to the identity — ``weights(c)`` gives the ``n_train``
weights of the training targets — and any target set is ``weights(c) @ targets``; the
large vertex targets are never handed to scipy. Training poses with identical
capacitance vectors (a symmetric design cannot tell them apart) are merged into one
sample with the mean target, the least-squares answer, since an interpolant through both
does not exist.

**Whitened features** (``noise_std`` given; the default of ``mscap calibrate``). The
paper's map works on the read-outs as they are. Where a design's read-outs vary over the
training family in some direction by far less than the noise (two plates that read
alike, a plate that reads nothing: 1e-4 noise standard deviations on the glove), an
interpolant through the clean training data has a huge slope there, and the noise of a
read-out along it sends the answer metres away (1,064 mm mean error for a four-plate
glove design whose read-back bound is 0.34 mm; docs/calibration.md). Here the features
are divided by their noise standard deviation, rotated onto the principal directions of
the training read-outs, and the directions whose training spread is below ``min_spread``
noise standard deviations are dropped: along them the read-outs carry nothing to
reconstruct from, and the map stays flat. ``smoothing`` then acts in noise units.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RBFInterpolator

from mscap.scene.calibration import MIN_SPREAD, NoiseModel

__all__ = ["Features", "Reconstructor", "fit", "whitened", "PoseErrors", "point_errors", "score", "MIN_SPREAD"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Features:
    """The coordinates the map works in: ``(c − center) @ projection``, ``(n, k) → (n, m)``.
    ``spread[i]`` is the training read-outs' standard deviation along the i-th principal
    direction in noise standard deviations (largest first); ``m`` of them are kept."""

    center: np.ndarray
    projection: np.ndarray
    spread: np.ndarray

    def __call__(self, capacitance_pF: np.ndarray) -> np.ndarray:
        return (np.atleast_2d(np.asarray(capacitance_pF, dtype=float)) - self.center) @ self.projection

    @property
    def directions(self) -> int:
        return self.projection.shape[1]


def whitened(features: np.ndarray, noise_std: np.ndarray, min_spread: float = MIN_SPREAD) -> Features:
    """The principal directions of ``(n, k)`` training ``features`` in units of their noise
    standard deviations ``(k,)``, those with a spread of at least ``min_spread`` kept."""
    c = np.asarray(features, dtype=float)
    std = np.asarray(noise_std, dtype=float).reshape(-1)
    if std.shape != (c.shape[1],) or not (np.isfinite(std).all() and (std > 0).all()):
        raise ValueError(f"need {c.shape[1]} finite positive noise standard deviations, got {std}")
    center = c.mean(axis=0)
    _, singular, rows = np.linalg.svd((c - center) / std, full_matrices=False)
    spread = singular / np.sqrt(len(c))
    keep = spread >= min_spread
    return Features(center, rows[keep].T / std[:, None], spread)


@dataclass(frozen=True, eq=False)
class Reconstructor:
    """A fitted capacitance → target map.

    ``groups[i]`` lists the training poses merged into sample ``i``; ``targets`` are the
    merged samples' ``(n_samples, n_out)`` targets; ``features`` maps read-outs to the
    interpolator's coordinates (``None``: the read-outs themselves). Without an
    interpolator (no direction above the noise) the map answers the mean sample.
    """

    interpolator: RBFInterpolator | None
    targets: np.ndarray
    groups: tuple[np.ndarray, ...]
    features: Features | None = None

    def weights(self, capacitance_pF: np.ndarray) -> np.ndarray:
        """``(n, n_samples)`` weights of the training samples at ``(n, k)`` read-outs."""
        c = np.atleast_2d(np.asarray(capacitance_pF, dtype=float))
        if self.interpolator is None:  # the mean training pose
            sizes = np.array([len(g) for g in self.groups], dtype=float)
            return np.broadcast_to(sizes / sizes.sum(), (len(c), len(sizes))).copy()
        return self.interpolator(c if self.features is None else self.features(c))

    def predict(self, capacitance_pF: np.ndarray) -> np.ndarray:
        """``(n, n_out)`` reconstructed targets."""
        return self.weights(capacitance_pF) @ self.targets


def fit(capacitance_pF: np.ndarray, targets: np.ndarray, kernel: str = "thin_plate_spline",
        smoothing: float = 0.0, noise_std: np.ndarray | None = None,
        min_spread: float = MIN_SPREAD) -> Reconstructor:
    """Fit the map on ``(n_train, k)`` read-outs and ``(n_train, n_out)`` targets; with
    ``noise_std`` (``(k,)``, the noise standard deviation of each read-out) on the
    :func:`whitened` features.

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
    features = None if noise_std is None else whitened(c, noise_std, min_spread)
    if features is not None:
        if not features.directions:
            log.warning("no direction of the read-outs varies over the training family by %g noise "
                        "standard deviations (largest: %.3g): the map answers the mean pose",
                        min_spread, features.spread.max(initial=0.0))
            return Reconstructor(None, merged_y, groups, features)
        merged_c = features(merged_c)
    n = len(merged_c)
    interpolator = RBFInterpolator(merged_c, np.eye(n), kernel=kernel, smoothing=smoothing)
    return Reconstructor(interpolator, merged_y, groups, features)


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
