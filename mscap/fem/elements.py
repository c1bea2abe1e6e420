"""Lagrange P1/P2 tetrahedra: basis tables and vectorised element kernels.

Geometry is always the straight-sided (affine) tet: for P2 the extra nodes are the edge
midpoints, so an element depends on the vertex positions only through the Jacobian
``J = [p1 - p0, p2 - p0, p3 - p0]`` (edges as columns). Physical basis gradients are
``G = D J⁻¹`` with ``D`` the reference gradients (rows), so a stiffness matrix is
``vol · Σ_q w_q D_q A D_qᵀ`` with ``A = J⁻¹ J⁻ᵀ`` and quadrature weights ``w_q`` that sum
to 1. The reference tensor ``S[k, l] = Σ_q w_q D_q[:, k] ⊗ D_q[:, l]`` turns assembly
into one matrix product over all elements.

Shape derivative (straight-sided P1/P2). For ``E = vol Σ_q w_q Σ_ab W_ab g_aq · g_bq``
with field gradients ``g = J⁻ᵀ ĝ`` held at fixed nodal values and ``W`` symmetric,
``d vol = vol tr(J⁻¹ dJ)`` and ``dg = -J⁻ᵀ dJᵀ g`` give

    dE/dp_a = vol (tr(T) I - 2 T) ∇λ_a,    T = Σ_q w_q Σ_ab W_ab g_aq g_bqᵀ,

with ``∇λ_a`` the P1 (vertex) gradients: the Maxwell stress of the field acting on the
vertices. The rows sum to zero (translation invariance) for any field.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mscap.profile import timed

__all__ = ["Element", "P1", "P2", "element", "basis_gradients", "dof_table", "jacobians", "stiffness",
           "upper_stiffness", "energy_vjp", "index_type"]

#: Elements per block in the vectorised kernels (bounds temporary memory, not a loop
#: over elements: each block is processed by whole-array operations).
BLOCK = 32768


def index_type(largest: int) -> type:
    """``np.int32`` for index arrays whose values stay below ``largest`` < 2³¹, else
    ``np.int64``: the index arrays of a problem are most of its memory (docs/performance.md §9)."""
    return np.int32 if largest < 2 ** 31 else np.int64

#: The 6 edges of a tet as local vertex pairs; P2 edge node ``4 + e`` sits on edge ``e``.
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])

# Reference gradients of the barycentric coordinates λ0 = 1 - ξ - η - ζ, λ1..3 = ξ, η, ζ.
_DLAMBDA = np.array([[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Element:
    """A Lagrange tet element on the reference tet.

    Attributes
    ----------
    order
        Polynomial degree (1 or 2).
    weights
        ``(nq,)`` quadrature weights, normalised to sum to 1 (multiply by the volume).
    gradients
        ``(nq, nb, 3)`` reference gradients of the ``nb`` basis functions at the points.
    tensor
        ``(3, 3, nb, nb)`` reference stiffness tensor ``Σ_q w_q D_q[:, k] ⊗ D_q[:, l]``.
    """

    order: int
    weights: np.ndarray
    gradients: np.ndarray
    tensor: np.ndarray

    @property
    def n_basis(self) -> int:
        return self.gradients.shape[1]


def basis_gradients(order: int, barycentric) -> np.ndarray:
    """Reference gradients ``(n_points, nb, 3)`` of the basis functions at points given by
    their barycentric coordinates ``(n_points, 4)``."""
    lam = np.asarray(barycentric, dtype=float)
    if order == 1:
        return np.broadcast_to(_DLAMBDA, (len(lam), 4, 3)).copy()
    # N_a = λa(2λa − 1) → (4λa − 1)∇λa;  N_ab = 4 λa λb → 4(λa ∇λb + λb ∇λa).
    vertex = (4 * lam - 1)[:, :, None] * _DLAMBDA[None]
    a, b = TET_EDGES[:, 0], TET_EDGES[:, 1]
    edge = 4 * (lam[:, a, None] * _DLAMBDA[b][None] + lam[:, b, None] * _DLAMBDA[a][None])
    return np.concatenate([vertex, edge], axis=1)


def _make(order: int, barycentric: np.ndarray, weights: np.ndarray) -> Element:
    grads = basis_gradients(order, barycentric)
    weights = np.asarray(weights, dtype=float)
    tensor = np.einsum("q,qik,qjl->klij", weights, grads, grads)
    for array in (weights, grads, tensor):
        array.setflags(write=False)
    return Element(order, weights, grads, tensor)


# P1 gradients are constant: one point. P2: the integrand |∇φ|² has degree 2, and the
# 4-point rule (a, b, b, b), a = (5 + 3√5)/20, b = (5 − √5)/20, is exact for degree 2.
_A, _B = (5 + 3 * np.sqrt(5)) / 20, (5 - np.sqrt(5)) / 20
P1 = _make(1, [[0.25] * 4], [1.0])
P2 = _make(2, _B + (_A - _B) * np.eye(4), [0.25] * 4)


def element(order: int) -> Element:
    """The element of the given order (1 or 2)."""
    return {1: P1, 2: P2}[order]


def dof_table(tets: np.ndarray, n_vertices: int, order: int) -> tuple[np.ndarray, int]:
    """Degrees of freedom per tet and their number.

    P1 dofs are the vertices. P2 adds one dof per unique edge, numbered after the
    vertices (``n_vertices + edge``), so vertex values are the first ``n_vertices``
    entries of any P2 field.

    Returns
    -------
    dofs
        ``(M, 4)`` or ``(M, 10)`` dof indices, local order as :data:`TET_EDGES`.
    n_dofs
        Total number of dofs.
    """
    tets = np.asarray(tets, dtype=np.int64)
    if order == 1:
        return tets, n_vertices
    pairs = np.sort(tets[:, TET_EDGES], axis=2)  # (M, 6, 2)
    keys = pairs[:, :, 0] * n_vertices + pairs[:, :, 1]
    unique, edge_of = np.unique(keys.ravel(), return_inverse=True)
    dofs = np.concatenate([tets, n_vertices + edge_of.reshape(-1, 6)], axis=1)
    return dofs, n_vertices + len(unique)


def _edges(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edge vectors from vertex 0 (the columns of J), each as (3, M) component rows:
    component-wise products then run on long contiguous arrays, 2x faster than np.cross
    on (M, 3) (measured on 300k tets)."""
    x = np.asarray(points, dtype=float).T
    p0 = x[:, tets[:, 0]]
    return x[:, tets[:, 1]] - p0, x[:, tets[:, 2]] - p0, x[:, tets[:, 3]] - p0


