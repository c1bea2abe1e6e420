"""Quasi-static neo-Hookean elasticity: the problem, the material, Newton, loading, contact."""
