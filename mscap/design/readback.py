"""Designing for read-back: design poses from the calibration family, the read-out noise
of each protocol, and the objective terms built on them (docs/optimize.md, "Designing
for read-back").

The paper's objective separates a few hand-listed poses in pF. A sensor is judged by the
pose read back from noisy read-outs over a continuous family, so a scene with a
``[calibration]`` can instead optimise on a regular sub-grid of its training family
(:func:`design_scene`) against

- :class:`ProtocolDissimilarity`: the soft minimum of pairwise distances measured in the
  standard deviation of the read-out difference under the protocol the sensor is read
  with (tared against a reference pose, or raw), or
- :class:`ReconstructionBound`: a soft maximum over the grid of the Cramér–Rao bound on
  the RMS per-vertex error of any unbiased reconstruction, from the finite-difference
  Jacobian of the read-outs along the grid.

Both are smooth functions of the design poses' capacitances ``C`` ``(n_rows, k)`` (pF), so
``∂/∂C`` enters the existing adjoint pipeline unchanged.

Noise (appendix A, :class:`mscap.scene.calibration.NoiseModel`): per run a factor s_j uniform in
1 ± h per capacitor, per reading an offset n_j uniform in ± a pF, σ² = a²/3.

- Raw reading r = s C + n: Var(r) = (h²/3) C² + σ²; of a difference of two poses in one
  run, Var(r_a − r_b) = (h²/3) (C_a − C_b)² + 2σ².
- Tared against the reference pose read once per run, ρ̂ = r / r_ref. To first order in
  the offsets, ρ̂ = ρ + (n − ρ n_ref) / (s C_ref) with ρ = C / C_ref: s cancels from the
  mean, and E[1/s²] = 1/(1 − h²) exactly, so
  Var(ρ̂) = σ² (1 + ρ²) / (C_ref² (1 − h²)) and
  Var(ρ̂_a − ρ̂_b) = σ² (2 + (ρ_a − ρ_b)²) / (C_ref² (1 − h²)) (the shared n_ref).
  A big reference reading lowers the tared noise; a small plate's ratios drown in it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from mscap.design.terms import Term, soft_min
from mscap.scene.calibration import NoiseModel, family_poses
from mscap.scene.loader import check_optimizer, family_grid_counts
from mscap.scene.settings import Scene

__all__ = ["DesignFamily", "design_family", "design_scene", "ProtocolDissimilarity",
           "ReconstructionBound", "reading_variance", "difference_variance", "grid_pose_name", "grid_derivatives"]

# ---------------------------------------------------------------- noise per protocol
def reading_variance(capacitance_pF: np.ndarray, reference_pF: np.ndarray | None, noise: NoiseModel):
    """Variance of one read-out feature per pose and capacitor, and its derivatives.

    Tared (``reference_pF`` given, features ρ = C / C_ref): returns ``(var, ∂var/∂ρ,
    ∂var/∂C_ref at fixed ρ)``; raw (features C): ``(var, ∂var/∂C, 0)``.
    """
    h2, sigma2 = noise.relative_shift**2, noise.additive_std_pF**2
    c = np.asarray(capacitance_pF, dtype=float)
    if reference_pF is None:
        return h2 / 3 * c**2 + sigma2, 2 * h2 / 3 * c, 0.0
    scale = sigma2 / (reference_pF**2 * (1 - h2))
    var = scale * (1 + c**2)  # here c is ρ
    return var, 2 * scale * c, -2 * var / reference_pF


def difference_variance(delta: np.ndarray, reference_pF: np.ndarray | None, noise: NoiseModel):
    """Variance of the difference of two poses' read-out features in one run, and its
    derivatives: tared (``delta`` = Δρ) ``(V, ∂V/∂Δ, ∂V/∂C_ref)``; raw (Δ = ΔC)
    ``(V, ∂V/∂Δ, 0)``."""
    h2, sigma2 = noise.relative_shift**2, noise.additive_std_pF**2
    if reference_pF is None:
        return h2 / 3 * delta**2 + 2 * sigma2, 2 * h2 / 3 * delta, 0.0
    scale = sigma2 / (reference_pF**2 * (1 - h2))
    var = scale * (2 + delta**2)
    return var, 2 * scale * delta, -2 * var / reference_pF


# ---------------------------------------------------------------- design poses
@dataclass(frozen=True, eq=False)
class DesignFamily:
    """A regular sub-grid of the calibration's training family, as design poses.

    ``values`` ``(n_grid, p)`` in ``itertools.product`` order over ``axes``; ``rows`` the
    row of each grid point in the design scene's pose table (equal poses share a row);
    ``reference_row`` the reference pose's row (``None``: raw read-outs); ``derivative``
    ``(p, n_grid, n_grid)`` the difference quotients along the grid (``∂f/∂θ_p ≈ D_p f``);
    ``sensitivity`` ``(n_grid, p, p)`` GᵀG / n_points of the reconstruction targets (mm²
    per unit² of the parameters); ``prior`` ``(p,)`` the precision 12 / range² of a
    uniform prior over the training range (keeps the bound finite where the read-outs
    say nothing); ``noise`` the calibration's noise model.
    """

    parameters: tuple[str, ...]
    axes: tuple[np.ndarray, ...]
    values: np.ndarray
    rows: np.ndarray
    reference_row: int | None
    derivative: np.ndarray
    sensitivity: np.ndarray
    prior: np.ndarray
    noise: NoiseModel

    @property
    def protocol(self) -> str:
        return "raw" if self.reference_row is None else "tared"


def grid_pose_name(parameters, row) -> str:
    """``grid[flexion_deg=-25, deviation_deg=20]``: a grid pose's name says its values."""
    return "grid[" + ", ".join(f"{p}={v:g}" for p, v in zip(parameters, row)) + "]"


