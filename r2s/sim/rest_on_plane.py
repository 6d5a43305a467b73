"""Does one rigid shape rest on a plane at a given pose? A short PyBullet rollout.

An object the camera saw standing on the table was at rest there. A candidate shape of
it (a registered prior, a completion) that rolls away when set down alone on the table
at the pose it was registered in contradicts that observation: its underside or its
centre of mass is wrong. :func:`rest_on_plane` measures how far it goes.

Resting on a plane involves only the shape's convex hull (the plane touches nothing
else), so the body is the hull of the mesh, with the centre of mass of the mesh itself
(uniform density; :func:`r2s.geometry.mass_properties.mass_properties`, the hull's where the
mesh is not closed). Gravity points
against the plane's normal: the object was seen at rest on this plane, whatever the
declared gravity says.

Frames: ``world_from_object`` (4, 4) takes the mesh (object frame, metres) to the world;
the plane is a point and an upward unit normal in the world.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb
import trimesh

from r2s.geometry.convex import closed_convex_hull
from r2s.geometry.mass_properties import mass_properties
from r2s.sim.pybullet_bodies import (TIME_STEP_S, add_rigid_body, add_support_plane,
                                     body_world_from_object, connect_direct)

SET_DOWN_GAP_M = 0.5e-3
"""The hull's lowest point is put this far above the plane before the rollout."""

MIN_HULL_VOLUME_M3 = 1e-9
"""A hull smaller than this (1 mm^3) is not a body PyBullet can roll out."""

MASS_KG = 0.2
"""The body's mass: on a plane alone the motion does not depend on it."""


@dataclass(frozen=True)
class RestOnPlane:
    """How far a shape set down on the plane went in the rollout.

    moved_m : translation of the object frame's origin (m), from the set-down pose.
    turned_deg : rotation angle (deg), from the set-down pose.
    lift_m : how far the pose was moved along the normal to set it down (m; > 0 = up).
    com_drop_m : how far the centre of mass went down (m): its height above the hull's
        lowest point (along the normal) at the set-down pose less that at the end. About 0
        for a shape that rolls without losing height (a true ball, a can on its side: a
        neutral rest on a real table, though it still rolls away in the simulator), > 0 for
        one that tips or rolls into a lower rest (its underside or proportions are wrong).
    """

    moved_m: float
    turned_deg: float
    lift_m: float
    com_drop_m: float


def rest_on_plane(mesh: trimesh.Trimesh, world_from_object: np.ndarray,
                  plane_point: np.ndarray, plane_normal: np.ndarray,
                  friction: float = 0.8, duration_s: float = 1.0) -> RestOnPlane:
    """Set ``mesh`` down on the plane (moved along the normal until its hull's lowest point
    is :data:`SET_DOWN_GAP_M` above it; orientation and the sideways position kept), roll it
    out alone for ``duration_s`` under gravity against the normal and report its motion.
    ``ValueError`` for a shape whose convex hull encloses no volume (a flat or degenerate
    mesh)."""
    normal = np.asarray(plane_normal, dtype=float)
    normal = normal / np.linalg.norm(normal)
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat hull's centre of mass
        try:
            hull = closed_convex_hull(mesh)
        except Exception as exc:  # qhull on flat or degenerate vertices
            raise ValueError(f"no convex hull ({str(exc)[:60]})") from None
        enclosed = hull.is_volume and hull.volume >= MIN_HULL_VOLUME_M3
    if not enclosed:
        raise ValueError("the shape encloses no volume")
    pose = np.array(world_from_object, dtype=float)
    world = np.asarray(hull.vertices) @ pose[:3, :3].T + pose[:3, 3]
    lift = SET_DOWN_GAP_M - float(np.min((world - np.asarray(plane_point)) @ normal))
    pose[:3, 3] += lift * normal
    com = mass_properties(mesh).com_in_object
    client = connect_direct()
    try:
        pb.setGravity(*(-9.81 * normal), physicsClientId=client)
        add_support_plane(client, plane_point, normal, friction)
        with tempfile.TemporaryDirectory(prefix="r2s-rest-") as folder:
            path = Path(folder) / "hull.obj"
            path.write_text(trimesh.exchange.obj.export_obj(hull, include_normals=False,
                                                            include_texture=False))
            body = add_rigid_body(client, [path], pose, MASS_KG, com, friction)
        for _ in range(int(round(duration_s / TIME_STEP_S))):
            pb.stepSimulation(physicsClientId=client)
        end = body_world_from_object(client, body, com)
    finally:
        pb.disconnect(client)
    turn = end[:3, :3] @ pose[:3, :3].T
    angle = float(np.degrees(np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0))))
    drop = (_com_above_lowest_m(hull, com, pose, normal)
            - _com_above_lowest_m(hull, com, end, normal))
    return RestOnPlane(moved_m=float(np.linalg.norm(end[:3, 3] - pose[:3, 3])),
                       turned_deg=angle, lift_m=lift, com_drop_m=drop)


def _com_above_lowest_m(hull: trimesh.Trimesh, com_in_object: np.ndarray,
                        world_from_object: np.ndarray, normal: np.ndarray) -> float:
    """How far the centre of mass lies above the hull's lowest point along ``normal`` (m) at
    ``world_from_object``: the height it has over the plane when resting there, whatever gap
    or contact margin holds the body off the plane."""
    rot = np.asarray(world_from_object, dtype=float)[:3, :3]
    lowest = float(np.min((np.asarray(hull.vertices) @ rot.T) @ normal))
    return float((rot @ np.asarray(com_in_object, dtype=float)) @ normal) - lowest
