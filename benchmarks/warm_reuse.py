"""Can an optimiser step reuse the previous design's factorisation? (issue 18, part 1)

For each pose of a scene this script factorises the electrostatic matrix at the initial
layout. It then solves the matrix of a design 0.1 mm along −∇J in two ways: by CG
preconditioned with that old factorisation, and by a fresh factorisation plus solves
(what mscap does today). It prints the CG iterations per right-hand side, the agreement
of the two solutions, and both times. Run::

    .venv/bin/python benchmarks/warm_reuse.py [jobs/poking_cross.toml]
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import time, numpy as np, scipy.sparse as sp
from mscap import load_scene, build_design
from mscap.fem import electrostatic
from mscap.fem.petsc import petsc, LinearSolver
PETSc = petsc()
scene = load_scene(sys.argv[1] if len(sys.argv) > 1 else "jobs/poking_cross.toml")
d = build_design(scene)
e0 = d.evaluate(d.deformer.zeros())
g = d.gradient(e0)
q1 = -0.1 * g / np.abs(g).max()   # a 0.1 mm step, as an optimiser step
e1 = d.evaluate(q1, warm=e0)
for i in range(len(scene.poses)):
    p = e0.sim.electro
    def kff(sim, res):
        data = electrostatic.assemble(sim.electro, res.vertices)
        pr = sim.electro
        A = sp.csr_matrix((data[pr.ff_entries], pr.ff_indices, pr.ff_indptr), shape=(len(pr.free),) * 2)
        coupling = np.bincount(pr.fd_target, weights=data[pr.fd_entries], minlength=len(pr.free) * 2 * pr.k)
        return A, -coupling.reshape(len(pr.free), 2 * pr.k)[:, pr.k:]
    A0, _ = kff(e0.sim, e0.sim.poses[i]); A1, b1 = kff(e1.sim, e1.sim.poses[i])
    def mat(A):
        A = A.tocsr(); m = PETSc.Mat().createAIJWithArrays(A.shape, (A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType), A.data.copy())); m.setOption(PETSc.Mat.Option.SPD, True); return m
    M0, M1 = mat(A0), mat(A1)
    t = time.perf_counter(); direct = LinearSolver("electro_"); direct.set_csr(A1, spd=True); x_direct = direct.solve(b1); t_direct = time.perf_counter() - t
    ksp = PETSc.KSP().create(PETSc.COMM_SELF); ksp.setType("cg"); ksp.getPC().setType("cholesky"); ksp.getPC().setFactorSolverType("cholmod")
    ksp.setOperators(M0); ksp.setUp()   # factor of the previous design (kept)
    ksp.setOperators(M1, M0); ksp.setTolerances(rtol=1e-10)
    its, t = [], time.perf_counter()
    xs = []
    for j in range(b1.shape[1]):
        b = M1.createVecLeft(); b.setArray(b1[:, j]); x = M1.createVecRight(); ksp.solve(b, x); its.append(ksp.getIterationNumber()); xs.append(x.getArray().copy())
    t_pcg = time.perf_counter() - t
    err = max(np.abs(np.array(xs).T - x_direct).max() / np.abs(x_direct).max(), 0)
    print(f"pose {i}: n = {A1.shape[0]}, k = {b1.shape[1]}, PCG iterations {its}, rel err {err:.1e}; "
          f"fresh factorisation + solves {t_direct:.3f} s, PCG with the old factor {t_pcg:.3f} s")
    ksp.destroy(); direct.destroy()
