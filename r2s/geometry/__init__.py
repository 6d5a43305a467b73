"""Geometry as free functions on numpy arrays (one module per topic)."""
