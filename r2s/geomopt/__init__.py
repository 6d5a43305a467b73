"""Geometry-aware pose optimisation (paper stage c, first half): the loss L_geom over all
object poses at once, SDF contact terms guided by the contact graph, a pose anchor."""