def _cross(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Components of a × b for (3, M) rows."""
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def jacobians(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse Jacobians ``(M, 3, 3)`` and signed volumes ``(M,)`` of affine tets."""
    e0, e1, e2 = _edges(points, tets)
    # Rows of J⁻¹ are the cofactor vectors e1×e2, e2×e0, e0×e1 over det J.
    inv = np.empty((len(tets), 3, 3))
    for row, (a, b) in enumerate(((e1, e2), (e2, e0), (e0, e1))):
        inv[:, row, 0], inv[:, row, 1], inv[:, row, 2] = _cross(a, b)
    det = e0[0] * inv[:, 0, 0] + e0[1] * inv[:, 0, 1] + e0[2] * inv[:, 0, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv /= det[:, None, None]
    return inv, det / 6.0


@timed("assembly")
def stiffness(el: Element, points: np.ndarray, tets: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    """Element matrices ``coefficient · ∫ ∇N_i · ∇N_j`` for all tets, ``(M, nb, nb)``.

    ``coefficient`` is ``(M,)``; volumes are taken as signed (callers reject inverted
    tets)."""
    if el.order == 1:
        return _p1_stiffness(points, tets, coefficient)
    return _tensor_stiffness(el, points, tets, coefficient)


def _tensor_stiffness(el: Element, points: np.ndarray, tets: np.ndarray, coefficient: np.ndarray,
                      entries: np.ndarray | None = None) -> np.ndarray:
    """Any order: ``vol · A : S`` with the reference tensor ``S`` (module docstring), as
    ``(M, nb, nb)`` matrices, or only the flat entries ``entries`` of each, ``(M, len(entries))``."""
    nb = el.n_basis
    tensor = el.tensor.reshape(9, nb * nb)
    if entries is not None:
        tensor = tensor[:, entries]
    out = np.empty((len(tets), tensor.shape[1]))
    for start in range(0, len(tets), BLOCK):
        block = slice(start, start + BLOCK)
        inv, vol = jacobians(points, tets[block])
        metric = (inv @ inv.transpose(0, 2, 1)).reshape(-1, 9)  # A = J⁻¹ J⁻ᵀ
        out[block] = (metric * (coefficient[block] * vol)[:, None]) @ tensor
    return out if entries is not None else out.reshape(-1, nb, nb)


@timed("assembly")
def upper_stiffness(el: Element, rows: np.ndarray, tets: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    """The upper triangles of :func:`stiffness`'s element matrices, entry by entry in the
    order of ``np.triu_indices(nb)``, as rows ``(nb (nb + 1) / 2, M)``: all a symmetric
    assembly needs (10 of 16 P1 entries, 55 of 100 P2 ones).

    ``rows`` are the vertex positions as contiguous component rows ``(3, N)`` (``x.T``,
    made contiguous once per assembly). For P1 the entries are computed row by row on
    component rows, 1.7× faster with the scatter than full matrices (measured on 242k
    tets, docs/performance.md §2)."""
    if el.order == 1:
        return _p1_upper_stiffness(rows, tets, coefficient)
    upper = np.ravel_multi_index(np.triu_indices(el.n_basis), (el.n_basis,) * 2)
    return _tensor_stiffness(el, rows.T, tets, coefficient, upper).T


def _row_cofactors(rows: np.ndarray, corners: np.ndarray) -> tuple[tuple, np.ndarray]:
    """``c_a = det J ∇λ_a`` for a = 1, 2, 3 (the rows of ``det J · J⁻¹``: e1×e2, e2×e0,
    e0×e1), each as three component rows, and ``det J``, from positions as component rows
    ``(3, N)`` and the tets' vertices as index rows ``(4, M)`` (contiguous: faster gathers)."""
    p0 = rows[:, corners[0]]
    e0, e1, e2 = (rows[:, corners[a]] - p0 for a in (1, 2, 3))
    c1, c2, c3 = _cross(e1, e2), _cross(e2, e0), _cross(e0, e1)
    return (c1, c2, c3), e0[0] * c1[0] + e0[1] * c1[1] + e0[2] * c1[2]


def _p1_upper_stiffness(rows: np.ndarray, tets: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    """:func:`upper_stiffness` for P1: ``c (c_a · c_b) / (6 det J)``, ``c_a = det J ∇λ_a``."""
    (c1, c2, c3), det = _row_cofactors(rows, np.ascontiguousarray(tets.T))
    c = (tuple(-(c1[i] + c2[i] + c3[i]) for i in range(3)), c1, c2, c3)
    scale = coefficient / (6.0 * det)
    out = np.empty((10, len(det)))
    for n, (a, b) in enumerate(zip(*np.triu_indices(4))):
        entry = out[n]
        np.multiply(c[a][0], c[b][0], out=entry)
        entry += c[a][1] * c[b][1]
        entry += c[a][2] * c[b][2]
        entry *= scale
    return out


def _p1_stiffness(points: np.ndarray, tets: np.ndarray, coefficient: np.ndarray) -> np.ndarray:
    """P1: the full matrices from :func:`_p1_upper_stiffness` (1.9× the general path's
    speed, measured on 359k tets)."""
    rows = np.ascontiguousarray(np.asarray(points, dtype=float).T)
    out = np.empty((len(tets), 4, 4))
    for start in range(0, len(tets), BLOCK):
        block = slice(start, start + BLOCK)
        upper = _p1_upper_stiffness(rows, tets[block], coefficient[block])
        for n, (a, b) in enumerate(zip(*np.triu_indices(4))):
            out[block, a, b] = out[block, b, a] = upper[n]
    return out


@timed("assembly")
def energy_vjp(el: Element, points: np.ndarray, tets: np.ndarray, dofs: np.ndarray,
               coefficient: np.ndarray, fields: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Vertex gradient of ``Σ_ab W_ab Σ_e c_e φ_aᵀ K_e(x) φ_b`` at fixed fields.

    Parameters
    ----------
    el
        The element.
    points
        ``(N, 3)`` vertex positions.
    tets, dofs
        ``(M, 4)`` vertices and ``(M, nb)`` dofs of the elements to include.
    coefficient
        ``(M,)`` coefficient per element.
    fields
        ``(n_dofs, m)`` nodal values of ``m`` fields.
    weights
        ``(m, m)`` weights ``W``; only its symmetric part matters.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` derivative with respect to the vertex positions.
    """
    w = 0.5 * (weights + weights.T)
    if fields.shape[1] == 0:
        return np.zeros((len(points), 3))
    if el.order == 1:
        return _p1_energy_vjp(points, tets, coefficient, fields, w)
    return _quadrature_energy_vjp(el, points, tets, dofs, coefficient, fields, w)


def _quadrature_energy_vjp(el: Element, points: np.ndarray, tets: np.ndarray, dofs: np.ndarray,
                           coefficient: np.ndarray, fields: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Any order: the module docstring's formula, point by point of the quadrature rule."""
    nq, m = len(el.weights), fields.shape[1]
    ref_rows = el.gradients.transpose(0, 2, 1).reshape(nq * 3, el.n_basis)  # rows (q, k)
    out = np.zeros((len(points), 3))
    for start in range(0, len(tets), BLOCK):
        block = slice(start, start + BLOCK)
        inv, vol = jacobians(points, tets[block])
        ref = (ref_rows @ fields[dofs[block]]).reshape(-1, nq, 3, m)  # ĝ per point and field
        grad = np.matmul(np.swapaxes(inv, 1, 2)[:, None], ref)  # g = J⁻ᵀ ĝ, (m_e, nq, 3, m)
        mixed = (grad @ w) * el.weights[None, :, None, None]
        t = np.einsum("eqif,eqjf->eij", grad, mixed, optimize=True)
        g1 = _DLAMBDA @ inv  # P1 gradients ∇λ_a, (m_e, 4, 3)
        trace = np.trace(t, axis1=1, axis2=2)
        local_grad = (coefficient[block] * vol)[:, None, None] * (trace[:, None, None] * g1 - 2 * g1 @ t)
        vertices = tets[block].ravel()
        for c in range(3):
            out[:, c] += np.bincount(vertices, weights=local_grad[:, :, c].ravel(), minlength=len(points))
    return out


def _p1_energy_vjp(points: np.ndarray, tets: np.ndarray, coefficient: np.ndarray, fields: np.ndarray,
                   w: np.ndarray) -> np.ndarray:
    """:func:`energy_vjp` for P1 (one gradient per tet), on component rows with the fields
    as rows ``(m, n_dofs)``: 2.7× the general path's speed (measured on 359k tets, 4 fields),
    and 1.2–1.4× more since the vertex terms go through one symmetric 3 × 3 matrix per tet
    (242k tets, docs/performance.md §2).

    With ``c_a = det J ∇λ_a`` and ``det J · g = Σ_a φ_a c_a``, the vertex term
    ``vol (tr(T) I − 2T) ∇λ_a`` is ``M c_a`` with ``M = (tr(T') I − 2 T') / (6 det J²)``,
    ``T'`` being ``T`` built from ``det J · g``; the four terms sum to zero (``Σ_a c_a = 0``).
    """
    out = np.zeros((3, len(points)))
    rows = np.ascontiguousarray(np.asarray(points, dtype=float).T)
    phis = np.ascontiguousarray(fields.T)  # (m, n_dofs)
    for start in range(0, len(tets), BLOCK):
        corners = np.ascontiguousarray(tets[start:start + BLOCK].T)
        cofactors, det = _row_cofactors(rows, corners)
        c = (None, *cofactors)  # c_0 = −(c_1 + c_2 + c_3) is not needed
        phi0 = phis[:, corners[0]]
        d = [None] + [phis[:, corners[a]] - phi0 for a in (1, 2, 3)]  # (m, B) each
        grad = []  # det J · g_i, (m, B) each
        for i in range(3):
            g = d[1] * c[1][i]
            g += d[2] * c[2][i]
            g += d[3] * c[3][i]
            grad.append(g)
        mixed = [w @ g for g in grad]
        t = {}
        for i in range(3):
            for j in range(i, 3):
                t[i, j] = t[j, i] = np.einsum("fb,fb->b", grad[i], mixed[j])
        scale = coefficient[start:start + BLOCK] / (6.0 * det * det)
        trace = t[0, 0] + t[1, 1] + t[2, 2]
        m = {}
        for i in range(3):
            for j in range(i, 3):
                m[i, j] = m[j, i] = ((trace - 2 * t[i, j]) if i == j else -2 * t[i, j]) * scale
        local = np.empty((3, 4, len(det)))
        for i in range(3):
            for a in (1, 2, 3):
                entry = local[i, a]
                np.multiply(m[i, 0], c[a][0], out=entry)
                entry += m[i, 1] * c[a][1]
                entry += m[i, 2] * c[a][2]
            np.add(local[i, 1], local[i, 2], out=local[i, 0])
            local[i, 0] += local[i, 3]
            np.negative(local[i, 0], out=local[i, 0])
        vertices = corners.ravel()
        for i in range(3):
            out[i] += np.bincount(vertices, weights=local[i].ravel(), minlength=len(points))
    return out.T
