"""Electrostatics of the sensor: capacitances, Maxwell matrix and shape derivative.

Conductor tets (``mesh.capacitor_of_tet >= 0``) are equipotential, so all their dofs are
Dirichlet; each capacitor j has two conductors ("plates"), its bottom plate (layer 1)
and its top plate (layer 3). Plates are numbered bottoms first: plate ``j`` is bottom
plate j, plate ``k + j`` is top plate j. The rest of the sheet is dielectric with a
natural (zero-flux) condition on the sheet surface. With ``φ_a`` the potential that is
1 V on plate a and 0 V on every other plate, the Maxwell capacitance matrix is
``C_ab = ∫ ε ∇φ_a · ∇φ_b`` (pF, lengths in mm and ε in pF/mm), and the capacitance of
capacitor j is ``C_j = C_(k+j)(k+j)`` (top plate j at 1 V, all else grounded).

Because ``C_ab`` is stationary in the free dofs (discrete Galerkin orthogonality), its
derivative with respect to the vertex positions is that of ``φ_aᵀ K(x) φ_b`` at fixed
``φ`` (:func:`mscap.fem.elements.energy_vjp`): no adjoint solve.

Everything that depends only on the mesh (dof table, Dirichlet split, sparsity pattern
and the COO → CSR map) is computed once in :func:`build_problem`; :func:`solve` then
assembles values for any vertex positions, factorises once and solves all right-hand
sides with that one factorisation.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from mscap.fem import elements as fem
from mscap.fem import wedge
from mscap.errors import ElectrostaticError, InvertedMeshError
from mscap.mesh.layered import (BOTTOM_PLATE_LAYER, CONDUCTIVE_LAYERS, TOP_PLATE_LAYER, LayeredMesh, prisms_of,
                                 tet_values, tet_volumes)
from mscap.fem.petsc import LinearSolver, petsc

__all__ = ["ElectrostaticError", "InvertedMeshError", "ElectrostaticProblem", "Capacitances", "build_problem",
           "check_plates", "permittivity_of_tets", "assemble", "free_system", "solve", "capacitance_vjp", "capacitance_jacobian",
           "maxwell_vjp"]

log = logging.getLogger(__name__)

#: A relative residual above this after a solve means the solve failed (an iterative
#: solver at its default rtol 1e-5 stays well below it).
RESIDUAL_LIMIT = 1e-3
#: Above this, warn: capacitances err by ~residual², shape derivatives by ~residual.
RESIDUAL_WARNING = 1e-8
#: The element shapes of ``[mesh] element``: the three tets of each prism, or the prism
#: itself (P1 only, :mod:`mscap.fem.wedge`).
SHAPES = ("tet", "prism")


@dataclass(frozen=True)
class ElectrostaticProblem:
    """Everything about the electrostatic system that depends on the mesh only.

    Attributes
    ----------
    mesh
        The layered mesh.
    order
        Element order (1 or 2).
    cells, dofs, permittivity
        Vertices ``(M, 4)`` (tets) or ``(M, 6)`` (prisms), dofs ``(M, nb)`` and ε (pF/mm)
        ``(M,)`` of the dielectric cells, the only ones assembled (a conductor carries no
        field).
    n_dofs
        Number of dofs of the whole mesh (P2: vertices first, then edges).
    plate_of_dof
        ``(n_dofs,)`` plate (0..2k-1, bottoms first) of each Dirichlet dof, -1 if free.
    free
        ``(n_free,)`` free dofs, ascending.
    indptr, indices
        Pattern of the full (symmetric) matrix.
    upper_to_csr, above, below
        ``(nb (nb + 1) / 2, M)``: the CSR data position of each element's upper-triangle
        entry (``np.triu_indices(nb)`` order) at ``(dof_a, dof_b)``; the positions of the
        entries above the diagonal and of their transposes. Assembly sums the elements'
        upper entries and then each off-diagonal pair (:func:`assemble`).
    ff_entries, ff_indptr, ff_indices
        CSR data positions and pattern of the free-free block.
    fd_entries, fd_target
        CSR data positions of the free-row, Dirichlet-column entries and their flat
        index ``free_row · 2k + plate`` in the coupling matrix ``K_fd P``.
    shape
        ``"tet"`` or ``"prism"`` (:data:`SHAPES`).
    """

    mesh: LayeredMesh
    order: int
    cells: np.ndarray
    dofs: np.ndarray
    permittivity: np.ndarray
    n_dofs: int
    plate_of_dof: np.ndarray
    free: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    upper_to_csr: np.ndarray
    above: np.ndarray
    below: np.ndarray
    ff_entries: np.ndarray
    ff_indptr: np.ndarray
    ff_indices: np.ndarray
    fd_entries: np.ndarray
    fd_target: np.ndarray
    shape: str = "tet"

    def __post_init__(self):
        for name, value in vars(self).items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @property
    def k(self) -> int:
        """Number of capacitors."""
        return self.mesh.n_capacitors

    @property
    def element(self) -> fem.Element:
        return fem.element(self.order)

    def plate_name(self, plate: int) -> str:
        """E.g. ``"top plate of capacitor 2"``."""
        return _name(plate, self.k)


@dataclass(frozen=True)
class Capacitances:
    """The electrostatic solution at one configuration.

    Attributes
    ----------
    capacitance_pF
        ``(k,)`` capacitance of each capacitor: top plate at 1 V, every other plate 0 V.
    potentials
        ``(n_dofs, m)`` potentials (V) with plate ``plates[i]`` at 1 V, all other plates
        at 0 V (``None`` when dropped: :func:`mscap.fem.simulate.solve_poses`).
    plates
        ``(m,)`` the plate held at 1 V in each column: the top plates ``k..2k-1``, or
        all plates ``0..2k-1`` when the Maxwell matrix was asked for.
    maxwell_pF
        ``(2k, 2k)`` Maxwell capacitance matrix, plates bottoms first, or ``None``.
    assembly_s, factorisation_s, solve_s
        Wall-clock times of the three stages.
    """

    capacitance_pF: np.ndarray
    potentials: np.ndarray | None
    plates: np.ndarray
    maxwell_pF: np.ndarray | None
    assembly_s: float
    factorisation_s: float
    solve_s: float

    @property
    def top_potentials(self) -> np.ndarray:
        """``(n_dofs, k)``: column j is φ_j (top plate j at 1 V)."""
        k = len(self.capacitance_pF)
        return self.potentials[:, np.searchsorted(self.plates, np.arange(k, 2 * k))]

    def vertex_potentials(self, n_vertices: int) -> np.ndarray:
        """``(N, m)`` potentials at the vertices (P2: the vertex dofs)."""
        return self.potentials[:n_vertices]


def permittivity_of_tets(mesh: LayeredMesh, layers: Sequence) -> np.ndarray:
    """ε (pF/mm) of every tet: the layer's material, or its ``fill`` off the plates.

    ``layers`` are :class:`mscap.scene.settings.Layer` objects, bottom to top."""
    return tet_values(mesh, layers, lambda material: material.permittivity_pF_per_mm)


def _plates(mesh: LayeredMesh, every_plate: bool = True) -> np.ndarray:
    """Plate of each tet (bottoms first), -1 for dielectric; checks every plate exists
    (unless not ``every_plate``: a wired sensor's m row and n column nets are the bottom
    and top plates 0..max(m, n) - 1, some of which need not exist,
    :mod:`mscap.fabrication.wired`)."""
    k, cap, layer = mesh.n_capacitors, mesh.capacitor_of_tet, mesh.layer_of_tet
    if k < 1:
        raise ElectrostaticError("the mesh has no capacitors (no triangle is tagged with one)")
    stray = (cap >= 0) & ~np.isin(layer, CONDUCTIVE_LAYERS)
    if stray.any():
        t = int(np.flatnonzero(stray)[0])
        raise ElectrostaticError(f"tet {t} is tagged capacitor {cap[t]} but lies in layer {layer[t]}, "
                                 f"not a conductive layer {CONDUCTIVE_LAYERS}")
    plate = np.where(cap >= 0, cap + k * (layer == TOP_PLATE_LAYER), -1)
    count = np.bincount(plate[plate >= 0], minlength=2 * k)
    for p in np.flatnonzero(count == 0) if every_plate else ():
        where = "bottom plate layer" if p < k else "top plate layer"
        lay = BOTTOM_PLATE_LAYER if p < k else TOP_PLATE_LAYER
        raise ElectrostaticError(f"capacitor {p % k} has no conductor tets in the {where} (layer {lay})")
    return plate


def build_problem(mesh: LayeredMesh, layers: Sequence, order: int = 1, shape: str = "tet",
                  every_plate: bool = True) -> ElectrostaticProblem:
    """Dofs, Dirichlet split and sparsity pattern of ``mesh`` (once per mesh), on its tets
    or (``shape="prism"``, P1) on the prisms they were cut from.

    Raises
    ------
    ElectrostaticError
        If a capacitor has no plate in a conductive layer, or two plates share a dof.
    """
    if order not in (1, 2):
        raise ElectrostaticError(f"element order must be 1 or 2, got {order!r}")
    if shape not in SHAPES:
        raise ElectrostaticError(f"element shape must be one of {SHAPES}, got {shape!r}")
    if shape == "prism" and order != 1:
        raise ElectrostaticError(f"prisms are P1 only; got order {order}")
    start = time.perf_counter()
    k = mesh.n_capacitors
    plate_of_tet = _plates(mesh, every_plate)
    all_dofs, n_dofs = fem.dof_table(mesh.tets, len(mesh.points), order)
    conductor = plate_of_tet >= 0
    plate_of_dof = _plate_of_dof(all_dofs[conductor], plate_of_tet[conductor], n_dofs, k)

    # int32 indices where they fit (all but astronomically large meshes): 60 MB less on
    # a 1.46 M tet finer-mesh check.
    dof_type = fem.index_type(n_dofs * 2 * k)  # fd_target below reaches n_free · 2k
    eps = permittivity_of_tets(mesh, layers)
    if shape == "tet":
        cells = mesh.tets[~conductor].astype(dof_type)
        eps = eps[~conductor]
    else:  # a prism's three tets share its triangle and slab, so its plate and its ε
        cells = prisms_of(mesh)[~conductor[::3]].astype(dof_type)
        eps = eps[::3][~conductor[::3]]
    dofs = cells if order == 1 else all_dofs[~conductor].astype(dof_type)  # P1: the dofs are the vertices
    indptr, indices, upper_to_csr, above, below = _csr_pattern(dofs, n_dofs)
    entry_type, indices = indptr.dtype, indices.astype(dof_type, copy=False)
    csr_row = np.repeat(np.arange(n_dofs, dtype=dof_type), np.diff(indptr))

    is_free = plate_of_dof < 0
    free = np.flatnonzero(is_free).astype(dof_type)
    free_index = (np.cumsum(is_free) - 1).astype(dof_type)
    row_free, col_free = is_free[csr_row], is_free[indices]
    ff_entries = np.flatnonzero(row_free & col_free).astype(entry_type)
    ff_indptr = np.searchsorted(free_index[csr_row[ff_entries]], np.arange(len(free) + 1)).astype(entry_type)
    fd_entries = np.flatnonzero(row_free & ~col_free).astype(entry_type)
    fd_target = (free_index[csr_row[fd_entries]] * 2 * k + plate_of_dof[indices[fd_entries]]).astype(dof_type)
    del csr_row, row_free, col_free

    problem = ElectrostaticProblem(
        mesh=mesh, order=order, cells=cells, dofs=dofs, permittivity=eps, n_dofs=n_dofs,
        plate_of_dof=plate_of_dof, free=free, indptr=indptr, indices=indices,
        upper_to_csr=upper_to_csr, above=above, below=below, ff_entries=ff_entries, ff_indptr=ff_indptr,
        ff_indices=free_index[indices[ff_entries]], fd_entries=fd_entries, fd_target=fd_target, shape=shape)
    log.info("electrostatic P%d problem: %d dofs (%d free), %d nonzeros, %d dielectric %ss (%.2f s)",
             order, n_dofs, len(free), len(indices), len(cells), shape, time.perf_counter() - start)
    return problem


def check_plates(mesh: LayeredMesh, every_plate: bool = True) -> None:
    """Raise what :func:`build_problem` would for ``mesh``'s plates (a missing plate, two
    plates touching), at a fraction of its cost: before a simulation's elastic solves."""
    plate_of_tet = _plates(mesh, every_plate)
    conductor = plate_of_tet >= 0
    _plate_of_dof(mesh.tets[conductor], plate_of_tet[conductor], len(mesh.points), mesh.n_capacitors)


