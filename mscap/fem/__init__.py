"""Finite elements: P1/P2 kernels, PETSc plumbing, electrostatics, elasticity, adjoints, the forward loop."""
