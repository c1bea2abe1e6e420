"""P1 prisms (6-node wedges): the electrostatic element of ``[mesh] element = "prism"``.

The layered mesh is a 2D triangulation extruded through the stack; every slab of it is a
layer of prisms, which :mod:`mscap.mesh.layered` cuts into three tets each. A flat tet
can hold a field that varies in-plane or vertically, but not the mixed variation of a
plate's fringe; the prism's bilinear-in-z basis can. On the same vertices (so the same
unknowns) prisms err about 3× less than the three tets (docs/performance.md §12,
measured with NGSolve; §14 with this module).

Reference prism: the triangle ``λ0 = 1 − ξ − η, λ1 = ξ, λ2 = η`` times ``ζ ∈ [0, 1]``;
nodes 0–2 on the bottom (ζ = 0), 3–5 above them; ``N_a = λ_a (1 − ζ)``, ``N_(a+3) = λ_a ζ``.
The map is isoparametric, ``x(ξ) = Σ_a x_a N_a``, so a deformed prism (top not a
translate of its bottom) is a curved element with a Jacobian ``J = Σ_a x_a ⊗ ∇̂N_a`` that
varies over it. Quadrature: the 3-point degree-2 triangle rule times 2-point Gauss in ζ,
exact for the stiffness of a right prism (J constant, integrand of degree 2 in-plane and
2 in ζ).

Shape derivative. With physical gradients ``g_a = J⁻ᵀ ∇̂N_a`` at each point and
``d det J = det J Σ_b g_b · dx_b``, ``dg_a = −Σ_b g_b (g_a · dx_b)``, the energy
``E = Σ_q w_q det J_q Σ_ab W_ab ∇φ_a · ∇φ_b`` at fixed nodal values has

    dE/dx_b = Σ_q w_q det J_q (tr(T_q) I − 2 T_q) g_bq,    T_q = Σ_ab W_ab ∇φ_a ∇φ_bᵀ,

the tets' formula (:mod:`mscap.fem.elements`) point by point, with the prism's own basis
gradients in place of the constant ``∇λ_a``: it is the exact derivative of the discrete
energy (Taylor-tested in tests/fem/test_wedge.py).
"""

from __future__ import annotations

import numpy as np

from mscap.profile import timed

__all__ = ["POINTS", "WEIGHTS", "GRADIENTS", "UPPER", "upper_stiffness", "stiffness", "energy_vjp",
           "min_jacobian", "volumes"]

#: Prisms per block of the vectorised kernels (bounds the temporaries).
BLOCK = 16384

_TRIANGLE = np.array([[1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3]])  # (ξ, η), weights 1/6 each
_GAUSS = np.array([0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)])  # ζ, weights 1/2 each
#: ``(6, 3)`` quadrature points (ξ, η, ζ) and ``(6,)`` weights (summing to the reference volume 1/2).
POINTS = np.array([[xi, eta, zeta] for zeta in _GAUSS for xi, eta in _TRIANGLE])
WEIGHTS = np.full(6, 1 / 12)


def _gradients(points: np.ndarray) -> np.ndarray:
    """Reference gradients ``(n_points, 6, 3)`` of the six basis functions."""
    xi, eta, zeta = points.T
    lam = np.stack([1 - xi - eta, xi, eta], axis=1)  # (n, 3)
    dlam = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])  # ∂λ_a/∂(ξ, η)
    out = np.empty((len(points), 6, 3))
    for a in range(3):
        out[:, a, :2] = dlam[a] * (1 - zeta)[:, None]
        out[:, a, 2] = -lam[:, a]
        out[:, a + 3, :2] = dlam[a] * zeta[:, None]
        out[:, a + 3, 2] = lam[:, a]
    return out


#: ``(6 points, 6 basis functions, 3)`` reference gradients at the quadrature points.
GRADIENTS = _gradients(POINTS)
#: Local index pairs of the upper triangle, ``np.triu_indices(6)`` order (21 entries).
UPPER = np.triu_indices(6)
for _array in (POINTS, WEIGHTS, GRADIENTS):
    _array.setflags(write=False)


