"""The one set of convex-decomposition parameters the judge's bodies are built with.

``r2s export`` decomposes every body with these (its ``convex_threshold`` and
``max_convex_pieces`` options default to them), physopt checks the scene with the same
pieces, ``r2s synth`` settles the ground truth with them and diagnose rolls out the same
bodies. Kept apart from :mod:`r2s.geometry.convex_cache`, whose source text fingerprints
the per-user memo of pieces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

ConvexMethod = Literal["vhacd", "coacd"]
DEFAULT_METHOD: ConvexMethod = "vhacd"


@dataclass(frozen=True)
class ConvexParams:
    """threshold: CoACD's concavity threshold (dimensionless; used by method="coacd" only);
    max_pieces: most convex pieces per object; method: "vhacd" (PyBullet's V-HACD, the
    default) or "coacd" (:func:`r2s.geometry.convex.convex_decomposition`)."""

    threshold: float = 0.05
    max_pieces: int = 64
    method: ConvexMethod = DEFAULT_METHOD

    def as_kwargs(self) -> dict:
        """Keyword arguments of :func:`r2s.geometry.convex_cache.cached_convex_decomposition`.

        ``method`` is named only when it is not the default, so the cache keys of V-HACD
        pieces (and those ``r2s synth`` primed) stay what they were before it was selectable.
        """
        kwargs: dict = {"threshold": float(self.threshold), "max_pieces": int(self.max_pieces)}
        if self.method != DEFAULT_METHOD:
            kwargs["method"] = self.method
        return kwargs


DEFAULT_CONVEX = ConvexParams()
