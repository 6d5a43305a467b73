"""Render RGB, metric depth and instance segmentation with PyBullet's software renderer.

``ER_TINY_RENDERER`` needs no OpenGL context. Every visual is a textured .obj file placed
by its world_from_object; the returned segmentation holds the index of the visual in the
list (``-1`` for the table and for empty background).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from r2s.sim.ascii_paths import ascii_safe_paths
from r2s.sim.pybullet_bodies import quat_xyzw_from_matrix
from r2s.synth.camera import FAR_M, NEAR_M, depth_from_gl_buffer, gl_projection_matrix, \
    gl_view_matrix


@dataclass(frozen=True)
class Visual:
    """A textured mesh to draw: ``obj_file`` (with texture coordinates), ``texture_file``
    (PNG), ``world_from_object`` (4, 4)."""

    obj_file: Path
    texture_file: Path
    world_from_object: np.ndarray


@dataclass(frozen=True)
class Lighting:
    """PyBullet light: ``direction`` (3,) towards the light, coefficients in [0, 1]."""

    direction: np.ndarray
    ambient: float
    diffuse: float
    specular: float


@dataclass(frozen=True)
class Frame:
    """A rendered view: ``rgb`` (H, W, 3) uint8, ``depth_m`` (H, W) float64 along the
    camera z axis, NaN where nothing is seen, ``segment`` (H, W) int32 index of the
    object visual, -1 elsewhere."""

    rgb: np.ndarray
    depth_m: np.ndarray
    segment: np.ndarray


def _add_visual(client: int, visual: Visual) -> int:
    with ascii_safe_paths([visual.obj_file, visual.texture_file]) as (obj_file, texture_file):
        shape = pb.createVisualShape(pb.GEOM_MESH, fileName=obj_file, physicsClientId=client)
        texture = pb.loadTexture(texture_file, physicsClientId=client)
    pose = np.asarray(visual.world_from_object, dtype=float)
    body = pb.createMultiBody(0.0, -1, shape, basePosition=list(pose[:3, 3]),
                              baseOrientation=quat_xyzw_from_matrix(pose[:3, :3]),
                              physicsClientId=client)
    pb.changeVisualShape(body, -1, textureUniqueId=texture, rgbaColor=[1, 1, 1, 1],
                         specularColor=[0.3, 0.3, 0.3], physicsClientId=client)
    return body


def render(objects: list[Visual], table: Visual, K: np.ndarray, world_from_camera: np.ndarray,
           width: int, height: int, lighting: Lighting,
           background_rgb: tuple[int, int, int] = (205, 208, 212)) -> Frame:
    """Draw the objects and the table from the camera (K from :func:`camera.intrinsics`)."""
    client = pb.connect(pb.DIRECT)
    try:
        body_ids = [_add_visual(client, v) for v in objects]
        _add_visual(client, table)
        out = pb.getCameraImage(
            int(width), int(height),
            viewMatrix=gl_view_matrix(world_from_camera),
            projectionMatrix=gl_projection_matrix(K, width, height, NEAR_M, FAR_M),
            renderer=pb.ER_TINY_RENDERER, shadow=1,
            lightDirection=[float(x) for x in lighting.direction],
            lightAmbientCoeff=float(lighting.ambient), lightDiffuseCoeff=float(lighting.diffuse),
            lightSpecularCoeff=float(lighting.specular),
            physicsClientId=client,
        )
    finally:
        pb.disconnect(client)
    rgba = np.asarray(out[2], dtype=np.uint8).reshape(height, width, 4)
    depth = depth_from_gl_buffer(np.asarray(out[3], dtype=np.float64).reshape(height, width),
                                 NEAR_M, FAR_M)
    raw = np.asarray(out[4], dtype=np.int64).reshape(height, width)
    segment = np.full((height, width), -1, dtype=np.int32)
    for index, body in enumerate(body_ids):
        segment[raw == body] = index
    rgb = rgba[:, :, :3].copy()
    rgb[raw < 0] = background_rgb
    return Frame(rgb=rgb, depth_m=depth, segment=segment)
