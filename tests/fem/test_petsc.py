"""PETSc plumbing: found without PETSC_DIR; defaults < scene options < command line."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import scipy.sparse as sp


def run_python(code: str, env_drop=("PETSC_DIR",)) -> str:
    env = {k: v for k, v in os.environ.items() if k not in env_drop}
    result = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_petsc_found_without_petsc_dir():
    out = run_python("""
        from mscap.fem.petsc import petsc
        print(petsc().Sys.getVersion()[0])
    """)
    assert out.strip() == "3"


def test_option_precedence():
    """A scene option overrides the default; the command line overrides the scene."""
    out = run_python("""
        from mscap.fem.petsc import petsc, set_scene_options, LinearSolver
        petsc(["-electro_pc_factor_mat_solver_type", "petsc"])
        set_scene_options([("electro_pc_factor_mat_solver_type", "mumps"),
                           ("electro_ksp_type", "cg"), ("electro_pc_type", "jacobi")])
        print(LinearSolver("electro_").description)
    """)
    assert out.strip() == "cg/jacobi"
    out = run_python("""
        from mscap.fem.petsc import petsc, set_scene_options, LinearSolver
        petsc(["-electro_pc_factor_mat_solver_type", "petsc"])
        set_scene_options([("electro_pc_factor_mat_solver_type", "mumps")])
        print(LinearSolver("electro_").description)
    """)
    assert out.strip() == "preonly/cholesky/petsc"


def test_linear_solver_many_rhs():
    """Several columns go through the factor at once (MatMatSolve): the same solutions as
    one KSP solve per column, to round-off, and exact for the matrix."""
    from mscap.fem.petsc import LinearSolver

    n = 200
    a = sp.diags([-np.ones(n - 1), 2.5 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
    solver = LinearSolver("electro_")
    assert solver.description == "preonly/cholesky/mumps"  # the electrostatic default
    solver.set_csr(a, spd=True)
    b = np.random.default_rng(0).normal(size=(n, 3))
    x = solver.solve(b)
    np.testing.assert_allclose(a @ x, b, atol=1e-12)
    for j in range(3):  # one column takes the KSP path
        np.testing.assert_allclose(solver.solve(b[:, j]), x[:, j], rtol=1e-14, atol=1e-14)
    assert solver.solve(np.asfortranarray(b)).shape == (n, 3) and solver.solve(b[:, :1]).shape == (n, 1)
    solver.destroy()


def test_an_iterative_solver_from_the_command_line_solves_column_by_column():
    out = run_python("""
        import numpy as np, scipy.sparse as sp
        from mscap.fem.petsc import petsc, LinearSolver
        petsc(["-electro_ksp_type", "cg", "-electro_pc_type", "jacobi", "-electro_ksp_rtol", "1e-12"])
        n = 100
        a = sp.diags([-np.ones(n - 1), 2.5 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
        solver = LinearSolver("electro_")
        solver.set_csr(a, spd=True)
        b = np.random.default_rng(1).normal(size=(n, 2))
        print(solver.description, float(np.abs(a @ solver.solve(b) - b).max() < 1e-9))
    """)
    assert out.strip() == "cg/jacobi 1.0"


def test_set_csr_refactorises_new_values_on_the_same_matrix():
    """Same pattern: the PETSc matrix is kept (symbolic factorisation reused) and the new
    values are factorised; a new pattern gets a new matrix."""
    from mscap.fem.petsc import LinearSolver

    n = 200
    rng = np.random.default_rng(1)
    b = rng.normal(size=(n, 2))
    solver = LinearSolver("electro_")
    matrices = []
    for diagonal in (2.5, 4.0, 3.0):
        a = sp.diags([-np.ones(n - 1), diagonal * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
        solver.set_csr(a, spd=True)
        matrices.append(solver._own.mat)
        np.testing.assert_allclose(a @ solver.solve(b), b, atol=1e-12)
    assert matrices[0] is matrices[1] is matrices[2]
    wider = sp.diags([-np.ones(n - 2), 3.0 * np.ones(n), -np.ones(n - 2)], [-2, 0, 2]).tocsr()
    solver.set_csr(wider, spd=True)
    assert solver._own.mat is not matrices[0]
    np.testing.assert_allclose(wider @ solver.solve(b), b, atol=1e-12)
    solver.destroy()


def test_out_of_core_factors_solve_like_in_core_ones(tmp_path, monkeypatch):
    """``out_of_core``: MUMPS writes its factors to $MUMPS_OOC_TMPDIR (ICNTL(22) = 1) and
    solves an indefinite symmetric system (an elastic Hessian can be one) as in core,
    over refactorisations on the same pattern."""
    from mscap.fem.petsc import LinearSolver

    monkeypatch.setenv("MUMPS_OOC_TMPDIR", str(tmp_path))
    n = 400
    rng = np.random.default_rng(2)
    b = rng.normal(size=(n, 2))
    solvers = {ooc: LinearSolver("elastic_", out_of_core=ooc) for ooc in (False, True)}
    for diagonal in (2.5, -0.3):  # the second is indefinite
        a = sp.diags([-np.ones(n - 1), diagonal * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
        x = {}
        for ooc, solver in solvers.items():
            solver.set_csr(a)
            x[ooc] = solver.solve(b)
            assert solver.ksp.getPC().getFactorMatrix().getMumpsIcntl(22) == int(ooc)
        np.testing.assert_allclose(a @ x[True], b, atol=1e-10)
        np.testing.assert_allclose(x[True], x[False], rtol=1e-12, atol=1e-12)
    for solver in solvers.values():
        solver.destroy()


def test_out_of_core_electrostatics_keep_mumps_with_factors_on_disk(tmp_path, monkeypatch):
    """``out_of_core`` keeps MUMPS (the electrostatic default) and sets its ICNTL(22): the factors go
    to ``$MUMPS_OOC_TMPDIR`` and the solution agrees with the in-core one to round-off."""
    from mscap.fem.petsc import LinearSolver

    monkeypatch.setenv("MUMPS_OOC_TMPDIR", str(tmp_path))
    n = 300
    a = sp.diags([-np.ones(n - 1), 2.5 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
    b = np.random.default_rng(3).normal(size=(n, 3))
    x = {}
    for ooc in (False, True):
        solver = LinearSolver("electro_", out_of_core=ooc)
        solver.set_csr(a, spd=True)
        x[ooc] = solver.solve(b)
        assert solver.description == "preonly/cholesky/mumps"
        assert solver.ksp.getPC().getFactorMatrix().getMumpsIcntl(22) == int(ooc)
        solver.destroy()
    np.testing.assert_allclose(x[True], x[False], rtol=1e-12, atol=1e-13)