def _geometry(corners: list) -> list:
    """For each quadrature point, the cofactor columns ``cof_j`` of ``det J · J⁻ᵀ`` (so
    ``det J · g_a = Σ_j ∂̂_j N_a cof_j``), each a ``(3, B)`` component row, and ``det J``,
    from the six corners' positions as component rows ``corners[a] = (3, B)``.

    J's first two columns (in-plane edges) depend on ζ only and its third (the vertical
    edge) on (ξ, η) only: 2 + 3 distinct columns, and ``col0 × col1`` per ζ, serve all six
    points."""
    x0, x1, x2, x3, x4, x5 = corners
    e1, e2, f1, f2 = x1 - x0, x2 - x0, x4 - x3, x5 - x3
    rise = (x3 - x0, x4 - x1, x5 - x2)
    out = []
    for zeta in _GAUSS:
        col0, col1 = (1 - zeta) * e1 + zeta * f1, (1 - zeta) * e2 + zeta * f2
        c2 = _cross(col0, col1)
        for xi, eta in _TRIANGLE:
            col2 = (1 - xi - eta) * rise[0] + xi * rise[1] + eta * rise[2]
            c0, c1 = _cross(col1, col2), _cross(col2, col0)
            out.append(([c0, c1, c2], col2[0] * c2[0] + col2[1] * c2[1] + col2[2] * c2[2]))
    return out


def _cross(a, b):
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _corners(rows: np.ndarray, prisms: np.ndarray) -> list:
    """The six corners of each prism as component rows ``(3, B)``."""
    index = np.ascontiguousarray(prisms.T)
    return [rows[:, index[a]] for a in range(6)]


def _pair_coefficients() -> np.ndarray:
    """``(21, 36)``: entry ``(a, b)`` of the upper triangle is ``Σ_q s_q ∇̂N_aᵀ M_q ∇̂N_b``
    with ``M_q`` the Gram matrix of the cofactor columns, whose 6 distinct entries per
    point (``i ≤ j``) are the 36 columns; off-diagonal ``(i, j)`` count twice."""
    i_up, j_up = np.triu_indices(3)
    d = GRADIENTS
    out = np.empty((21, 6, 6))  # [entry, point, Gram pair]
    for n, (a, b) in enumerate(zip(*UPPER)):
        out[n] = d[:, a, i_up] * d[:, b, j_up] + np.where(i_up != j_up, d[:, a, j_up] * d[:, b, i_up], 0.0)
    return out.reshape(21, 36)


_PAIRS = _pair_coefficients()
_PAIRS.setflags(write=False)