def _difference_matrix(values: np.ndarray) -> np.ndarray:
    """``(n, n)`` difference quotients on a 1-D grid: central inside, one-sided at the ends."""
    n = len(values)
    d = np.zeros((n, n))
    for i in range(n):
        a, b = max(i - 1, 0), min(i + 1, n - 1)
        d[i, a], d[i, b] = -1.0 / (values[b] - values[a]), 1.0 / (values[b] - values[a])
    return d


def grid_derivatives(axes) -> np.ndarray:
    """``(p, n, n)`` difference quotients along each axis of the product grid of ``axes``
    (``itertools.product`` order): Kronecker products of the 1-D operators."""
    out = []
    for i, axis in enumerate(axes):
        m = np.ones((1, 1))
        for j, other in enumerate(axes):
            m = np.kron(m, _difference_matrix(axis) if j == i else np.eye(len(other)))
        out.append(m)
    return np.array(out)


def _same_pose(a, b) -> bool:
    if a.kind == "glue" and b.kind == "glue":
        pa, pb = a.vertex_positions(1.0), b.vertex_positions(1.0)
        return a.object is b.object and pa.shape == pb.shape and np.allclose(pa, pb, rtol=0, atol=1e-9)
    try:
        return bool(replace(a, name="") == replace(b, name=""))
    except ValueError:  # array fields: compare them one by one
        fa, fb = vars(replace(a, name="")), vars(replace(b, name=""))
        return fa.keys() == fb.keys() and all(np.array_equal(fa[k], fb[k]) for k in fa)


def _targets(poses, target: str, values: np.ndarray) -> tuple[np.ndarray, int]:
    if target == "parameters":
        return np.asarray(values, dtype=float), 1
    return np.array([p.vertex_positions(1.0).ravel() for p in poses]), 3


