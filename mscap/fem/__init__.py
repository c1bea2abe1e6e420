"""Finite elements: P1/P2 kernels, PETSc plumbing, electrostatics, elasticity, adjoints, the forward loop,
interpolation between meshes (:mod:`~mscap.fem.transfer`).

Its public names load their module on first use::

    from mscap import simulate                   # (mscap.fem.simulate is the module)
    sim = simulate(scene)                        # every pose: Newton, then capacitances
    sim.capacitance_pF                           # (poses, k)
"""

from mscap._lazy import lazy_names

__all__, __getattr__ = lazy_names(__name__, {
    "Simulation": "simulate",
    "PoseResult": "simulate",
    "solve_poses": "simulate",
    "LinearSolver": "petsc",
    "Operator": "petsc",
    "pose_rest_gradient": "adjoint",
    "interpolation_matrix": "transfer",
    "p1_matrix": "transfer",
})
