"""Small PyBullet helpers shared by the generator, the judge and the optimisers.

Frames: PyBullet's base position is the *link* frame at creation but
``getBasePositionAndOrientation`` returns the *inertial* (COM) frame; these helpers hide
that and always speak ``world_from_object`` (4, 4).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pybullet as pb

TIME_STEP_S = 1.0 / 240.0


def connect_direct() -> int:
    """A headless PyBullet client (DIRECT mode) with default 240 Hz stepping."""
    client = pb.connect(pb.DIRECT)
    pb.setTimeStep(TIME_STEP_S, physicsClientId=client)
    return client


def quat_xyzw_from_matrix(rot: np.ndarray) -> list[float]:
    """(3, 3) rotation -> PyBullet quaternion [x, y, z, w]."""
    from scipy.spatial.transform import Rotation

    return list(Rotation.from_matrix(np.asarray(rot, dtype=float)).as_quat())


def matrix_from_quat_xyzw(quat: Sequence[float]) -> np.ndarray:
    return np.asarray(pb.getMatrixFromQuaternion(quat), dtype=np.float64).reshape(3, 3)


def add_support_plane(client: int, point: Sequence[float], normal: Sequence[float],
                      friction: float) -> int:
    """A static infinite plane through ``point`` with upward ``normal`` (world frame)."""
    normal = np.asarray(normal, dtype=float)
    normal = normal / np.linalg.norm(normal)
    shape = pb.createCollisionShape(pb.GEOM_PLANE, planeNormal=[0, 0, 1], physicsClientId=client)
    rot = _rotation_z_to(normal)
    body = pb.createMultiBody(0.0, shape, basePosition=list(map(float, point)),
                              baseOrientation=quat_xyzw_from_matrix(rot), physicsClientId=client)
    pb.changeDynamics(body, -1, lateralFriction=float(friction), restitution=0.0,
                      physicsClientId=client)
    return body


def _rotation_z_to(normal: np.ndarray) -> np.ndarray:
    """A rotation taking +z to ``normal`` (unit)."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, normal)
    s, c = np.linalg.norm(v), float(np.dot(z, normal))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / s**2)


def add_rigid_body(client: int, collision_files: Sequence[Path], world_from_object: np.ndarray,
                   mass_kg: float, com_in_object: Sequence[float], friction: float,
                   restitution: float = 0.0) -> int:
    """One dynamic body made of convex mesh pieces (files in the object frame)."""
    files = [str(f) for f in collision_files]
    shape = pb.createCollisionShapeArray([pb.GEOM_MESH] * len(files), fileNames=files,
                                         physicsClientId=client)
    pose = np.asarray(world_from_object, dtype=float)
    body = pb.createMultiBody(
        float(mass_kg), shape,
        basePosition=list(pose[:3, 3]),
        baseOrientation=quat_xyzw_from_matrix(pose[:3, :3]),
        baseInertialFramePosition=[float(x) for x in com_in_object],
        physicsClientId=client,
    )
    pb.changeDynamics(body, -1, lateralFriction=float(friction), restitution=float(restitution),
                      physicsClientId=client)
    return body


def body_world_from_object(client: int, body: int, com_in_object: Sequence[float]) -> np.ndarray:
    """(4, 4) world_from_object of a body made by :func:`add_rigid_body`."""
    pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    rot = matrix_from_quat_xyzw(quat)
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = np.asarray(pos) - rot @ np.asarray(com_in_object, dtype=float)
    return out


def set_body_pose(client: int, body: int, world_from_object: np.ndarray,
                  com_in_object: Sequence[float]) -> None:
    """Teleport a body (velocity zeroed) so that its object frame is ``world_from_object``."""
    pose = np.asarray(world_from_object, dtype=float)
    com_world = pose[:3, :3] @ np.asarray(com_in_object, dtype=float) + pose[:3, 3]
    pb.resetBasePositionAndOrientation(body, list(com_world), quat_xyzw_from_matrix(pose[:3, :3]),
                                       physicsClientId=client)
    pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=client)
