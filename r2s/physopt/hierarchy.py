"""Optimisation order from the contact graph: root (table) to leaves, parents first."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable, Optional

import numpy as np

from r2s.graph.schema import ContactGraph


def parents_from_graph(graph_path: Path) -> Optional[dict[int, int]]:
    """child id -> parent id (0 = the table) from ``graph/contact_graph.json``, or None.

    The support tree's edges (``in_tree``; :class:`r2s.graph.schema.SupportEdge`) give the
    parents; a node's own ``parent`` field, where the graph records one, has the last word
    (the graph stage writes both from the same choice).
    """
    graph_path = Path(graph_path)
    if not graph_path.is_file():
        return None
    return parents_of(ContactGraph.model_validate(json.loads(graph_path.read_text())))


def parents_of(graph: ContactGraph) -> Optional[dict[int, int]]:
    """child id -> parent id (0 = the table) of a contact graph (as
    :func:`parents_from_graph`), or None for a graph without support edges."""
    parents = {e.child: e.parent for e in graph.support_edges if e.in_tree}
    for node in graph.nodes:
        if node.parent is not None and node.id != graph.root:
            parents[node.id] = node.parent
    return parents or None


def order_root_to_leaves(ids: list[int], parents: Optional[dict[int, int]],
                         heights_m: dict[int, float]) -> list[int]:
    """Topological order (parents before children); without a graph, lowest object first."""
    if not parents:
        return sorted(ids, key=lambda i: heights_m.get(i, 0.0))
    depth: dict[int, int] = {}

    def depth_of(i: int, seen: tuple = ()) -> int:
        if i in depth:
            return depth[i]
        p = parents.get(i, 0)
        d = 0 if p == 0 or p not in ids or i in seen else depth_of(p, seen + (i,)) + 1
        depth[i] = d
        return d

    return sorted(ids, key=lambda i: (depth_of(i), heights_m.get(i, 0.0)))


def descendants(root: int, parents: dict[int, int]) -> set[int]:
    """Every object supported (directly or not) by ``root``, ``root`` included."""
    out = {root}
    changed = True
    while changed:
        changed = False
        for child, parent in parents.items():
            if parent in out and child not in out:
                out.add(child)
                changed = True
    return out


def lowest_points_m(objects: Iterable, meshes: dict) -> dict[int, float]:
    """Height (world z, metres) of each object's lowest vertex: the order without a graph.

    objects : items with ``id`` and ``pose`` (4, 4 world_from_object); meshes : id -> mesh.
    """
    return {o.id: float(np.min((o.pose[:3, :3] @ meshes[o.id].vertices.T).T[:, 2]
                               + o.pose[2, 3])) for o in objects}
