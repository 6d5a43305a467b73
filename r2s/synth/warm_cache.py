"""Precompute the convex decompositions of the catalogue (``python -m r2s.synth.warm_cache``).

A concave object's decomposition takes seconds (V-HACD) to minutes (CoACD); a generated
scene reuses the memo (:mod:`r2s.synth.collision`). Warming the whole catalogue once per
machine (and per version of the decomposition code) makes every later scene take seconds.

Usage: ``python -m r2s.synth.warm_cache [ycb|pybullet|mixed|NAME,NAME...]``
"""

from __future__ import annotations

import sys
import time

from r2s.synth import catalog
from r2s.synth.collision import collision_pieces, default_cache_dir


def warm(objects: str = "mixed") -> list[tuple[str, int, float]]:
    """Decompose every usable entry of ``objects``; returns (name, pieces, seconds)."""
    cache = default_cache_dir()
    out = []
    for entry in catalog.entries_for(objects):
        mesh = catalog.load_object_mesh(entry.name)
        if mesh is None:
            continue
        t0 = time.perf_counter()
        pieces = collision_pieces(mesh, cache)
        out.append((entry.name, len(pieces), time.perf_counter() - t0))
        print(f"{entry.name:28s} {len(pieces):3d} pieces {out[-1][2]:7.1f} s", flush=True)
    return out


if __name__ == "__main__":
    warm(sys.argv[1] if len(sys.argv) > 1 else "mixed")
