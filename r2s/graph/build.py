"""Build the contact graph from posed meshes: nodes, support tree, proximity edges, order."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import networkx as nx
import numpy as np
import trimesh

from r2s.graph.nodes import ObjectNode, build_object_node, gravity_frame
from r2s.graph.proximity import aabb_overlap_pairs
from r2s.graph.schema import ContactGraph, GraphNode, Obb, PlaneSummary, ProximityEdge
from r2s.graph.support import (TABLE_ID, SupportParams, choose_supports,
                               support_candidates)


@dataclass(frozen=True)
class GraphParams:
    """Every threshold of graph construction (recorded in the graph's ``params``)."""

    support: SupportParams = field(default_factory=SupportParams)
    proximity_margin_m: float = 0.005
    plane_max_tilt_deg: float = 20.0
    plane_height_tolerance_m: float = 0.003
    min_plane_area_m2: float = 2e-5
    n_samples: int = 2000
    seed: int = 0


@dataclass(frozen=True)
class PosedObject:
    """Input of :func:`build_contact_graph`: a mesh already placed in the world."""

    id: int
    label: str
    mesh_world: trimesh.Trimesh
    com_world_m: np.ndarray


def support_order(parent: dict[int, int], edges: list[tuple[int, int]]) -> list[int]:
    """Topological order (root first) of the support DAG: tree edges plus extra supporters.

    ``edges`` are (supporter, child) pairs; ties are broken by id.
    """
    g = nx.DiGraph()
    g.add_node(TABLE_ID)
    for child, par in parent.items():
        g.add_edge(par, child)
    for sup, child in edges:
        g.add_edge(sup, child)
    if not nx.is_directed_acyclic_graph(g):  # cannot happen with the broad phase; be safe
        g = nx.DiGraph([(p, c) for c, p in parent.items()])
        g.add_node(TABLE_ID)
    return list(nx.lexicographical_topological_sort(g, key=lambda n: (n != TABLE_ID, n)))


def _depths(parent: dict[int, int]) -> dict[int, int]:
    depth = {TABLE_ID: 0}

    def walk(i: int) -> int:
        if i not in depth:
            depth[i] = walk(parent[i]) + 1
        return depth[i]

    for i in parent:
        walk(i)
    return depth


def _node_model(node: ObjectNode, parent: int, depth: int) -> GraphNode:
    return GraphNode(
        id=node.id, label=node.label, parent=parent, depth=depth,
        obb=Obb(world_from_box=node.obb_world_from_box.tolist(),
                extents_m=node.obb_extents_m.tolist()),
        aabb_min_m=node.aabb_m[0].tolist(), aabb_max_m=node.aabb_m[1].tolist(),
        com_world_m=node.com_world_m.tolist(),
        bottom_height_m=node.bottom_height_m, top_height_m=node.top_height_m,
        footprint_uv_m=node.footprint_uv_m.tolist(),
        support_planes=[PlaneSummary(height_m=p.height_m, area_m2=p.area_m2,
                                     polygon_uv_m=p.polygon_uv_m.tolist())
                        for p in node.support_planes],
    )


def build_nodes(objects: list[PosedObject], gravity: np.ndarray, plane_point: np.ndarray,
                params: GraphParams) -> list[ObjectNode]:
    frame = gravity_frame(gravity, plane_point)
    return [build_object_node(o.id, o.label, o.mesh_world, o.com_world_m, frame,
                              n_samples=params.n_samples, seed=params.seed + o.id,
                              max_tilt_deg=params.plane_max_tilt_deg,
                              height_tolerance_m=params.plane_height_tolerance_m,
                              min_plane_area_m2=params.min_plane_area_m2)
            for o in objects]


def build_contact_graph(objects: list[PosedObject], gravity: np.ndarray,
                        plane_point: np.ndarray, plane_normal: np.ndarray,
                        params: GraphParams = GraphParams()) -> ContactGraph:
    """The scene's contact graph (see :mod:`r2s.graph`).

    Parameters
    ----------
    objects : posed meshes (world frame) with their centres of mass.
    gravity : (3,) world gravity vector.
    plane_point, plane_normal : (3,) the support plane (the root, id 0).
    """
    ids = [o.id for o in objects]
    if TABLE_ID in ids or len(set(ids)) != len(ids):
        raise ValueError("object ids must be unique and positive")
    frame = gravity_frame(gravity, plane_point)
    nodes = build_nodes(objects, gravity, plane_point, params)
    candidates = support_candidates(nodes, frame, np.asarray(plane_point),
                                    np.asarray(plane_normal), params.support)
    parent, chosen = choose_supports(candidates, params.support)
    depth = _depths(parent)
    support_pairs = {tuple(sorted((c.child, c.parent))) for c in chosen}
    prox = aabb_overlap_pairs(ids, np.stack([n.aabb_m for n in nodes]) if nodes else
                              np.zeros((0, 2, 3)), params.proximity_margin_m)
    order = support_order(parent, [(c.parent, c.child) for c in chosen])
    table = GraphNode(id=TABLE_ID, label="table", is_root=True, parent=None, depth=0)
    return ContactGraph(
        up=frame.up.tolist(), plane_basis=frame.basis.tolist(),
        plane_point=np.asarray(plane_point, dtype=float).tolist(),
        nodes=[table] + [_node_model(n, parent[n.id], depth[n.id]) for n in nodes],
        support_edges=chosen,
        proximity_edges=[ProximityEdge(a=a, b=b, support=(a, b) in support_pairs)
                         for a, b in prox],
        order=order,
        params=asdict(params),
    )
