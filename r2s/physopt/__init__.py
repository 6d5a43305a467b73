"""Hierarchical physics-constrained optimisation (the physopt stage's building blocks)."""
