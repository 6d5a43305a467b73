"""``graph/contact_graph.json``: the contact graph as a pydantic model (r2s's own format).

::

    {"format": "r2s-contact-graph", "version": 1, "root": 0,
     "up": [0, 0, 1], "plane_basis": [[1, 0, 0], [0, 1, 0]], "plane_point": [0, 0, 0],
     "nodes": [{"id": 0, "label": "table", "is_root": true, ...},
               {"id": 3, "label": "mug", "parent": 0, "depth": 1,
                "obb": {"world_from_box": 4x4, "extents_m": [..]},
                "aabb_min_m": [..], "aabb_max_m": [..], "com_world_m": [..],
                "bottom_height_m": 0.0, "top_height_m": 0.1,
                "footprint_uv_m": [[u, v], ..],
                "support_planes": [{"height_m": .., "area_m2": .., "polygon_uv_m": [..]}]}],
     "support_edges": [{"child": 3, "parent": 0, "likelihood": 0.98, "d_gap": 0.02,
                        "d_com": 0.0, "gap_m": 0.001, "com_distance_m": 0.0,
                        "plane_height_m": 0.0, "in_tree": true}],
     "proximity_edges": [{"a": 3, "b": 5, "support": false}],
     "order": [0, 3, 5, ...],          # topological: every supporter before its children
     "params": {...}}

Heights are along ``up`` from ``plane_point``; (u, v) are coordinates on ``plane_basis``.
"""

from __future__ import annotations

from typing import Optional

from pydantic import BaseModel, ConfigDict, Field

GRAPH_FORMAT = "r2s-contact-graph"


class Obb(BaseModel):
    model_config = ConfigDict(extra="allow")

    world_from_box: list[list[float]]
    extents_m: list[float]


class PlaneSummary(BaseModel):
    model_config = ConfigDict(extra="allow")

    height_m: float
    area_m2: float
    polygon_uv_m: list[list[float]]


class GraphNode(BaseModel):
    model_config = ConfigDict(extra="allow")

    id: int
    label: str
    is_root: bool = False
    parent: Optional[int] = None
    depth: int = 0
    obb: Optional[Obb] = None
    aabb_min_m: Optional[list[float]] = None
    aabb_max_m: Optional[list[float]] = None
    com_world_m: Optional[list[float]] = None
    bottom_height_m: Optional[float] = None
    top_height_m: Optional[float] = None
    footprint_uv_m: list[list[float]] = Field(default_factory=list)
    support_planes: list[PlaneSummary] = Field(default_factory=list)


class SupportEdge(BaseModel):
    """One support relation (child rests on parent; 0 is the table) with the terms of its
    likelihood H (r2s.graph.support). ``in_tree``: the edge is the child's parent in the
    support tree; candidates start outside it."""

    model_config = ConfigDict(extra="allow")

    child: int
    parent: int
    likelihood: float
    d_gap: float
    d_com: float
    gap_m: float
    com_distance_m: float
    plane_height_m: float
    in_tree: bool = False


class ProximityEdge(BaseModel):
    model_config = ConfigDict(extra="allow")

    a: int
    b: int
    support: bool = False
    """Whether a support edge also joins the pair."""


class ContactGraph(BaseModel):
    model_config = ConfigDict(extra="allow")

    format: str = GRAPH_FORMAT
    version: int = 1
    root: int = 0
    up: list[float]
    plane_basis: list[list[float]]
    plane_point: list[float]
    nodes: list[GraphNode]
    support_edges: list[SupportEdge] = Field(default_factory=list)
    proximity_edges: list[ProximityEdge] = Field(default_factory=list)
    order: list[int] = Field(default_factory=list)
    params: dict = Field(default_factory=dict)

    def node(self, node_id: int) -> GraphNode:
        for n in self.nodes:
            if n.id == node_id:
                return n
        raise KeyError(node_id)

    def parent_of(self, node_id: int) -> Optional[int]:
        return self.node(node_id).parent

    def supporters_of(self, node_id: int) -> list[SupportEdge]:
        """Every recorded support edge of a child, tree edge first."""
        edges = [e for e in self.support_edges if e.child == node_id]
        return sorted(edges, key=lambda e: (not e.in_tree, -e.likelihood))

    def children_of(self, node_id: int) -> list[int]:
        return sorted(n.id for n in self.nodes if n.parent == node_id and not n.is_root)