def _plate_of_dof(dofs: np.ndarray, plates: np.ndarray, n_dofs: int, k: int) -> np.ndarray:
    """Plate of each dof (-1: free) from the conductor tets' ``dofs`` and ``plates``.
    Two plates touch at a P2 edge dof only where they share the edge's vertices, so the
    P1 check (:func:`check_plates`) finds every touching pair."""
    # Unique (dof, plate) pairs: a dof listed twice in a row belongs to two plates.
    pairs = np.unique(dofs.astype(np.int64) * (2 * k) + plates[:, None])
    dof_of_pair, plate_of_pair = np.divmod(pairs, 2 * k)
    shared = np.flatnonzero(np.diff(dof_of_pair) == 0)
    if len(shared):
        d = shared[0]
        raise ElectrostaticError(f"the {_name(plate_of_pair[d], k)} and the {_name(plate_of_pair[d + 1], k)} "
                                 f"touch ({len(shared)} shared nodes, e.g. node {dof_of_pair[d]}); "
                                 "conductors must be apart")
    plate_of_dof = np.full(n_dofs, -1)
    plate_of_dof[dof_of_pair] = plate_of_pair
    return plate_of_dof


def _element_entries(dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column dof of every element-matrix entry of ``dofs`` ``(m, nb)``, in the
    order of ``local.ravel()`` for element matrices ``local`` ``(m, nb, nb)``."""
    nb = dofs.shape[1]
    return np.repeat(dofs, nb, axis=1).ravel(), np.tile(dofs, (1, nb)).ravel()


def _csr_pattern(dofs: np.ndarray, n_dofs: int) -> tuple[np.ndarray, ...]:
    """The CSR pattern (``indptr``, ``indices``) of a symmetric matrix assembled from
    element matrices on ``dofs`` ``(M, nb)``; the CSR data position of each element's
    upper-triangle entry ``(nb (nb + 1) / 2, M)``; the positions above the diagonal and
    those of their transposes.

    Built ``BLOCK`` elements at a time, so the temporaries stay a few tens of MB; one
    ``np.unique`` over all ``M nb²`` entries needed about 800 bytes per tet (1.1 GB on the
    glove's finer-mesh check, the largest allocation of a multi-start worker)."""
    pattern = sp.csr_matrix((n_dofs, n_dofs), dtype=np.float32)
    for start in range(0, len(dofs), fem.BLOCK):
        rows, cols = _element_entries(dofs[start:start + fem.BLOCK])
        pattern = pattern + sp.csr_matrix((np.ones(len(rows), dtype=np.float32), (rows, cols)),
                                          shape=(n_dofs, n_dofs))
    pattern.sum_duplicates()  # also sorts the column indices of each row
    # int32 where it fits (:func:`elements.index_type`): the upper entries' positions are
    # the largest array of the problem (P1: 40 of its bytes per tet); assemble() widens
    # one block at a time.
    entry_type = fem.index_type(pattern.nnz + 1)
    indptr = pattern.indptr.astype(entry_type)
    indices = pattern.indices.astype(fem.index_type(n_dofs))
    csr_row = np.repeat(np.arange(n_dofs, dtype=np.int64), np.diff(indptr))
    keys = csr_row * n_dofs + indices
    upper_a, upper_b = np.triu_indices(dofs.shape[1])
    upper_to_csr = np.empty((len(upper_a), len(dofs)), dtype=entry_type)
    for start in range(0, len(dofs), fem.BLOCK):
        block = dofs[start:start + fem.BLOCK].astype(np.int64)
        upper_to_csr[:, start:start + len(block)] = np.searchsorted(keys, (block[:, upper_a] * n_dofs + block[:, upper_b]).T)
    above = np.flatnonzero(csr_row < indices)
    below = np.searchsorted(keys, indices[above].astype(np.int64) * n_dofs + csr_row[above]).astype(entry_type)
    return indptr, indices, upper_to_csr, above.astype(entry_type), below


def _name(plate: int, k: int) -> str:
    return f"{'bottom' if plate < k else 'top'} plate of capacitor {plate % k}"


def _positions(problem: ElectrostaticProblem, x) -> np.ndarray:
    n = len(problem.mesh.points)
    x = problem.mesh.points if x is None else np.asarray(x, dtype=float)
    if x.shape != (n, 3):
        raise ElectrostaticError(f"vertex positions must have shape ({n}, 3), got {x.shape}")
    if not np.isfinite(x).all():
        raise ElectrostaticError(f"{int((~np.isfinite(x)).any(axis=1).sum())} vertex positions are not finite")
    return x


def assemble(problem: ElectrostaticProblem, x: np.ndarray | None = None) -> np.ndarray:
    """CSR data (pattern ``problem.indptr/indices``) of the stiffness matrix at ``x``.

    The matrix is symmetric: the elements' upper-triangle entries are summed into their
    CSR positions (an element's ``(a, b)`` lands above or below the diagonal as its dofs
    fall), then each off-diagonal pair is summed and written to both, so the two halves
    are equal bit for bit.

    Raises
    ------
    ElectrostaticError
        If a dielectric tet is inverted or degenerate at ``x``.
    """
    x = _positions(problem, x)
    rows = np.ascontiguousarray(x.T)
    data = np.zeros(len(problem.indices))
    # BLOCK tets at a time: the element matrices of all tets at once were the largest
    # temporary of an evaluation (M nb² doubles, 145 MB on the glove's finer mesh).
    for start in range(0, len(problem.cells), fem.BLOCK):
        block = slice(start, start + fem.BLOCK)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # degenerate cells: reported below
            if problem.shape == "prism":
                upper = wedge.upper_stiffness(rows, problem.cells[block], problem.permittivity[block])
            else:
                upper = fem.upper_stiffness(problem.element, rows, problem.cells[block], problem.permittivity[block])
        # A vertex's diagonal entry ε vol ∫|∇N_0|² has the sign of the volume (ε > 0): a
        # non-positive or non-finite one marks an inverted or degenerate tet, without a
        # second pass over all tets for their volumes (a third of the assembly's time); a
        # prism's is NaN when its Jacobian is not positive at every point (wedge.py).
        corner = upper[0]
        bad = np.flatnonzero(~(np.isfinite(corner) & (corner > 0)))
        if len(bad):
            _raise_inverted(problem, x, start + bad)
        entries = problem.upper_to_csr[:, block]
        lo, hi = int(entries.min()), int(entries.max()) + 1  # a block's rows are a window of the CSR data
        data[lo:hi] += np.bincount((entries.astype(np.intp) - lo).ravel(), weights=upper.ravel(), minlength=hi - lo)
    for start in range(0, len(problem.above), fem.BLOCK * 4):  # in place, a few MB at a time
        above, below = problem.above[start:start + fem.BLOCK * 4], problem.below[start:start + fem.BLOCK * 4]
        data[above] += data[below]
        data[below] = data[above]
    return data


def _raise_inverted(problem: ElectrostaticProblem, x: np.ndarray, bad: np.ndarray) -> None:
    """Raise for the inverted or degenerate dielectric cells ``bad`` (all of them counted)."""
    measure = wedge.min_jacobian if problem.shape == "prism" else tet_volumes
    what = "smallest Jacobian" if problem.shape == "prism" else "volume"
    count = len(bad)
    for start in range(int(bad[-1]) + 1, len(problem.cells), fem.BLOCK):
        vol = measure(x, problem.cells[start:start + fem.BLOCK])
        count += int((~(np.isfinite(vol) & (vol > 0))).sum())
    vol = measure(x, problem.cells[bad[:1]])[0]
    raise InvertedMeshError(f"{count} dielectric {problem.shape}s are inverted or degenerate at the given "
                            f"positions (e.g. {problem.shape} {int(bad[0])}, {what} {vol:.3g} mm³)")


def solve(problem: ElectrostaticProblem, x: np.ndarray | None = None, maxwell: bool = False,
          solver: LinearSolver | None = None) -> Capacitances:
    """Capacitances at vertex positions ``x`` (default: rest), one factorisation.

    Parameters
    ----------
    problem
        From :func:`build_problem`.
    x
        ``(N, 3)`` vertex positions (mm).
    maxwell
        Also solve with each bottom plate at 1 V and return the Maxwell matrix.
    solver
        A :class:`~mscap.fem.petsc.LinearSolver` to reuse; default a new ``"electro_"`` one.

    Raises
    ------
    ElectrostaticError
        On inverted tets, a failed factorisation, or a non-finite or inaccurate solution.
    """
    x = _positions(problem, x)
    k, n_free = problem.k, len(problem.free)
    plates = np.arange(2 * k) if maxwell else np.arange(k, 2 * k)
    start = time.perf_counter()
    data = assemble(problem, x)
    kff, rhs = free_system(problem, data, plates)
    assembled = time.perf_counter()
    u = np.zeros((n_free, len(plates)))
    factorised = assembled
    if n_free:
        solver = solver or LinearSolver("electro_")
        try:
            solver.set_csr(kff, spd=True)
            factorised = time.perf_counter()
            u = solver.solve(rhs)
        except petsc().Error as exc:
            raise ElectrostaticError(f"the electrostatic solve ({solver.description}, {n_free} unknowns) "
                                     f"failed: {exc}") from exc
        _check_solution(problem, kff, u, rhs, plates, solver.description)
    solved = time.perf_counter()

    potentials = np.zeros((problem.n_dofs, len(plates)))
    potentials[problem.free] = u
    fixed = problem.plate_of_dof >= 0
    potentials[fixed] = problem.plate_of_dof[fixed, None] == plates[None, :]
    full = sp.csr_matrix((data, problem.indices, problem.indptr), shape=(problem.n_dofs,) * 2)
    energies = potentials.T @ (full @ potentials)  # C_ab = φ_aᵀ K φ_b (pF)
    capacitance = np.diag(energies)[np.searchsorted(plates, np.arange(k, 2 * k))].copy()
    result = Capacitances(capacitance_pF=capacitance, potentials=potentials, plates=plates,
                          maxwell_pF=energies if maxwell else None, assembly_s=assembled - start,
                          factorisation_s=factorised - assembled, solve_s=solved - factorised)
    for array in (capacitance, potentials, plates, energies):
        array.setflags(write=False)
    log.info("capacitances (pF): %s; assembly %.2f s, factorisation %.2f s, %d solves %.2f s",
             np.array2string(capacitance, precision=4), result.assembly_s, result.factorisation_s,
             len(plates), result.solve_s)
    return result


def free_system(problem: ElectrostaticProblem, data: np.ndarray, plates: np.ndarray
                ) -> tuple[sp.csr_matrix, np.ndarray]:
    """The free-dof matrix and the right-hand sides of ``plates`` at 1 V (the others
    grounded) from the assembled values ``data`` (:func:`assemble`)."""
    k, n_free = problem.k, len(problem.free)
    coupling = np.bincount(problem.fd_target, weights=data[problem.fd_entries], minlength=n_free * 2 * k)
    rhs = -coupling.reshape(n_free, 2 * k)[:, plates]
    kff = sp.csr_matrix((data[problem.ff_entries], problem.ff_indices, problem.ff_indptr), shape=(n_free, n_free))
    return kff, rhs


def _check_solution(problem, kff, u, rhs, plates, description) -> None:
    """Raise if a column is not finite or its relative residual is too large."""
    finite = np.isfinite(u).all(axis=0)
    residual = np.full(u.shape[1], np.inf)
    residual[finite] = (np.linalg.norm(kff @ u[:, finite] - rhs[:, finite], axis=0)
                        / np.maximum(np.linalg.norm(rhs[:, finite], axis=0), np.finfo(float).tiny))
    worst = int(np.argmax(residual))
    if not finite.all() or residual[worst] > RESIDUAL_LIMIT:
        raise ElectrostaticError(
            f"the potential with the {problem.plate_name(plates[worst])} at 1 V is "
            f"{'not finite' if not finite[worst] else 'inaccurate'} (relative residual "
            f"{residual[worst]:.3g}, solver {description})")
    log.log(logging.WARNING if residual[worst] > RESIDUAL_WARNING else logging.DEBUG,
            "electrostatic relative residual up to %.3g (solver %s)", residual[worst], description)


def capacitance_vjp(problem: ElectrostaticProblem, caps: Capacitances, weights,
                    x: np.ndarray | None = None) -> np.ndarray:
    """``Σ_j w_j dC_j/dx`` (pF/mm), ``(N, 3)``, at the configuration ``caps`` was solved at.

    Parameters
    ----------
    problem
        The problem ``caps`` was solved for.
    caps
        The solution at ``x``.
    weights
        ``(k,)`` weights ``w_j``.
    x
        ``(N, 3)`` vertex positions ``caps`` was computed at (default: rest).
    """
    x = _positions(problem, x)
    weights = np.asarray(weights, dtype=float).reshape(-1)
    if weights.shape != (problem.k,):
        raise ElectrostaticError(f"expected {problem.k} weights, got {weights.shape[0]}")
    used = np.flatnonzero(weights)
    return _energy_vjp(problem, x, caps.top_potentials[:, used], np.diag(weights[used]))


def _energy_vjp(problem: ElectrostaticProblem, x: np.ndarray, fields: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``Σ_ab W_ab d(φ_aᵀ K(x) φ_b)/dx`` at fixed ``fields``, on the problem's cells."""
    if problem.shape == "prism":
        return wedge.energy_vjp(x, problem.cells, problem.permittivity, fields, weights)
    return fem.energy_vjp(problem.element, x, problem.cells, problem.dofs, problem.permittivity, fields, weights)


def capacitance_jacobian(problem: ElectrostaticProblem, caps: Capacitances,
                         x: np.ndarray | None = None) -> np.ndarray:
    """``dC_j/dx`` for every capacitor, ``(k, N, 3)`` (pF/mm)."""
    return np.stack([capacitance_vjp(problem, caps, np.eye(problem.k)[j], x) for j in range(problem.k)])


def maxwell_vjp(problem: ElectrostaticProblem, caps: Capacitances, weights,
                x: np.ndarray | None = None) -> np.ndarray:
    """``Σ_ab W_ab dC_ab/dx`` for the Maxwell matrix (``caps`` solved with ``maxwell=True``)."""
    if caps.maxwell_pF is None:
        raise ElectrostaticError("the Maxwell derivative needs a solution computed with maxwell=True")
    x = _positions(problem, x)
    weights = np.asarray(weights, dtype=float)
    if weights.shape != (2 * problem.k,) * 2:
        raise ElectrostaticError(f"expected ({2 * problem.k}, {2 * problem.k}) weights, got {weights.shape}")
    return _energy_vjp(problem, x, caps.potentials, weights)
