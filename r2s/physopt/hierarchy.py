"""Optimisation order from the contact graph: root (table) to leaves, parents first."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import numpy as np


def parents_from_graph(graph_path: Path) -> Optional[dict[int, int]]:
    """child id -> parent id (0 = the table) from ``graph/contact_graph.json``, or None."""
    graph_path = Path(graph_path)
    if not graph_path.is_file():
        return None
    data = json.loads(graph_path.read_text())
    parents: dict[int, int] = {}
    for edge in data.get("support_edges", []):
        if edge.get("is_tree_edge", True) and "child" in edge and "parent" in edge:
            child, parent = int(edge["child"]), int(edge["parent"])
            if child not in parents or edge.get("is_tree_edge", False):
                parents[child] = parent
    for node in data.get("nodes", []):
        if "id" in node and "parent" in node and node["parent"] is not None and int(node["id"]) != 0:
            parents[int(node["id"])] = int(node["parent"])
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


def lowest_point_heights(meshes_world: dict[int, np.ndarray]) -> dict[int, float]:
    """Min z of each object's world vertices (sort key without a graph)."""
    return {i: float(np.min(v[:, 2])) for i, v in meshes_world.items()}
