"""Assemble a :class:`GeomProblem` from meshes, poses, SDFs and the contact graph."""

from __future__ import annotations

import numpy as np
import trimesh

from r2s.geometry.sdf import SdfGrid
from r2s.geomopt.optimise import TABLE, GeomProblem
from r2s.graph.schema import ContactGraph


def surface_samples(mesh: trimesh.Trimesh, count: int, seed: int) -> np.ndarray:
    """(count, 3) area-uniform surface samples of ``mesh`` (its own frame), seeded."""
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(pts, dtype=np.float64)


def graph_pairs(graph: ContactGraph, ids: list[int], all_supporters: bool = True,
                min_likelihood: float = 0.0
                ) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Support edges (child index, parent index or TABLE) and proximity pairs (indices).

    ``all_supporters``: extra (non-tree) supporters get the contact term too; otherwise
    only the tree parent does. A tree edge whose likelihood H is under ``min_likelihood``
    is the graph's fallback for a child nothing was found under (the table 55 mm below a
    ball wedged between its neighbours): it gets no contact term, and an object parent
    stays a penetration pair. Ids absent from ``ids`` are ignored.
    """
    index = {obj_id: i for i, obj_id in enumerate(ids)}
    support, unsupported = [], []
    for e in graph.support_edges:
        if not (e.in_tree or all_supporters) or e.child not in index:
            continue
        if e.parent == graph.root:
            pair = (index[e.child], TABLE)
        elif e.parent in index:
            pair = (index[e.child], index[e.parent])
        else:
            continue
        (support if e.likelihood >= min_likelihood else unsupported).append(pair)
    prox = {tuple(sorted((index[p.a], index[p.b]))) for p in graph.proximity_edges
            if p.a in index and p.b in index}
    prox |= {tuple(sorted(pair)) for pair in unsupported if pair[1] != TABLE}
    return sorted(set(support)), sorted(prox)


def build_problem(ids: list[int], meshes: list[trimesh.Trimesh], world_from_object: np.ndarray,
                  grids: list[SdfGrid], graph: ContactGraph, plane_point: np.ndarray,
                  plane_normal: np.ndarray, samples: int = 2000, seed: int = 0,
                  all_supporters: bool = True, gravity: np.ndarray | None = None,
                  min_support_likelihood: float = 0.0) -> GeomProblem:
    """The optimisation problem of one scene.

    Parameters
    ----------
    ids : (M,) object ids; meshes, grids : per object, object frame.
    world_from_object : (M, 4, 4) init poses.
    graph : the contact graph of the same objects.
    samples : surface samples per object (seeded by ``seed + id``).
    gravity : (3,) world gravity; the contact term moves objects along it (default: -normal).
    min_support_likelihood : support edges under this H get no contact term (:func:`graph_pairs`).
    """
    poses = np.asarray(world_from_object, dtype=np.float64)
    samples_obj = np.stack([surface_samples(m, samples, seed + i) for m, i in zip(meshes, ids)])
    centres = np.stack([p[:3, :3] @ np.asarray(m.centroid) + p[:3, 3] for m, p in zip(meshes, poses)])
    support, prox = graph_pairs(graph, ids, all_supporters, min_support_likelihood)
    n = np.asarray(plane_normal, dtype=np.float64)
    up = None if gravity is None else -np.asarray(gravity, dtype=np.float64)
    return GeomProblem(ids=list(ids), samples_object_m=samples_obj, init_world_from_object=poses,
                       centres_world_m=centres, grids=list(grids),
                       plane_point=np.asarray(plane_point, dtype=np.float64),
                       plane_normal=n / np.linalg.norm(n), support_edges=support,
                       penetration_pairs=prox, up=None if up is None else up / np.linalg.norm(up))
