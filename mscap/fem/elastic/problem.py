"""Quasi-static elasticity of the sheet: an :class:`ElasticProblem` per mesh, assembly.

The unknowns are the current positions of the nodes (P1: the vertices; P2: the vertices,
then one node per unique edge), three components each, dof ``3 node + i``. Everything
that depends only on the mesh — rest gradients and volumes, Lamé parameters, the sparsity
pattern and the element → CSR maps — is computed once by :func:`build_problem`;
:func:`assemble` then gives energy, gradient and Hessian for any positions. The Newton
solver with load stepping lives in :mod:`mscap.fem.elastic.newton`.

The Hessian is assembled by 3 × 3 node blocks: one ``bincount`` per block entry over the
``nb²`` node pairs of every element, then a fixed permutation to scalar CSR. Every pose
uses the same CSR pattern (Dirichlet rows and columns are replaced by the identity in
place), so PETSc's symbolic factorisation is done once per mesh.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from mscap.errors import ElasticError
from mscap.fem import elements as fem
from mscap.fem.elastic import neohookean
from mscap.profile import timed
from mscap.mesh.layered import LayeredMesh, tet_values

__all__ = ["ElasticError", "ElasticProblem", "Assembly", "build_problem", "rest_geometry", "lame_of_tets",
           "nodal_deformation_gradients", "carried_displacement",
           "assemble", "total_energy", "node_values", "tet_fields"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ElasticProblem:
    """Everything about the elastic system that depends on the mesh only.

    Attributes
    ----------
    mesh, order
        The layered mesh and the element order (1 or 2).
    nodes
        ``(M, nb)`` node indices of each tet (P1: vertices; P2: vertices then edges).
    rest
        ``(n_nodes, 3)`` rest node positions (P2 edge nodes at edge midpoints).
    edge_vertices
        ``(n_edges, 2)`` end vertices of each P2 edge node (empty for P1).
    rest_inv, rest_vol
        ``(M, 3, 3)`` inverse rest Jacobians and ``(M,)`` rest volumes (mm³).
    mu, lam
        ``(M,)`` Lamé parameters (MPa).
    diag_block
        ``(n_nodes,)`` the block (i, i).
    indptr, indices
        Scalar CSR pattern of the ``3 n_nodes`` square matrix.
    csr_of_block
        ``(n_blocks · 9,)`` CSR data position of block entry ``9 b + 3 c + d``.
    scatter
        Per chunk of :attr:`block` elements, the sparse 0/1 matrix that sums
        the chunk's node-pair blocks into the global blocks (one sparse product).
    force_scale
        ``(n_nodes,)`` ``Σ μ_e vol_e^(2/3)`` over the node's elements (N): gradients divided
        by it are residual stresses over μ, a dimensionless residual.
    """

    mesh: LayeredMesh
    order: int
    nodes: np.ndarray
    rest: np.ndarray
    edge_vertices: np.ndarray
    rest_inv: np.ndarray
    rest_vol: np.ndarray
    mu: np.ndarray
    lam: np.ndarray
    diag_block: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    csr_of_block: np.ndarray
    force_scale: np.ndarray
    scatter: tuple

    def __post_init__(self):
        for value in vars(self).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @property
    def n_nodes(self) -> int:
        return len(self.rest)

    @property
    def block(self) -> int:
        """Elements per assembly chunk: :func:`elements_per_block`."""
        return elements_per_block(self.nodes.shape[1])

    @property
    def n_dofs(self) -> int:
        return 3 * len(self.rest)

    @property
    def element(self) -> fem.Element:
        return fem.element(self.order)

    @property
    def n_vertices(self) -> int:
        return len(self.mesh.points)


@dataclass(frozen=True)
class Assembly:
    """Energy (mJ = N·mm), gradient ``(n_nodes, 3)`` (N), Hessian CSR data (pattern of the
    problem, N/mm) or ``None``, and the smallest J over all quadrature points."""

    energy: float
    gradient: np.ndarray
    hessian: np.ndarray | None
    min_j: float


def lame_of_tets(mesh: LayeredMesh, layers: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """``(μ, λ)`` (MPa) of every tet: the layer's material, or its ``fill`` off the plates."""
    lame = tet_values(mesh, layers, lambda material: material.lame_MPa)
    return lame[:, 0].copy(), lame[:, 1].copy()


def rest_geometry(mesh: LayeredMesh, what: str = "rest mesh") -> tuple[np.ndarray, np.ndarray]:
    """Inverse rest Jacobians and volumes of every tet; a tet with volume ≤ 0 raises."""
    rest_inv, rest_vol = fem.jacobians(mesh.points, mesh.tets)
    if not (rest_vol > 0).all():
        bad = int(np.argmin(rest_vol))
        raise ElasticError(f"tet {bad} of the {what} is inverted or flat (volume {rest_vol[bad]:.3g} mm³)")
    return rest_inv, rest_vol


