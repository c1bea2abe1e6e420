"""All PETSc plumbing lives here: finding petsc4py, initialising it with options.

Debian installs petsc4py under ``$PETSC_DIR/lib/python3/dist-packages`` and adds that to
``sys.path`` through a ``.pth`` file only if ``PETSC_DIR`` is set when Python starts.
:func:`petsc` makes this automatic: it finds the installed PETSc when ``PETSC_DIR`` is
unset, so ``mscap``, ``pytest`` and ``mpirun`` work without any environment set-up.
:func:`unused_options` names the command line's options that nothing read (a misspelt
``-ksp_tpye``), for the CLI to warn about.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from mscap.errors import LinearSolveError
from mscap.profile import section

__all__ = ["petsc", "find_petsc_dir", "DEFAULTS", "set_scene_options", "unused_options", "LinearSolver",
           "LinearSolveError", "Operator"]

_DEBIAN_PETSC = "/usr/lib/petscdir/petsc*/*-real"


def find_petsc_dir() -> str | None:
    """``PETSC_DIR`` if set, else the newest real-scalar Debian PETSc, else ``None``."""
    if os.environ.get("PETSC_DIR"):
        return os.environ["PETSC_DIR"]
    candidates = sorted(glob.glob(_DEBIAN_PETSC))
    return candidates[-1] if candidates else None


def petsc(argv: list[str] | None = None):
    """Initialise petsc4py once (with command-line ``argv``) and return ``PETSc``.

    ``argv`` entries such as ``-electro_ksp_type cg`` go into the options database. The
    first call initialises PETSc with them; a later call (a second command run in the
    same process, as tests do) inserts its ``argv`` into the database.
    """
    global _command_line
    if "petsc4py.PETSc" in sys.modules:
        PETSc = sys.modules["petsc4py.PETSc"]
        if argv:
            PETSc.Options().insertString(" ".join(argv))
            _command_line = _command_line | set(PETSc.Options().getAll())
        return PETSc
    petsc_dir = find_petsc_dir()
    if petsc_dir:
        os.environ.setdefault("PETSC_DIR", petsc_dir)
        site = os.path.join(petsc_dir, "lib", "python3", "dist-packages")
        if os.path.isdir(site) and site not in sys.path:
            sys.path.append(site)
    import petsc4py

    program = sys.executable if sys.argv[0].startswith("-") else sys.argv[0]  # python -c: "-c" is no option
    petsc4py.init([program, *(argv or [])])
    from petsc4py import PETSc

    _command_line = set(PETSc.Options().getAll())
    return PETSc


#: Default solver per options prefix. The command line (and a scene's [petsc] table)
#: override these through KSP.setFromOptions, e.g. ``-electro_ksp_type cg``.
DEFAULTS: dict[str, dict[str, str]] = {
    # MUMPS for electrostatics: with the symbolic analysis kept it refactorises in 0.1-0.2x its first
    # factorisation (CHOLMOD: 0.7x), 2.3x cheaper than CHOLMOD per pose, and cheaper than CG on the
    # previous design's factor too (docs/performance.md §2). -electro_pc_factor_mat_solver_type
    # cholmod gives the earlier default (faster for a single configuration: no METIS analysis).
    "electro_": {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"},
    "elastic_": {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"},
    "adjoint_": {"ksp_type": "preonly", "pc_type": "cholesky", "pc_factor_mat_solver_type": "mumps"},
}

_command_line: set[str] | None = None


def set_scene_options(options) -> None:
    """Put a scene's ``[petsc]`` entries (name, value) into the options database;
    anything given on the command line wins."""
    PETSc = petsc()
    database = PETSc.Options()
    for name, value in options:
        if name not in _command_line:
            database.setValue(name, value)


#: Options PETSc reads only in PetscFinalize, after any check of ours.
_READ_AT_EXIT = ("options_left", "options_view")


def unused_options() -> list[str]:
    """The options of the command line, ``PETSC_OPTIONS`` and ``.petscrc`` (not a
    scene's ``[petsc]`` table) that nothing has read so far, as ``-name``.

    Empty when the command line gave ``-options_left`` (PETSc itself then lists the
    unused options at exit, or, given ``-options_left 0``, does not) and under MPI with
    more than one rank (the master reads no solver options). petsc4py does not expose
    ``PetscOptionsUsed``; it is called through ctypes from the library the ``PETSc``
    module links.
    """
    PETSc = petsc()
    if PETSc.Options().hasName("options_left") or PETSc.COMM_WORLD.getSize() > 1:
        return []
    used = ctypes.CDLL(PETSc.__file__).PetscOptionsUsed
    used.argtypes = (ctypes.c_void_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_int))
    flag = ctypes.c_int()
    unused = []
    for name in sorted(_command_line.difference(_READ_AT_EXIT)):
        used(None, name.encode(), ctypes.byref(flag))
        if not flag.value:
            unused.append(f"-{name}")
    return unused


class _Wrapped(NamedTuple):
    """A PETSc AIJ matrix over CSR arrays it does not copy (keep them alive with it)."""

    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray
    mat: object


class LinearSolver:
    """A KSP with an options prefix and named defaults, and the PETSc matrix it factorises.

    Parameters
    ----------
    prefix
        Options prefix such as ``"electro_"``; defaults come from :data:`DEFAULTS`.
    """

    def __init__(self, prefix: str, out_of_core: bool = False):
        PETSc = petsc()
        self.prefix = prefix
        self.out_of_core = out_of_core
        self.ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        self.ksp.setOptionsPrefix(prefix)
        defaults = DEFAULTS.get(prefix, {})
        self.ksp.setType(defaults.get("ksp_type", "preonly"))
        pc = self.ksp.getPC()
        pc.setType(defaults.get("pc_type", "cholesky"))
        if "pc_factor_mat_solver_type" in defaults:
            pc.setFactorSolverType(defaults["pc_factor_mat_solver_type"])
        if out_of_core:  # only MUMPS factorises out of core (a scene's CHOLMOD cannot)
            pc.setFactorSolverType("mumps")
        self.ksp.setFromOptions()  # the command line still decides
        self._own: _Wrapped | None = None  # the matrix set_csr made, and its arrays

    def set_csr(self, matrix, spd: bool = False) -> None:
        """Factorise the scipy CSR ``matrix`` (symmetric; ``spd`` tells PETSc it is positive
        definite, as electrostatics are; elastic Hessians of compressed thin sheets can be
        indefinite). While its pattern stays that of the previous call, the same PETSc
        matrix takes the new values and PETSc refactorises numerically only, keeping the ordering and symbolic analysis (electrostatics on
        359k tets: 0.18 → 0.13 s with CHOLMOD, 0.60 → 0.095 s with MUMPS)."""
        csr = matrix.tocsr()
        own = self._own
        new = own is None or own.data.shape != csr.data.shape or not (
            np.array_equal(own.indptr, csr.indptr) and np.array_equal(own.indices, csr.indices))
        if new:
            PETSc = petsc()
            if own is not None:
                own.mat.destroy()
            # The pattern is shared, not copied (nothing writes to it; 28 MB on biaxial's check);
            # the values are copied, since the next call overwrites them in place.
            arrays = (csr.indptr.astype(PETSc.IntType, copy=False), csr.indices.astype(PETSc.IntType, copy=False),
                      csr.data.astype(float))
            mat = PETSc.Mat().createAIJWithArrays(csr.shape, arrays, comm=PETSc.COMM_SELF)  # wraps, no copy
            mat.setOption(PETSc.Mat.Option.SYMMETRIC, True)
            if spd:
                mat.setOption(PETSc.Mat.Option.SPD, True)
            own = self._own = _Wrapped(*arrays, mat)
        else:
            own.data[:] = csr.data
            own.mat.assemble()  # bumps the matrix state: a numeric refactorisation follows
        with section("factorisation"):
            self.ksp.setOperators(own.mat)
            if self.out_of_core and new:  # a new matrix gets a new factor matrix
                self._mumps_out_of_core()
            self.ksp.setUp()

    def _mumps_out_of_core(self) -> None:
        """Let MUMPS keep its factors on disk (``ICNTL(22) = 1``, in ``$MUMPS_OOC_TMPDIR``,
        default ``/tmp``) unless the command line says otherwise (``out_of_core`` also made
        MUMPS the default factor package; a command-line one is left alone)."""
        PETSc = petsc()
        pc = self.ksp.getPC()
        if pc.getType() not in ("cholesky", "lu"):
            return
        if PETSc.Options().hasName(f"{self.prefix}mat_mumps_icntl_22"):
            return
        pc.setFactorSetUpSolverType()
        if pc.getFactorSolverType() == "mumps":
            pc.getFactorMatrix().setMumpsIcntl(22, 1)

    def solve(self, rhs):
        """Solve for one right-hand side ``(n,)`` or several ``(n, m)`` columns. Several
        columns through a direct factorisation go to the factor in one MatMatSolve (MUMPS:
        the 4 potentials of a poking pose in 11 ms instead of 32); an iterative KSP from the
        command line solves them one by one."""
        rhs = np.asarray(rhs, dtype=float)
        columns = rhs.reshape(len(rhs), -1)
        if columns.shape[1] > 1 and self._direct():
            return self._solve_columns(columns).reshape(rhs.shape)
        out = np.empty_like(columns)
        b, x = self._own.mat.createVecLeft(), self._own.mat.createVecRight()
        for j in range(columns.shape[1]):
            b.setArray(columns[:, j])
            with section("solve"):
                self.ksp.solve(b, x)
            reason = self.ksp.getConvergedReason()
            if reason < 0:
                raise LinearSolveError(f"{self.prefix}ksp diverged (reason {reason}) on right-hand side {j}")
            out[:, j] = x.getArray()
        return out.reshape(rhs.shape)

    def _direct(self) -> bool:
        """Is the solve one application of a factorisation (``preonly`` with a factor PC)?"""
        return self.ksp.getType() == "preonly" and self.ksp.getPC().getType() in ("cholesky", "lu")

    def _solve_columns(self, columns: np.ndarray) -> np.ndarray:
        """All ``columns`` through the factor matrix at once (``MatMatSolve``)."""
        PETSc = petsc()
        n, m = columns.shape
        b = PETSc.Mat().createDense((n, m), array=np.asfortranarray(columns), comm=PETSc.COMM_SELF)
        x = PETSc.Mat().createDense((n, m), comm=PETSc.COMM_SELF)
        x.setUp()
        try:
            with section("solve"):
                self.ksp.getPC().getFactorMatrix().matSolve(b, x)
            return np.array(x.getDenseArray(), copy=True)
        finally:
            b.destroy()
            x.destroy()

    def destroy(self) -> None:
        """Free the KSP (and the factorisation it holds) now rather than at exit."""
        self.ksp.destroy()
        if self._own is not None:
            self._own.mat.destroy()
        self._own = None

    @property
    def description(self) -> str:
        pc = self.ksp.getPC()
        solver = pc.getFactorSolverType() if pc.getType() in ("cholesky", "lu") else ""
        return f"{self.ksp.getType()}/{pc.getType()}" + (f"/{solver}" if solver else "")


class Operator:
    """A matrix over a fixed CSR pattern (the elastic Hessian), and its solver: the pattern never
    changes, so every factorisation after the first is numeric only
    (:meth:`~mscap.fem.petsc.LinearSolver.set_csr` keeps the symbolic one)."""

    def __init__(self, problem, prefix: str = "elastic_", out_of_core: bool = False):
        """``problem``: anything with a CSR pattern ``indices``, ``indptr`` and ``n_dofs``
        (an :class:`~mscap.fem.elastic.problem.ElasticProblem`); ``out_of_core``: MUMPS
        factors on disk (:meth:`LinearSolver._mumps_out_of_core`)."""
        self._pattern = (problem.indices, problem.indptr)
        self._shape = (problem.n_dofs, problem.n_dofs)
        self.solver = LinearSolver(prefix, out_of_core)

    def factorise(self, data: np.ndarray) -> None:
        """Factorise the matrix with CSR values ``data``; a failed factorisation raises
        :class:`LinearSolveError` here or at the first :meth:`solve`."""
        try:
            self.solver.set_csr(sp.csr_matrix((data, *self._pattern), shape=self._shape))
        except petsc().Error as exc:
            raise LinearSolveError(f"{self.solver.description} factorisation failed: {exc}") from exc

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self.solver.solve(rhs)

    def destroy(self) -> None:
        """Free the PETSc matrix and the factorisation now: petsc4py objects do not free
        their native memory when garbage-collected (an optimisation that kept one
        adjoint factorisation per evaluation grew by ~34 MB per evaluation)."""
        self.solver.destroy()
