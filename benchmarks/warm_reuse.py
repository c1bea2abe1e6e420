"""Can an optimiser step reuse a factorisation? (issue 18, part 1)

A design step moves the rest geometry by about a tenth of a millimetre, so every pose's
electrostatic matrix changes a little (|ΔA|/|A| ≈ 1-5 % on poking). This script compares,
per pose, the ways to solve the k potentials of the new matrix:

- ``refactor cholmod`` / ``refactor mumps``: a numeric refactorisation with the symbolic
  analysis kept (what :class:`mscap.fem.petsc.LinearSolver` does) and one MatMatSolve;
- ``stale <solver>``: CG on all k columns in lockstep, preconditioned by the previous
  design's factorisation of the same pose (one MatMatSolve per iteration; this needs one
  kept factorisation per pose between steps);
- ``shared <solver>``: the same CG, preconditioned by the factorisation of the design's
  first pose (one factorisation per design, none kept between steps);
- ``hypre`` / ``icc``: CG with BoomerAMG or incomplete Cholesky, column by column.

CG stops at ``--rtol`` per column. The capacitance C = φᵀKφ is variational, so its error
is quadratic in the potential's: the table prints the worst relative C error against the
direct solve. One BLAS thread (CHOLMOD's supernodes halve their time on two threads,
which an optimiser worker does not have). Run::

    .venv/bin/python benchmarks/warm_reuse.py [jobs/poking.toml] [--rtol 1e-8] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one core per process, as a worker
    os.environ[_var] = "1"

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from mscap import build_design, load_scene  # noqa: E402
from mscap.fem import electrostatic  # noqa: E402
from mscap.fem.petsc import LinearSolver, petsc  # noqa: E402

PETSc = petsc()


def electrostatic_system(problem, vertices):
    """The free-dof matrix and the k right-hand sides (top plates at 1 V) at ``vertices``."""
    return electrostatic.free_system(problem, electrostatic.assemble(problem, vertices),
                                     np.arange(problem.k, 2 * problem.k))


def solver(way: str, matrix) -> LinearSolver:
    """mscap's own solver (options prefix ``warm_<way>_``) with ``matrix`` factorised (a
    direct ``way``: ``cholmod``, ``mumps``) or set up (``hypre``, ``icc``: CG at ``--rtol``)."""
    options = PETSc.Options()
    prefix = f"warm_{way}_"
    if way in ("cholmod", "mumps"):
        options.setValue(f"{prefix}pc_factor_mat_solver_type", way)
    else:
        options.setValue(f"{prefix}ksp_type", "cg")
        options.setValue(f"{prefix}pc_type", way)
    out = LinearSolver(prefix)
    out.set_csr(matrix, spd=True)
    return out


def lockstep_cg(matrix, rhs, factor: LinearSolver, rtol: float, max_iterations: int = 100):
    """CG on every column at once, preconditioned by ``factor``: (solution, iterations)."""
    x = np.zeros_like(rhs)
    residual = rhs.copy()
    z = factor.solve(residual)
    direction = z.copy()
    rz = np.einsum("ij,ij->j", residual, z)
    limit = rtol * np.linalg.norm(rhs, axis=0)
    for iteration in range(max_iterations):
        if (np.linalg.norm(residual, axis=0) <= limit).all():
            return x, iteration
        q = matrix @ direction
        alpha = rz / np.einsum("ij,ij->j", direction, q)
        x += alpha * direction
        residual -= alpha * q
        z = factor.solve(residual)
        rz_new = np.einsum("ij,ij->j", residual, z)
        direction = z + (rz_new / rz) * direction
        rz = rz_new
    raise RuntimeError(f"lockstep CG did not reach rtol {rtol:g} in {max_iterations} iterations")


def iterative(matrix, rhs, pc_type: str, rtol: float):
    """CG with a PETSc preconditioner, one column after the other: (solution, iterations of
    the last column)."""
    PETSc.Options().setValue(f"warm_{pc_type}_ksp_rtol", rtol)
    cg = solver(pc_type, matrix)
    out = cg.solve(rhs)
    iterations = cg.ksp.getIterationNumber()
    cg.destroy()
    return out, iterations


def capacitance_error(matrix, x, reference) -> float:
    """Worst relative energy-norm error² of the columns: C's relative error (variational)."""
    error = x - reference
    return float(np.max(np.einsum("ij,ij->j", error, matrix @ error)
                        / np.einsum("ij,ij->j", reference, matrix @ reference)))