def design_family(scene: Scene) -> tuple[tuple, DesignFamily | None]:
    """The design poses of ``scene`` (``[optimizer] design_poses``) and, when they include
    the calibration family, its :class:`DesignFamily`. Grid points take ``family_grid``
    evenly spread members of each training axis (the first and last included)."""
    check_optimizer(scene.path, scene.optimizer, scene.calibration)
    mode = scene.optimizer.design_poses
    if mode == "listed":
        return scene.poses, None
    cal = scene.calibration
    training = np.asarray(cal.training)
    full_axes = [np.unique(training[:, i]) for i in range(training.shape[1])]
    counts = family_grid_counts(scene.path, scene.optimizer, cal)
    axes = tuple(axis[np.round(np.linspace(0, len(axis) - 1, n)).astype(int)] for axis, n in zip(full_axes, counts))
    values = np.array(list(itertools.product(*axes)), dtype=float)
    template = next(p for p in scene.poses if p.name == cal.pose)
    grid = [replace(p, name=grid_pose_name(cal.parameters, v))
            for p, v in zip(family_poses(template, cal.parameters, values, "grid"), values)]
    poses = list(scene.poses) if mode == "both" else []
    if mode == "family" and cal.reference is not None:
        poses.append(next(p for p in scene.poses if p.name == cal.reference))

    def row_of(pose) -> int:
        for i, other in enumerate(poses):
            if _same_pose(pose, other):
                return i
        poses.append(pose)
        return len(poses) - 1

    rows = np.array([row_of(p) for p in grid])
    reference_row = None if cal.reference is None else \
        row_of(next(p for p in scene.poses if p.name == cal.reference))
    derivative = grid_derivatives(axes)
    x, dim = _targets(grid, cal.target, values)
    g = np.einsum("pgh,ho->gpo", derivative, x)  # ∂X/∂θ_p per grid point
    sensitivity = np.einsum("gpo,gqo->gpq", g, g) / (x.shape[1] // dim)
    span = np.array([a[-1] - a[0] for a in full_axes])
    family = DesignFamily(parameters=cal.parameters, axes=axes, values=values, rows=rows,
                          reference_row=reference_row, derivative=derivative, sensitivity=sensitivity,
                          prior=12.0 / span**2, noise=cal.noise)
    return tuple(poses), family


def design_scene(scene: Scene) -> Scene:
    """``scene`` with its design poses in place of its listed ones (the same scene when
    ``design_poses = "listed"``) and ``design_family`` set; checks ``[optimizer]``
    (:func:`mscap.scene.loader.check_optimizer`). Idempotent."""
    if scene.design_family is not None:
        return scene
    poses, family = design_family(scene)
    return scene if family is None else replace(scene, poses=poses, design_family=family)


# ---------------------------------------------------------------- objective terms
def _features(c: np.ndarray, reference_row: int | None) -> tuple[np.ndarray, np.ndarray | None]:
    if reference_row is None:
        return c, None
    return c / c[reference_row], c[reference_row]


def _back_features(c, reference_row, g_f, g_ref) -> np.ndarray:
    """∂/∂C from ∂/∂features and ∂/∂C_ref (at fixed features)."""
    if reference_row is None:
        return g_f
    ref = c[reference_row]
    grad = g_f / ref
    grad[reference_row] += g_ref - np.sum(g_f * c, axis=0) / ref**2
    return grad


@dataclass(frozen=True, eq=False)
class ProtocolDissimilarity(Term):
    """Soft minimum (τ, dimensionless) of pairwise squared distances between the design
    poses' read-outs in units of the read-out noise of the protocol:

        D_ab = Σ_j Δ_abj² / Var(Δ_abj)

    with Δ the difference of tared ratios (``reference_row`` given) or of raw readings,
    and Var from :func:`difference_variance`. A pair of poses D_ab apart is told apart
    with a z-score of √D_ab on one reading of each."""

    noise: NoiseModel
    reference_row: int | None
    tau: float = 1.0

    def value_and_gradient(self, capacitance_pF: np.ndarray) -> tuple[float, np.ndarray]:
        c = np.asarray(capacitance_pF, dtype=float)
        f, ref = _features(c, self.reference_row)
        a, b = np.triu_indices(len(c), 1)
        delta = f[a] - f[b]
        var, dvar_ddelta, dvar_dref = difference_variance(delta, ref, self.noise)
        d_pair = (delta**2 / var).sum(axis=1)
        value, weight = soft_min(d_pair, self.tau)
        # ∂D/∂Δ = 2Δ/V − Δ² V'/V², ∂D/∂V = −Δ²/V² (per capacitor)
        g_var = -weight[:, None] * delta**2 / var**2
        g_delta = weight[:, None] * 2 * delta / var + g_var * dvar_ddelta
        g_f = np.zeros_like(f)
        np.add.at(g_f, a, g_delta)
        np.add.at(g_f, b, -g_delta)
        g_ref = (g_var * dvar_dref).sum(axis=0) if ref is not None else 0.0
        return value, _back_features(c, self.reference_row, g_f, g_ref)


@dataclass(frozen=True, eq=False)
class ReconstructionBound(Term):
    """Soft maximum over the grid (temperature ``tau_mm``) of the Cramér–Rao bound on the
    RMS per-vertex reconstruction error (mm):

        J_g = Σ_h D_g,h f_h          (k × p: read-out features' sensitivity to θ)
        I_g = J_gᵀ W_g J_g + Λ       (Fisher information, W_g = 1 / Var(f_g), Λ the prior)
        e_g = tr(A_g I_g⁻¹)          (A_g = G_gᵀ G_g / n_points: mm² of the body per θ²)
        r_g = √e_g,    bound = τ log( mean_g exp(r_g/τ) )

    which lies between the mean and the max of r_g. ``value_and_gradient`` returns the
    bound (mm) and ``∂bound/∂C`` (mm/pF) over the design scene's rows."""

    family: DesignFamily
    tau_mm: float = 0.25

    @classmethod
    def of(cls, scene: Scene) -> ReconstructionBound | None:
        """The bound a design scene's runs are judged by (its design family, ``[optimizer]
        tau_mm``), or ``None`` when it has no family (:func:`design_scene`)."""
        return None if scene.design_family is None else cls(scene.design_family, scene.optimizer.tau_mm)

    def per_pose_mm(self, capacitance_pF: np.ndarray) -> np.ndarray:
        """r_g (mm) per grid point."""
        return self._forward(np.asarray(capacitance_pF, dtype=float))[0]

    def _forward(self, c):
        fam = self.family
        f_rows, ref = _features(c, fam.reference_row)
        f = f_rows[fam.rows]
        var, dvar_df, dvar_dref = reading_variance(f, ref, fam.noise)
        jac = np.einsum("pgh,hk->gkp", fam.derivative, f)
        w = 1.0 / var
        info = np.einsum("gkp,gk,gkq->gpq", jac, w, jac) + np.diag(fam.prior)
        inv = np.linalg.inv(info)
        e = np.einsum("gpq,gqp->g", fam.sensitivity, inv)
        return np.sqrt(e), (f_rows, ref, f, var, dvar_df, dvar_dref, jac, w, inv, e)

    def value_and_gradient(self, capacitance_pF: np.ndarray) -> tuple[float, np.ndarray]:
        c = np.asarray(capacitance_pF, dtype=float)
        fam, tau = self.family, self.tau_mm
        r, (f_rows, ref, f, var, dvar_df, dvar_dref, jac, w, inv, e) = self._forward(c)
        high = r.max()
        weight = np.exp((r - high) / tau)
        value = float(high + tau * np.log(weight.mean()))
        g_e = weight / weight.sum() / (2 * r)  # ∂bound/∂e_g
        # e = tr(A I⁻¹): ∂e/∂I = −I⁻¹ A I⁻¹ =: −B (symmetric)
        b = g_e[:, None, None] * np.einsum("gpq,gqr,grs->gps", inv, fam.sensitivity, inv)
        g_jac = -2 * w[:, :, None] * np.einsum("gpq,gkq->gkp", b, jac)
        g_w = -np.einsum("gkp,gpq,gkq->gk", jac, b, jac)
        g_var = -g_w * w**2
        g_f = np.einsum("pgh,gkp->hk", fam.derivative, g_jac) + g_var * dvar_df
        g_f_rows = np.zeros_like(f_rows)
        np.add.at(g_f_rows, fam.rows, g_f)
        g_ref = (g_var * dvar_dref).sum(axis=0) if ref is not None else 0.0
        return value, _back_features(c, fam.reference_row, g_f_rows, g_ref)
