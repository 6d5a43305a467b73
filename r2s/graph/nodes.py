"""Contact-graph nodes: each object as gravity sees it.

Heights are measured along ``up`` (opposite to gravity) from the support plane's point;
2-D coordinates (u, v) are the world position projected on the plane perpendicular to
``up`` with the basis of :func:`gravity_frame`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from r2s.graph.polygon import convex_hull_2d


@dataclass(frozen=True)
class GravityFrame:
    """``up`` (3,) unit vector against gravity; ``basis`` (2, 3) spans the horizontal plane;
    ``origin`` (3,) the support plane's point (height 0)."""

    up: np.ndarray
    basis: np.ndarray
    origin: np.ndarray

    def height(self, points: np.ndarray) -> np.ndarray:
        """(N,) height of (N, 3) world points above the origin along ``up``."""
        return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.origin) @ self.up

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) horizontal coordinates of (N, 3) world points."""
        return (np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.origin) @ self.basis.T


def gravity_frame(gravity: np.ndarray, origin: np.ndarray) -> GravityFrame:
    """The frame in which heights and footprints are measured (deterministic basis)."""
    g = np.asarray(gravity, dtype=np.float64)
    norm = np.linalg.norm(g)
    up = -g / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return GravityFrame(up=up, basis=np.stack([e1, e2]), origin=np.asarray(origin, dtype=np.float64))


@dataclass(frozen=True)
class SupportPlaneInfo:
    """One upward-facing planar region of a mesh.

    height_m : area-weighted height of its faces; area_m2 : their total area;
    polygon_uv_m : (K, 2) convex hull of its faces' vertices in horizontal coordinates.
    """

    height_m: float
    area_m2: float
    polygon_uv_m: np.ndarray


@dataclass(frozen=True)
class ObjectNode:
    """An object of the scene in the gravity frame (all arrays world-derived).

    obb_world_from_box : (4, 4) pose of the oriented bounding box; obb_extents_m : (3,).
    aabb_m : (2, 3) world axis-aligned bounds.
    com_world_m : (3,) centre of mass.
    bottom_height_m, top_height_m : lowest / highest height of the mesh.
    footprint_uv_m : (K, 2) convex hull of the mesh projected on the horizontal plane.
    support_planes : upward planar regions, lowest first.
    samples_world_m : (N, 3) surface samples (plus vertices), for gap measurements.
    """

    id: int
    label: str
    obb_world_from_box: np.ndarray
    obb_extents_m: np.ndarray
    aabb_m: np.ndarray
    com_world_m: np.ndarray
    bottom_height_m: float
    top_height_m: float
    footprint_uv_m: np.ndarray
    support_planes: tuple[SupportPlaneInfo, ...] = field(default_factory=tuple)
    samples_world_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def support_planes(mesh_world: trimesh.Trimesh, frame: GravityFrame, max_tilt_deg: float,
                   height_tolerance_m: float, min_area_m2: float) -> tuple[SupportPlaneInfo, ...]:
    """Upward planar regions: faces whose normal is within ``max_tilt_deg`` of ``up``,
    grouped by height (a new group starts where sorted face heights jump by more than
    ``height_tolerance_m``); groups smaller than ``min_area_m2`` are dropped."""
    normals = np.asarray(mesh_world.face_normals)
    areas = np.asarray(mesh_world.area_faces)
    upward = (normals @ frame.up) >= np.cos(np.radians(max_tilt_deg))
    upward &= areas > 0
    if not np.any(upward):
        return ()
    face_ids = np.flatnonzero(upward)
    heights = frame.height(np.asarray(mesh_world.triangles_center)[face_ids])
    order = np.argsort(heights)
    face_ids, heights = face_ids[order], heights[order]
    breaks = np.flatnonzero(np.diff(heights) > height_tolerance_m) + 1
    planes = []
    for group, h in zip(np.split(face_ids, breaks), np.split(heights, breaks)):
        area = float(areas[group].sum())
        if area < min_area_m2:
            continue
        verts = np.asarray(mesh_world.vertices)[np.asarray(mesh_world.faces)[group].reshape(-1)]
        planes.append(SupportPlaneInfo(
            height_m=float(np.average(h, weights=areas[group])), area_m2=area,
            polygon_uv_m=convex_hull_2d(frame.project(verts))))
    return tuple(planes)


def build_object_node(obj_id: int, label: str, mesh_world: trimesh.Trimesh,
                      com_world_m: np.ndarray, frame: GravityFrame, *, n_samples: int = 2000,
                      seed: int = 0, max_tilt_deg: float = 20.0,
                      height_tolerance_m: float = 0.003,
                      min_plane_area_m2: float = 2e-5) -> ObjectNode:
    """Describe one object (mesh already placed in the world) for the contact graph."""
    vertices = np.asarray(mesh_world.vertices, dtype=np.float64)
    heights = frame.height(vertices)
    try:
        obb = mesh_world.bounding_box_oriented
        world_from_box = np.asarray(obb.primitive.transform, dtype=np.float64)
        extents = np.asarray(obb.primitive.extents, dtype=np.float64)
    except Exception:  # degenerate meshes: fall back to the AABB  # noqa: BLE001
        world_from_box = np.eye(4)
        world_from_box[:3, 3] = vertices.mean(axis=0)
        extents = vertices.max(axis=0) - vertices.min(axis=0)
    samples, _ = trimesh.sample.sample_surface(mesh_world, n_samples, seed=seed)
    footprint = convex_hull_2d(frame.project(vertices))
    return ObjectNode(
        id=int(obj_id), label=str(label), obb_world_from_box=world_from_box,
        obb_extents_m=extents,
        aabb_m=np.stack([vertices.min(axis=0), vertices.max(axis=0)]),
        com_world_m=np.asarray(com_world_m, dtype=np.float64).reshape(3),
        bottom_height_m=float(heights.min()), top_height_m=float(heights.max()),
        footprint_uv_m=footprint,
        support_planes=support_planes(mesh_world, frame, max_tilt_deg, height_tolerance_m,
                                      min_plane_area_m2),
        samples_world_m=np.concatenate([np.asarray(samples, dtype=np.float64), vertices]),
    )


def footprint_radius_m(node: ObjectNode, frame: GravityFrame) -> float:
    """Largest horizontal distance from the projected COM to the footprint's vertices."""
    c = frame.project(node.com_world_m[None])[0]
    if len(node.footprint_uv_m) == 0:
        return 0.0
    return float(np.max(np.linalg.norm(node.footprint_uv_m - c, axis=1)))
