"""What the viewer shows, read from a scene directory (pure: numpy and trimesh, no viser).

Every position is in the scene's world frame (metres, the frame of ``export/scene.json``).
Reads ``input/`` (observed point cloud), ``export/`` (meshes, collision pieces, poses),
``graph/contact_graph.json`` and ``evaluate/metrics.json`` (the judge's rollout settings);
only ``export/`` is required.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import trimesh
from pydantic import ValidationError

from r2s.errors import InputError
from r2s.geometry.camera import backproject
from r2s.graph.schema import ContactGraph
from r2s.io.declared_world import camera_in_export_world
from r2s.io.input_scene import Camera, load_camera, load_depth, load_rgb, read_json_file
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import ScenePaths
from r2s.io.unmodelled import read_unmodelled_boxes
from r2s.io.scene_json import ExportScene, read_export_scene

SUPPORT_EDGE_RGB = (40, 170, 60)
"""Colour of support edges (child -> supporter) in the contact graph."""

PROXIMITY_EDGE_RGB = (240, 140, 20)
"""Colour of proximity edges (objects closer than the graph's proximity distance)."""

MAX_POINTS = 60000
"""The observed point cloud is subsampled (on a regular pixel grid) to at most this many."""


@dataclass
class ViewerObject:
    """One exported object.

    ``visual`` and ``collision`` are in the object frame; ``world_from_object`` (4, 4) is the
    exported pose; ``com_world_m`` (3,) the exported centre of mass in the world frame.
    """

    id: int
    label: str
    visual: trimesh.Trimesh
    collision: list[trimesh.Trimesh]
    world_from_object: np.ndarray
    com_world_m: np.ndarray

    @property
    def name(self) -> str:
        return f"{self.id} {self.label}".strip()


@dataclass
class GraphSegments:
    """Contact-graph edges as line segments between object centres.

    ``points`` : (E, 2, 3) world endpoints; ``kinds`` : E strings, "support" or "proximity";
    ``pairs`` : E (a, b) node ids (for support edges ``(child, supporter)``; a supporter
    that is the table is drawn at the child's centre dropped onto the support plane).
    """

    points: np.ndarray
    kinds: list[str]
    pairs: list[tuple[int, int]]

    def colours(self) -> np.ndarray:
        """(E, 2, 3) uint8 colour of each endpoint, by kind."""
        rgb = [SUPPORT_EDGE_RGB if k == "support" else PROXIMITY_EDGE_RGB for k in self.kinds]
        arr = np.asarray(rgb, dtype=np.uint8).reshape(-1, 1, 3)
        return np.repeat(arr, 2, axis=1)


@dataclass
class ViewerScene:
    """Everything the viewer draws. Optional parts are None when their files are absent."""

    root: Path
    export: ExportScene
    objects: list[ViewerObject]
    points_m: Optional[np.ndarray] = None          # (P, 3) observed points, world
    points_rgb: Optional[np.ndarray] = None        # (P, 3) uint8 their colours
    camera: Optional[Camera] = None
    graph: Optional[GraphSegments] = None
    point_size_m: float = 0.002                    # about one pixel's footprint on the table
    rollout_duration_s: float = 3.0
    rollout_rate_hz: float = 240.0
    notes: list[str] = field(default_factory=list)  # what could not be shown, and why
    # export/unmodelled.json: (world_from_box (4, 4), size_m (3,)) of each unmasked thing
    unmodelled: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

    def centre_m(self) -> np.ndarray:
        """(3,) mean of the object centres (the origin when there is no object)."""
        if not self.objects:
            return np.zeros(3)
        return np.mean([o.com_world_m for o in self.objects], axis=0)


def _objects(paths: ScenePaths, scene: ExportScene) -> list[ViewerObject]:
    out = []
    for o in scene.objects:
        pose = np.asarray(o.world_from_object, dtype=np.float64)
        com = pose[:3, :3] @ np.asarray(o.com_in_object, dtype=np.float64) + pose[:3, 3]
        out.append(ViewerObject(
            id=o.id, label=o.label, visual=load_mesh(paths.export / o.visual_mesh),
            collision=[load_mesh(paths.export / rel) for rel in o.collision_meshes],
            world_from_object=pose, com_world_m=com))
    return out


def observed_points(paths: ScenePaths, max_points: int = MAX_POINTS
                    ) -> tuple[np.ndarray, np.ndarray, Camera, float]:
    """Points back-projected from ``input/`` depth: (P, 3) world points, (P, 3) uint8
    colours, the camera, and the size (metres) of one sampled pixel at the median depth.

    Pixels are taken on a regular grid whose stride keeps P <= ``max_points``.
    """
    cam, unit_m = load_camera(paths.camera)
    cam = camera_in_export_world(cam, paths.export)  # where the exported objects are
    depth = load_depth(paths, cam.width, cam.height, unit_m)
    rgb = load_rgb(paths.rgb, cam.width, cam.height)
    valid = int(np.isfinite(depth).sum())
    stride = max(1, int(np.ceil(np.sqrt(valid / max_points))))
    grid = np.zeros(depth.shape, dtype=bool)
    grid[::stride, ::stride] = True
    pts, pix = backproject(depth, cam.K, cam.world_from_camera, mask=grid, return_pixels=True)
    footprint_m = float(np.nanmedian(depth)) * stride / float(cam.K[0, 0])
    return pts, rgb[pix[:, 0], pix[:, 1]].astype(np.uint8), cam, footprint_m


def graph_segments(graph: ContactGraph, objects: list[ViewerObject],
                   plane_point: np.ndarray, plane_normal: np.ndarray) -> GraphSegments:
    """Segments of the graph's support and proximity edges between exported object centres.

    Nodes that are not exported objects (the table) sit at the other end's centre projected
    onto the plane ``(plane_point, plane_normal)``; edges between two such nodes are skipped.
    """
    centre = {o.id: o.com_world_m for o in objects}
    n = np.asarray(plane_normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    p0 = np.asarray(plane_point, dtype=np.float64)

    def ends(a: int, b: int) -> Optional[np.ndarray]:
        if a not in centre and b not in centre:
            return None
        ca = centre.get(a, None)
        cb = centre.get(b, None)
        if ca is None:
            ca = cb - np.dot(cb - p0, n) * n
        if cb is None:
            cb = ca - np.dot(ca - p0, n) * n
        return np.stack([ca, cb])

    points, kinds, pairs = [], [], []
    for e in graph.support_edges:
        seg = ends(e.child, e.parent)
        if seg is not None:
            points.append(seg), kinds.append("support"), pairs.append((e.child, e.parent))
    for e in graph.proximity_edges:
        seg = ends(e.a, e.b)
        if seg is not None:
            points.append(seg), kinds.append("proximity"), pairs.append((e.a, e.b))
    arr = np.stack(points) if points else np.zeros((0, 2, 3))
    return GraphSegments(points=arr, kinds=kinds, pairs=pairs)


def _rollout_settings(paths: ScenePaths) -> tuple[float, float]:
    """(duration_s, rate_hz) the judge used, from evaluate/metrics.json; (3, 240) without it."""
    if not paths.metrics.is_file():
        return 3.0, 240.0
    opts = (read_json_file(paths.metrics) or {}).get("options", {})
    return float(opts.get("duration_s", 3.0)), float(opts.get("rate_hz", 240.0))


def load_viewer_scene(scene_dir: Path, max_points: int = MAX_POINTS) -> ViewerScene:
    """Read a scene directory for the viewer. :class:`InputError` without ``export/scene.json``."""
    paths = ScenePaths(Path(scene_dir))
    if not paths.export_scene.is_file():
        raise InputError(paths.export_scene,
                         f"missing; run 'r2s run {scene_dir}' (or 'r2s export') first")
    export = read_export_scene(paths.export_scene)
    scene = ViewerScene(root=paths.root, export=export, objects=_objects(paths, export))
    try:
        (scene.points_m, scene.points_rgb, scene.camera,
         scene.point_size_m) = observed_points(paths, max_points)
    except InputError as exc:
        scene.notes.append(f"no observed point cloud: {exc}")
    if paths.contact_graph.is_file():
        try:
            graph = ContactGraph.model_validate(read_json_file(paths.contact_graph))
            scene.graph = graph_segments(graph, scene.objects, np.asarray(export.support.point),
                                         np.asarray(export.support.normal))
        except ValidationError as exc:
            scene.notes.append(f"{paths.contact_graph}: malformed ({exc.errors()[0]['msg']})")
    else:
        scene.notes.append("no contact graph (graph/contact_graph.json is missing)")
    scene.rollout_duration_s, scene.rollout_rate_hz = _rollout_settings(paths)
    scene.unmodelled = read_unmodelled_boxes(paths.export)
    return scene