def best_of(repeats: int, function):
    """(the fastest wall time of ``repeats`` calls, the last result)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene", nargs="?", default="jobs/poking.toml")
    parser.add_argument("--rtol", type=float, default=1e-8, help="CG tolerance per column (default 1e-8)")
    parser.add_argument("--step-mm", type=float, default=0.1, help="largest control move of the step (default 0.1)")
    parser.add_argument("--repeats", type=int, default=3, help="time each way as the best of this many (default 3)")
    args = parser.parse_args(argv)

    scene = load_scene(args.scene)
    design = build_design(scene)
    before = design.evaluate(design.deformer.zeros())
    gradient = design.gradient(before)
    after = design.evaluate(-args.step_mm * gradient / np.abs(gradient).max(), warm=before)
    old = [electrostatic_system(before.sim.electro, pose.vertices) for pose in before.sim.poses]
    new = [electrostatic_system(after.sim.electro, pose.vertices) for pose in after.sim.poses]
    print(f"{scene.name}: {len(new)} poses, {new[0][0].shape[0]} unknowns, k = {new[0][1].shape[1]}, "
          f"|ΔA|/|A| = {max(abs(n[0] - o[0]).sum() / abs(o[0]).sum() for n, o in zip(new, old)):.1e}, "
          f"CG rtol {args.rtol:g}, best of {args.repeats}")

    rows: dict[str, list] = {}
    for package in ("cholmod", "mumps"):
        kept = [solver(package, matrix) for matrix, _ in old]
        for pose, ((matrix, rhs), factor) in enumerate(zip(new, kept)):
            direct = solver(package, old[pose][0])  # then numeric refactorisations, as an optimiser step
            wall, x = best_of(args.repeats, lambda: (direct.set_csr(matrix, spd=True), direct.solve(rhs))[1])
            rows.setdefault(f"refactor {package}", []).append((wall, 0, None))
            if package == "mumps":  # the reference of the C errors
                rows.setdefault("_reference", []).append(x)
            direct.destroy()
            wall, (y, its) = best_of(args.repeats, lambda: lockstep_cg(matrix, rhs, factor, args.rtol))
            rows.setdefault(f"stale {package}", []).append((wall, its, y))
        shared = None
        for pose, (matrix, rhs) in enumerate(new):
            if pose == 0:
                shared = solver(package, matrix)
                continue
            wall, (y, its) = best_of(args.repeats, lambda: lockstep_cg(matrix, rhs, shared, args.rtol))
            rows.setdefault(f"shared {package}", []).append((wall, its, y))
        shared.destroy()
        for factor in kept:
            factor.destroy()
    for pc_type in ("hypre", "icc"):
        for matrix, rhs in new:
            wall, (y, its) = best_of(1, lambda: iterative(matrix, rhs, pc_type, args.rtol))
            rows.setdefault(pc_type, []).append((wall, its, y))

    references = rows.pop("_reference")
    print(f"{'way':<18} {'per pose (ms)':>14} {'CG iterations':>14} {'worst C error':>14}")
    for way, entries in rows.items():
        offset = len(references) - len(entries)  # "shared" skips the first pose
        errors = [capacitance_error(new[i + offset][0], y, references[i + offset])
                  for i, (_, _, y) in enumerate(entries) if y is not None]
        walls = [e[0] * 1e3 for e in entries]
        iterations = [e[1] for e in entries]
        print(f"{way:<18} {np.mean(walls):>8.0f} ({min(walls):.0f}-{max(walls):.0f}) "
              f"{'' if not max(iterations) else f'{min(iterations)}-{max(iterations)}':>14} "
              f"{(f'{max(errors):.1e}' if errors else '(direct)'):>14}")


if __name__ == "__main__":
    main()
