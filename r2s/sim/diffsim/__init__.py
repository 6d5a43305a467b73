"""Differentiable rigid-body simulator (torch) for the physics-constrained optimisation."""
