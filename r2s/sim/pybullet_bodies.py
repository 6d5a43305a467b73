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

from r2s.sim.ascii_paths import ascii_safe_paths

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


MAX_SHAPE_ARRAY = 16
"""``createCollisionShapeArray`` keeps only the first 16 shapes and drops the rest without a
word; a body with more convex pieces is built from one multi-part OBJ instead."""


_MULTI_PART_TEXT: dict[bytes, str] = {}
"""The multi-part OBJ text of :func:`_multi_part_shape` by the content of its piece files
(physopt builds dozens of worlds from the same pieces; reading them back is slow)."""


def _multi_part_text(files: Sequence[str]) -> str:
    """The pieces of ``files`` as one OBJ text, an ``o`` part each (remembered by content)."""
    import hashlib

    import trimesh

    h = hashlib.sha1()
    for f in files:
        h.update(Path(f).read_bytes())
        h.update(b"\0")
    key = h.digest()
    if key in _MULTI_PART_TEXT:
        return _MULTI_PART_TEXT[key]
    lines, offset = [], 0
    for k, f in enumerate(files):
        piece = trimesh.load(f, force="mesh", process=False)
        lines.append(f"o piece_{k}")
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(piece.vertices)]
        lines += [f"f {a + offset} {b + offset} {c + offset}"
                  for a, b, c in np.asarray(piece.faces) + 1]
        offset += len(piece.vertices)
    if len(_MULTI_PART_TEXT) >= 256:
        _MULTI_PART_TEXT.clear()
    text = _MULTI_PART_TEXT[key] = "\n".join(lines) + "\n"
    return text


def _multi_part_shape(client: int, files: Sequence[str]) -> int:
    """One compound collision shape of all ``files`` (convex pieces, object frame): PyBullet
    makes one convex hull per ``o`` part of an OBJ file, with no limit on their number."""
    import tempfile

    text = _multi_part_text(files)
    with tempfile.TemporaryDirectory(prefix="r2s-pieces-") as tmp:
        path = Path(tmp) / "pieces.obj"
        path.write_text(text)
        return pb.createCollisionShape(pb.GEOM_MESH, fileName=str(path), physicsClientId=client)


def add_rigid_body(client: int, collision_files: Sequence[Path], world_from_object: np.ndarray,
                   mass_kg: float, com_in_object: Sequence[float], friction: float,
                   restitution: float = 0.0) -> int:
    """One dynamic body made of convex mesh pieces (files in the object frame)."""
    files = [str(f) for f in collision_files]
    if len(files) <= MAX_SHAPE_ARRAY:
        with ascii_safe_paths(files) as names:  # PyBullet crashes on non-ASCII file names
            shape = pb.createCollisionShapeArray([pb.GEOM_MESH] * len(names), fileNames=names,
                                                 physicsClientId=client)
    else:  # the pieces are read by trimesh and handed over in one ASCII-named temporary OBJ
        shape = _multi_part_shape(client, files)
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
