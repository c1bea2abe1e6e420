"""A rigid ball pressed into the sheet: a smooth IPC log barrier on vertex–sphere distance.

For a node at ``x`` and a ball of centre ``c`` and radius ``r`` the distance is
``d = |x − c| − r`` and the barrier (Li et al. 2020, IPC)

    b(d) = −(d − d̂)² ln(d / d̂)   for 0 < d < d̂,   0 for d ≥ d̂,

is C² at ``d̂`` (b, b', b'' all vanish there), so the equilibrium it produces can be
differentiated (the adjoint of the next stage needs second derivatives). The contact energy
is ``κ Σ_v a_v b(d_v)`` over the top-surface nodes with lumped areas ``a_v`` (mm²), so the
barrier acts as a pressure ``κ |b'(d)|`` (MPa) independent of the mesh. A step-length bound
(:meth:`Ball.max_step`) keeps every node outside the ball along any Newton direction.

We write the point–sphere case directly: the sphere is analytic and convex, and ipctk's
mesh–mesh machinery (triangulated obstacle, broad phase, CCD) would only approximate it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Ball", "barrier", "barrier_derivatives"]


def barrier(d: np.ndarray, dhat) -> np.ndarray:
    """``b(d)`` (mm²); ``inf`` for d ≤ 0. ``dhat``: one reach, or one per entry of ``d``."""
    d = np.asarray(d, dtype=float)
    dhat = np.broadcast_to(np.asarray(dhat, dtype=float), d.shape)
    out = np.zeros_like(d)
    near = d < dhat
    with np.errstate(divide="ignore", invalid="ignore"):
        dn, h = d[near], dhat[near]
        out[near] = np.where(dn > 0, -(dn - h) ** 2 * np.log(dn / h), np.inf)
    return out


def barrier_derivatives(d: np.ndarray, dhat) -> tuple[np.ndarray, np.ndarray]:
    """``b'(d)`` (mm) and ``b''(d)`` (dimensionless); zero beyond ``dhat`` (one reach, or
    one per entry of ``d``). Needs d > 0."""
    d = np.asarray(d, dtype=float)
    dhat = np.broadcast_to(np.asarray(dhat, dtype=float), d.shape)
    db, d2b = np.zeros_like(d), np.zeros_like(d)
    near = d < dhat
    h = dhat[near]
    dn, e = d[near], d[near] - h
    log = np.log(dn / h)
    db[near] = -2 * e * log - e ** 2 / dn
    d2b[near] = -2 * log - 4 * e / dn + e ** 2 / dn ** 2
    return db, d2b


@dataclass(frozen=True)
class Ball:
    """A rigid ball acting on some nodes through the barrier.

    Attributes
    ----------
    center
        ``(3,)`` centre (mm).
    radius
        Radius (mm).
    nodes
        Indices of the nodes it can touch (the top surface).
    areas
        ``(len(nodes),)`` lumped surface areas (mm²).
    dhat
        Barrier activation distance d̂ (mm).
    stiffness
        κ (MPa/mm): the barrier pressure is ``κ |b'(d)|``.
    """

    center: np.ndarray
    radius: float
    nodes: np.ndarray
    areas: np.ndarray
    dhat: float
    stiffness: float

    def distances(self, x: np.ndarray) -> np.ndarray:
        """Gap ``d`` of each contact node at node positions ``x`` (all nodes)."""
        return np.linalg.norm(x[self.nodes] - self.center, axis=1) - self.radius

    def energy(self, x: np.ndarray) -> float:
        """Contact energy (mJ); ``inf`` if a node is inside the ball."""
        return float(self.stiffness * np.dot(self.areas, barrier(self.distances(x), self.dhat)))

    def terms(self, x: np.ndarray, project: bool = False):
        """Active nodes, their gradient ``(n, 3)`` and Hessian blocks ``(n, 3, 3)``.

        ``project`` drops the negative tangential curvature term ``b'/ρ (I − n nᵀ)``
        (b' < 0), leaving a positive semi-definite block."""
        w = x[self.nodes] - self.center
        rho = np.linalg.norm(w, axis=1)
        d = rho - self.radius
        active = np.flatnonzero(d < self.dhat)
        n = w[active] / rho[active, None]
        db, d2b = barrier_derivatives(d[active], self.dhat)
        scale = self.stiffness * self.areas[active]
        grad = (scale * db)[:, None] * n
        nn = n[:, :, None] * n[:, None, :]
        hess = (scale * d2b)[:, None, None] * nn
        if not project:
            tangential = (scale * db / rho[active])[:, None, None]
            hess = hess + tangential * (np.eye(3)[None] - nn)
        return self.nodes[active], grad, hess

    def max_step(self, x: np.ndarray, p: np.ndarray, keep: float = 0.1) -> float:
        """Largest ``α ≤ 1`` with every node's gap at least ``keep`` times its current gap
        along ``x + α p``: the root of ``|w + α p|² = (r + keep·d)²``, ``w = x − c``."""
        w, v = x[self.nodes] - self.center, p[self.nodes]
        target = self.radius + keep * (np.linalg.norm(w, axis=1) - self.radius)
        a, b, c = np.einsum("ij,ij->i", v, v), 2 * np.einsum("ij,ij->i", w, v), \
            np.einsum("ij,ij->i", w, w) - target ** 2
        disc = b * b - 4 * a * c
        moving = (a > 0) & (disc >= 0) & (b < 0)  # approaching the sphere
        with np.errstate(divide="ignore", invalid="ignore"):
            roots = (-b[moving] - np.sqrt(disc[moving])) / (2 * a[moving])
        roots = roots[roots >= 0]
        return float(min(1.0, roots.min())) if len(roots) else 1.0

    def push_out(self, x: np.ndarray, gap: float) -> np.ndarray:
        """Downward shift of each contact node needed to leave a gap ``gap`` (zero for
        nodes already clear, or above the centre, which pushing down cannot clear)."""
        w = x[self.nodes] - self.center
        reach = self.radius + gap
        horizontal2 = w[:, 0] ** 2 + w[:, 1] ** 2
        inside = (np.linalg.norm(w, axis=1) < reach) & (horizontal2 < reach ** 2) & (w[:, 2] < 0)
        shift = np.zeros(len(self.nodes))
        shift[inside] = w[inside, 2] + np.sqrt(reach ** 2 - horizontal2[inside])
        return np.maximum(shift, 0.0)
