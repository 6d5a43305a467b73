"""The one set of convex-decomposition parameters the judge's bodies are built with.

``r2s export`` decomposes every body with these (its ``convex_threshold`` and
``max_convex_pieces`` options default to them), physopt checks the scene with the same
pieces, ``r2s synth`` settles the ground truth with them and diagnose rolls out the same
bodies. Kept apart from :mod:`r2s.geometry.convex_cache`, whose source text fingerprints
the per-user memo of pieces.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ConvexParams:
    """threshold: the decomposition's concavity threshold (CoACD's units, dimensionless);
    max_pieces: most convex pieces per object."""

    threshold: float = 0.05
    max_pieces: int = 64

    def as_kwargs(self) -> dict:
        """Keyword arguments of :func:`r2s.geometry.convex_cache.cached_convex_decomposition`."""
        return {"threshold": float(self.threshold), "max_pieces": int(self.max_pieces)}


DEFAULT_CONVEX = ConvexParams()
