"""The physical residual: roll the reconstruction forward in PyBullet and see what moves.

A :class:`WorldSpec` is the scene as rigid bodies (convex collision pieces on disk, poses,
mass, COM, friction) and a support plane. :func:`rollout_motion` builds a fresh DIRECT
client for one :class:`r2s.diagnose.data.PhysicsModel` (gravity, COM shifts, friction),
steps it and reports each object's :class:`r2s.diagnose.data.Motion`;
:func:`support_contacts` finds where each object rests on something below it.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import open3d as o3d
import pybullet as pb
import trimesh
from scipy.spatial.transform import Rotation

from r2s.diagnose.data import Motion, PhysicsModel
from r2s.sim.pybullet_bodies import (add_rigid_body, add_support_plane, body_world_from_object,
                                     connect_direct)

SUPPORT_NORMAL_MIN_UP = 0.3
"""A contact supports an object when its normal (towards the object) has at least this
component along up."""


@dataclass(frozen=True)
class BodySpec:
    """One rigid body: convex collision files in the object frame and its physics."""

    id: int
    files: tuple
    world_from_object: np.ndarray
    mass_kg: float
    com_in_object: np.ndarray
    friction: float
    radius_m: float = 0.05
    mesh: Optional[trimesh.Trimesh] = None
    """The shape in the object frame (for contact patches); None: the convex pieces."""

    def shape(self) -> trimesh.Trimesh:
        if self.mesh is not None:
            return self.mesh
        return trimesh.util.concatenate([trimesh.load(f, force="mesh") for f in self.files])


@dataclass
class WorldSpec:
    """Bodies and the support plane; ``keep`` holds a temporary folder alive."""

    bodies: list
    support_point: np.ndarray
    support_normal: np.ndarray
    support_friction: float
    keep: Optional[tempfile.TemporaryDirectory] = field(default=None, repr=False)

    def body(self, obj_id: int) -> BodySpec:
        return next(b for b in self.bodies if b.id == obj_id)


def write_pieces(pieces: list[trimesh.Trimesh], folder: Path, stem: str) -> tuple:
    """Save convex pieces as ``folder/stem_k.obj``; returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for k, piece in enumerate(pieces):
        f = folder / f"{stem}_{k}.obj"
        piece.export(f)
        files.append(f)
    return tuple(files)


@dataclass
class Client:
    client: int
    body_ids: dict
    coms: dict
    support_body: int = 0

    def close(self) -> None:
        pb.disconnect(physicsClientId=self.client)


def build_client(spec: WorldSpec, model: PhysicsModel) -> Client:
    """A DIRECT client holding ``spec`` with ``model``'s gravity, COM shifts and friction."""
    client = connect_direct()
    pb.setGravity(*[float(g) for g in model.gravity], physicsClientId=client)
    plane = add_support_plane(client, spec.support_point, spec.support_normal,
                              spec.support_friction)
    ids, coms = {}, {}
    for b in spec.bodies:
        com = np.asarray(b.com_in_object, dtype=np.float64)
        shift = model.com_shift_world_m.get(b.id)
        if shift is not None:
            com = com + np.asarray(b.world_from_object)[:3, :3].T @ np.asarray(shift, dtype=float)
        friction = float(model.friction.get(b.id, b.friction))
        ids[b.id] = add_rigid_body(client, b.files, b.world_from_object, b.mass_kg, com, friction)
        coms[b.id] = com
    return Client(client, ids, coms, plane)


def _poses(c: Client) -> dict:
    return {i: body_world_from_object(c.client, b, c.coms[i]) for i, b in c.body_ids.items()}


def motion_between(pose0: np.ndarray, pose1: np.ndarray, com_in_object: np.ndarray) -> Motion:
    """:class:`Motion` of a body from ``pose0`` to ``pose1`` (4, 4) with its COM."""
    c0 = pose0[:3, :3] @ com_in_object + pose0[:3, 3]
    c1 = pose1[:3, :3] @ com_in_object + pose1[:3, 3]
    rel = pose1[:3, :3] @ pose0[:3, :3].T
    return Motion(translation_m=c1 - c0, rotation_rad=Rotation.from_matrix(rel).as_rotvec())


def rollout_motion(spec: WorldSpec, model: PhysicsModel, horizon_s: float = 1.0,
                   rate_hz: float = 240.0) -> dict:
    """{object id: :class:`Motion`} over ``horizon_s`` of simulation under ``model``."""
    c = build_client(spec, model)
    try:
        pb.setTimeStep(1.0 / rate_hz, physicsClientId=c.client)
        start = _poses(c)
        for _ in range(max(1, int(round(horizon_s * rate_hz)))):
            pb.stepSimulation(physicsClientId=c.client)
        end = _poses(c)
    finally:
        c.close()
    return {i: motion_between(start[i], end[i], c.coms[i]) for i in start}


def support_contacts(spec: WorldSpec, up: np.ndarray, gap_m: float = 0.002,
                     reach_m: float = 0.005, samples: int = 3000) -> tuple[dict, dict]:
    """Where each object rests on something below it, and whom it touches.

    Returns ``{object id: (M, 3) contact points, world}`` and ``{object id: set of ids of
    the objects within reach_m of it}``.


    Geometric, on the shapes at their initial poses: surface samples of the object within
    ``gap_m`` of their closest approach to a supporter (the plane, or another object whose
    surface there faces up), for every supporter closer than ``reach_m``. This gives the
    whole contact patch (a line for a lying cylinder), where a simulator's contact query
    reports a single closest point per pair of convex shapes.
    """
    neighbours: dict = {b.id: set() for b in spec.bodies}
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    posed = {b.id: b.shape().copy().apply_transform(np.asarray(b.world_from_object))
             for b in spec.bodies}
    scenes = {i: _distance_scene(m) for i, m in posed.items()}
    n_plane = np.asarray(spec.support_normal, dtype=np.float64)
    n_plane /= np.linalg.norm(n_plane)
    out: dict = {}
    for obj_id, mesh in posed.items():
        pts, _ = trimesh.sample.sample_surface(mesh, samples, seed=0)
        pts = np.vstack([np.asarray(pts), np.asarray(mesh.vertices)])
        found = []
        if n_plane @ up >= SUPPORT_NORMAL_MIN_UP:
            d = (pts - np.asarray(spec.support_point)) @ n_plane
            if d.min() <= reach_m:
                found.append(pts[d <= max(d.min(), 0.0) + gap_m])
        for other, scene in scenes.items():
            if other == obj_id:
                continue
            ans = scene.compute_closest_points(o3d.core.Tensor(pts.astype(np.float32)))
            closest = ans["points"].numpy().astype(np.float64)
            normal = ans["primitive_normals"].numpy().astype(np.float64)
            d = np.linalg.norm(pts - closest, axis=1)
            if d.min() <= reach_m:
                neighbours[obj_id].add(other)
                neighbours[other].add(obj_id)
            below = normal @ up >= SUPPORT_NORMAL_MIN_UP
            if not below.any() or d[below].min() > reach_m:
                continue
            found.append(pts[below & (d <= d[below].min() + gap_m)])
        out[obj_id] = np.vstack(found) if found else np.zeros((0, 3))
    return out, neighbours


def _distance_scene(mesh: trimesh.Trimesh) -> "o3d.t.geometry.RaycastingScene":
    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.int32))
    scene.add_triangles(tm)
    return scene