def build_problem(mesh: LayeredMesh, layers: Sequence, order: int = 1) -> ElasticProblem:
    """Rest geometry, materials and the Hessian's sparsity pattern (once per mesh)."""
    if order not in (1, 2):
        raise ElasticError(f"element order must be 1 or 2, got {order!r}")
    started = time.perf_counter()
    n_vertices = len(mesh.points)
    nodes, n_nodes = fem.dof_table(mesh.tets, n_vertices, order)
    if order == 2:
        edges = np.zeros((n_nodes - n_vertices, 2), dtype=np.int64)
        edges[nodes[:, 4:] - n_vertices] = np.sort(mesh.tets[:, fem.TET_EDGES], axis=2)
        rest = np.concatenate([mesh.points, 0.5 * mesh.points[edges].sum(axis=1)])
    else:
        edges, rest = np.zeros((0, 2), dtype=np.int64), mesh.points.copy()
    rest_inv, rest_vol = rest_geometry(mesh)
    mu, lam = lame_of_tets(mesh, layers)

    nb = nodes.shape[1]
    keys = (nodes[:, :, None] * n_nodes + nodes[:, None, :]).ravel()
    unique, block_of_pair = np.unique(keys, return_inverse=True)
    del keys
    rows, cols = np.divmod(unique, n_nodes)
    degree = np.bincount(rows, minlength=n_nodes)
    node_ptr = np.concatenate([[0], np.cumsum(degree)])
    diag_block = np.flatnonzero(rows == cols)
    # Scalar row 3i + c holds 3 deg(i) entries: block q of row i, component (c, d) sits at
    # 9 ptr(i) + 3 c deg(i) + 3 (q − ptr(i)) + d.
    offset = np.arange(len(unique)) - node_ptr[rows]
    c, d = np.divmod(np.arange(9), 3)
    csr_of_block = (9 * node_ptr[rows][:, None] + 3 * c[None] * degree[rows][:, None]
                    + 3 * offset[:, None] + d[None]).ravel()
    indices = np.empty(9 * len(unique), dtype=fem.index_type(3 * n_nodes))  # int32: 55 MB less on biaxial's check
    indices[csr_of_block] = (3 * cols[:, None] + d[None]).ravel()
    indptr = np.concatenate([[0], np.cumsum(np.repeat(3 * degree, 3))])

    scale = mu * rest_vol ** (2.0 / 3.0)
    force_scale = np.bincount(nodes.ravel(), weights=np.repeat(scale, nb), minlength=n_nodes)
    scatter, block = [], elements_per_block(nb)
    for start in range(0, len(nodes), block):
        # Pair order (a, b, element) of neohookean.element_terms' Hessian layout.
        pairs = block_of_pair[start * nb * nb:(start + block) * nb * nb]
        pairs = pairs.reshape(-1, nb * nb).T.ravel()
        scatter.append(sp.csr_matrix((np.ones(len(pairs)), (pairs, np.arange(len(pairs)))),
                                     shape=(len(unique), len(pairs))))
    problem = ElasticProblem(mesh, order, nodes, rest, edges, rest_inv, rest_vol, mu, lam,
                             diag_block,
                             indptr.astype(np.int64), indices, csr_of_block.astype(fem.index_type(len(indices))),
                             force_scale,
                             tuple(scatter))
    log.info("elastic P%d problem: %d nodes, %d dofs, %d nonzeros (%.2f s)", order, n_nodes,
             3 * n_nodes, len(indices), time.perf_counter() - started)
    return problem


#: Hessian entries per assembly chunk: :data:`mscap.fem.elements.BLOCK` P1 tets (144 each,
#: 38 MB of doubles).
HESSIAN_ENTRIES_PER_BLOCK = fem.BLOCK * 144