@timed("assembly")
def upper_stiffness(rows: np.ndarray, prisms: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    """Upper triangles ``(21, M)`` (``np.triu_indices(6)`` order) of the element matrices
    ``c ∫ ∇N_a · ∇N_b`` of ``prisms`` ``(M, 6)`` at positions ``rows`` ``(3, N)``.

    At each point ``det J (g_a · g_b) = ∇̂N_aᵀ M ∇̂N_b / det J`` with ``M = cofᵀ cof``
    (``cof = det J · J⁻ᵀ``), so a point needs its 6 distinct Gram entries and the 21
    entries are one matrix product with fixed coefficients (``_PAIRS``) over all points.

    A prism whose Jacobian is not positive at every quadrature point (inverted or
    degenerate) gets NaN as its first entry: :func:`mscap.fem.electrostatic.assemble`
    reports it, as it does a tet with a non-positive diagonal."""
    out = np.empty((21, len(prisms)))
    i_up, j_up = np.triu_indices(3)
    for start in range(0, len(prisms), BLOCK):
        block = slice(start, start + BLOCK)
        corners = _corners(rows, prisms[block])
        gram = np.empty((36, len(prisms[block])))
        worst = np.full(len(prisms[block]), np.inf)
        for q, (cof, det) in enumerate(_geometry(corners)):
            worst = np.minimum(worst, det)
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = WEIGHTS[q] * coefficient[block] / det
            for n, (i, j) in enumerate(zip(i_up, j_up)):
                np.einsum("ib,ib->b", cof[i], cof[j], out=gram[6 * q + n])
                gram[6 * q + n] *= scale
        acc = _PAIRS @ gram
        acc[0, ~(worst > 0)] = np.nan
        out[:, block] = acc
    return out


def stiffness(points: np.ndarray, prisms: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    """Full element matrices ``(M, 6, 6)`` (tests and small problems)."""
    upper = upper_stiffness(np.ascontiguousarray(np.asarray(points, dtype=float).T), prisms, coefficient)
    out = np.empty((len(prisms), 6, 6))
    for n, (a, b) in enumerate(zip(*UPPER)):
        out[:, a, b] = out[:, b, a] = upper[n]
    return out


def min_jacobian(points: np.ndarray, prisms: np.ndarray) -> np.ndarray:
    """``(M,)`` the smallest ``det J`` of each prism over its quadrature points (mm³ per
    unit reference volume; positive for a valid prism)."""
    rows = np.ascontiguousarray(np.asarray(points, dtype=float).T)
    corners = _corners(rows, prisms)
    return np.min([det for _, det in _geometry(corners)], axis=0)


def volumes(points: np.ndarray, prisms: np.ndarray) -> np.ndarray:
    """``(M,)`` volumes by the quadrature rule (exact for straight and sheared prisms)."""
    rows = np.ascontiguousarray(np.asarray(points, dtype=float).T)
    corners = _corners(rows, prisms)
    return sum(w * det for w, (_, det) in zip(WEIGHTS, _geometry(corners)))


@timed("assembly")
def energy_vjp(points: np.ndarray, prisms: np.ndarray, coefficient: np.ndarray, fields: np.ndarray,
               weights: np.ndarray) -> np.ndarray:
    """Vertex gradient ``(N, 3)`` of ``Σ_ab W_ab Σ_e c_e φ_aᵀ K_e(x) φ_b`` at fixed fields
    ``(N, m)`` (the module docstring's formula); ``weights`` ``(m, m)``, only its
    symmetric part matters.

    With ``cof = det J · J⁻ᵀ`` (columns ``cof_j``), ``det J · g_b = Σ_j ∂̂_j N_b cof_j``, and
    ``T' = det J² T``, a point adds ``Σ_j ∂̂_j N_b P_j`` to vertex b, ``P_j = w c (tr T' I −
    2T') cof_j / det J²``: the sum over points and basis functions is one matrix product
    with the reference gradients."""
    w = 0.5 * (weights + weights.T)
    n = len(points)
    out = np.zeros((3, n))
    if fields.shape[1] == 0:
        return out.T
    rows = np.ascontiguousarray(np.asarray(points, dtype=float).T)
    phis = np.ascontiguousarray(fields.T)  # (m, N)
    reference = GRADIENTS.transpose(1, 0, 2).reshape(6, 18)  # [basis b, (point q, j)]
    for start in range(0, len(prisms), BLOCK):
        block = slice(start, start + BLOCK)
        index = np.ascontiguousarray(prisms[block].T)
        size = index.shape[1]
        corners = [rows[:, index[a]] for a in range(6)]
        values = [phis[:, index[a]] for a in range(6)]  # (m, B) each
        stacked = np.empty((6, 3, 3, size))  # P_j per point: [q, j, component]
        for q, (cof, det) in enumerate(_geometry(corners)):
            d = GRADIENTS[q]
            ref = [sum(values[a] * d[a, j] for a in range(6) if d[a, j] != 0.0) for j in range(3)]  # ∂̂_j φ
            grad = [cof[0][i] * ref[0] + cof[1][i] * ref[1] + cof[2][i] * ref[2] for i in range(3)]  # det J ∇φ
            mixed = [w @ g for g in grad]
            t = {}
            for i in range(3):
                for j in range(i, 3):
                    t[i, j] = t[j, i] = np.einsum("fb,fb->b", grad[i], mixed[j])
            scale = WEIGHTS[q] * coefficient[block] / (det * det)
            trace = t[0, 0] + t[1, 1] + t[2, 2]
            m = [[scale * ((trace - 2 * t[i, k]) if i == k else -2 * t[i, k]) for k in range(3)] for i in range(3)]
            for j in range(3):
                for i in range(3):
                    stacked[q, j, i] = m[i][0] * cof[j][0] + m[i][1] * cof[j][1] + m[i][2] * cof[j][2]
        local = (reference @ stacked.reshape(18, 3 * size)).reshape(6, 3, size)
        vertices = index.ravel()
        for i in range(3):
            out[i] += np.bincount(vertices, weights=local[:, i, :].ravel(), minlength=n)
    return out.T
