"""Convex decomposition of a closed mesh for simulation (CoACD), deterministic per seed.

A bowl or a mug must stay concave in simulation, so a shape whose convex hull is much
larger than itself is split; a shape that is already nearly convex is kept as its hull.
"""

from __future__ import annotations

import numpy as np
import trimesh

CONVEX_VOLUME_RATIO = 0.92
"""A mesh whose volume is at least this fraction of its hull's is treated as convex."""


def _clean(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


def convex_decomposition(mesh: trimesh.Trimesh, threshold: float = 0.05, max_pieces: int = 16,
                         seed: int = 0) -> list[trimesh.Trimesh]:
    """Convex pieces (object frame) whose union approximates ``mesh``.

    Parameters
    ----------
    mesh : closed triangle mesh, metres, object frame.
    threshold : CoACD concavity threshold (smaller: more, tighter pieces).
    max_pieces : upper bound on the number of pieces.
    seed : CoACD's random seed, so that a mesh always gives the same pieces.

    Returns
    -------
    list of convex ``trimesh.Trimesh``, each watertight.
    """
    mesh = _clean(mesh)
    hull = mesh.convex_hull
    vol = abs(mesh.volume) if mesh.is_watertight else 0.0
    if vol > 0 and vol >= CONVEX_VOLUME_RATIO * hull.volume:
        return [hull]
    try:
        import coacd

        coacd.set_log_level("error")
        parts = coacd.run_coacd(
            coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64),
                       np.asarray(mesh.faces, dtype=np.int64)),
            threshold=threshold, max_convex_hull=max_pieces, seed=seed,
            preprocess_mode="auto", resolution=2000, mcts_nodes=20, mcts_iterations=100,
            mcts_max_depth=2,
        )
    except Exception:
        return [hull]
    pieces = []
    for verts, faces in parts:
        piece = trimesh.Trimesh(np.asarray(verts), np.asarray(faces), process=True).convex_hull
        if piece.volume > 1e-9:
            pieces.append(piece)
    return pieces or [hull]