def elements_per_block(nb: int) -> int:
    """Elements per assembly chunk for ``nb`` nodes per element: :data:`fem.BLOCK` for P1,
    fewer for P2 (900 Hessian entries each), so that a chunk's element Hessians and their
    temporaries take the same memory as for P1. With P1's block, a P2 chunk's temporaries
    were 570 MB, the peak of the biaxial finer-mesh check."""
    return max(1, min(fem.BLOCK, HESSIAN_ENTRIES_PER_BLOCK // (9 * nb * nb)))


def node_values(problem: ElasticProblem, vertex_values: np.ndarray) -> np.ndarray:
    """Extend per-vertex values to all nodes (P2 edge nodes: mean of the two ends), which is
    exact for fields linear on each edge."""
    if problem.order == 1:
        return vertex_values
    return np.concatenate([vertex_values, 0.5 * vertex_values[problem.edge_vertices].sum(axis=1)])


@timed("assembly")
def assemble(problem: ElasticProblem, x: np.ndarray, hessian: bool = True,
             project: bool = False) -> Assembly:
    """Elastic energy, gradient and Hessian at node positions ``x`` ``(n_nodes, 3)``.

    An inverted element (J ≤ 0 at a quadrature point) gives ``energy = inf`` and no
    Hessian. ``project`` makes every element Hessian positive semi-definite."""
    el = problem.element
    nodes = problem.nodes
    energy, min_j = 0.0, np.inf
    gradient = np.zeros((problem.n_nodes, 3))
    # Block entries in CSR-block order (pair, 9): ``data[csr_of_block] = blocks.ravel()``
    # then needs no transposed copy (65 MB on biaxial's finer-mesh check).
    blocks = np.zeros((len(problem.indices) // 9, 9)) if hessian else None
    for start in range(0, len(nodes), problem.block):
        part = slice(start, start + problem.block)
        terms = neohookean.element_terms(el, problem.rest_inv[part], problem.rest_vol[part],
                                         x[nodes[part]], problem.mu[part], problem.lam[part],
                                         hessian=hessian, project=project)
        min_j = min(min_j, float(terms.min_j.min()))
        if not np.isfinite(terms.energy).all():
            return Assembly(np.inf, gradient, None, min_j)
        energy += float(terms.energy.sum())
        flat = nodes[part].ravel()
        for i in range(3):
            gradient[:, i] += np.bincount(flat, weights=terms.gradient[:, :, i].ravel(), minlength=problem.n_nodes)
        if hessian:
            local = terms.hessian.reshape(9, -1)
            scatter = problem.scatter[start // problem.block]
            for e in range(9):
                blocks[:, e] += scatter @ local[e]
    data = None
    if hessian:
        data = np.empty(len(problem.indices))
        data[problem.csr_of_block] = blocks.ravel()
    return Assembly(energy, gradient, data, min_j)


def total_energy(problem: ElasticProblem, x: np.ndarray) -> tuple[float, float]:
    """Elastic energy (``inf`` if inverted) and min J at ``x``, without derivatives."""
    energy, min_j = 0.0, np.inf
    for start in range(0, len(problem.nodes), problem.block):
        part = slice(start, start + problem.block)
        e, j = neohookean.element_energy(problem.element, problem.rest_inv[part], problem.rest_vol[part],
                                         x[problem.nodes[part]], problem.mu[part], problem.lam[part])
        energy += float(e.sum())
        min_j = min(min_j, float(j.min()))
    return (energy if np.isfinite(energy) else np.inf), min_j


def nodal_deformation_gradients(problem: ElasticProblem, x: np.ndarray) -> np.ndarray:
    """``(n_nodes, 3, 3)`` deformation gradient at every node: each element's F = ∂x/∂X at
    the node (the element's own basis gradients there), averaged over the node's elements.
    Exact for an affine ``x``."""
    gradients = _nodal_basis_gradients(problem.order)  # [node a, basis b, 3]
    F = np.zeros((problem.n_nodes, 3, 3))
    for start in range(0, len(problem.nodes), problem.block):
        part = slice(start, start + problem.block)
        nodes = problem.nodes[part]
        G = gradients[None] @ problem.rest_inv[part][:, None]  # [m, a, b, 3] = ∇_X N_b at node a
        local = np.einsum("mbi,mabj->maij", x[nodes], G)
        for i in range(3):
            for j in range(3):
                F[:, i, j] += np.bincount(nodes.ravel(), weights=local[:, :, i, j].ravel(), minlength=problem.n_nodes)
    count = np.bincount(problem.nodes.ravel(), minlength=problem.n_nodes)
    return F / count[:, None, None]


def _nodal_basis_gradients(order: int) -> np.ndarray:
    """Reference basis gradients ``(nb, nb, 3)`` at the element's own nodes (vertices, then
    P2 edge midpoints)."""
    barycentric = np.eye(4)
    if order == 2:
        barycentric = np.concatenate([barycentric, 0.5 * barycentric[fem.TET_EDGES].sum(axis=1)])
    return fem.basis_gradients(order, barycentric)


def carried_displacement(problem: ElasticProblem, x: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """A pose's displacement at new rest positions ``rest`` of the same mesh, from its
    equilibrium ``x`` at ``problem.rest``: every node keeps its place in the deformed body,
    ``x' = x + F δX`` (``δX = rest − problem.rest``, F at the node), so the start is the old
    deformation map evaluated at the moved node to first order. For a design step, which
    moves nodes within unchanged layers, this is the new equilibrium up to the change of
    discretisation; keeping the displacement instead (``x' = x + δX``) strains the body by
    ``(F − I) ∇δX``. Returns ``x' − rest`` ``(n_nodes, 3)``."""
    delta = rest - problem.rest
    return x - problem.rest + np.einsum("nij,nj->ni", nodal_deformation_gradients(problem, x), delta) - delta


def tet_fields(problem: ElasticProblem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per tet: J and the Cauchy stress ``(M, 3, 3)`` (MPa) of the volume-averaged F."""
    el = problem.element
    xt = np.swapaxes(x[problem.nodes], 1, 2)
    F = sum(w * (xt @ (el.gradients[q][None] @ problem.rest_inv)) for q, w in enumerate(el.weights))
    return neohookean.det_and_inverse(F)[0], neohookean.cauchy_stress(F, problem.mu, problem.lam)
