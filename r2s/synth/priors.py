"""Imperfect shape priors, as a single-image 3D model would give them.

The prior of an object is its true mesh with the wrong detail: decimated, smoothed (the
fine relief and sharp edges are gone), scaled by a few percent per axis about its
bounding-box centre, with smooth low-amplitude surface waves. It is expressed in the true
object frame, so that ``world_from_object`` registers it perfectly; the pose handed to
r2s (``world_from_prior``) is the true pose turned by 10-20 degrees about the prior's
centroid and shifted by 1-4 cm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class PriorError:
    """How a prior's shape differs from the truth (recorded in gt/ only).

    ``scale`` (3,) per object axis; ``surface_noise_m`` amplitude of the surface waves;
    ``faces`` of the prior mesh.
    """

    scale: tuple[float, float, float]
    surface_noise_m: float
    faces: int


def _decimate(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    if len(mesh.faces) <= faces:
        return mesh.copy()
    import open3d as o3d

    o3d_mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices)),
                                         o3d.utility.Vector3iVector(np.asarray(mesh.faces)))
    o3d_mesh = o3d_mesh.simplify_quadric_decimation(int(faces))
    out = trimesh.Trimesh(np.asarray(o3d_mesh.vertices), np.asarray(o3d_mesh.triangles),
                          process=False)
    out.merge_vertices()
    out.update_faces(out.nondegenerate_faces())
    out.remove_unreferenced_vertices()
    return out


def _surface_waves(points: np.ndarray, rng: np.random.Generator, amplitude_m: float
                   ) -> np.ndarray:
    """(N,) smooth displacement field: a few random plane waves of 3-8 cm wavelength."""
    out = np.zeros(len(points))
    waves = 4
    for _ in range(waves):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        k = 2 * np.pi / rng.uniform(0.03, 0.08)
        out += np.sin(k * points @ direction + rng.uniform(0, 2 * np.pi))
    return amplitude_m * out * (2.0 / waves)  # |field| <= 2 * amplitude, typically ~amplitude


def make_prior_mesh(mesh: trimesh.Trimesh, rng: np.random.Generator,
                    scale_error: float = 0.04, surface_noise_m: float = 0.0015,
                    faces: int = 1500) -> tuple[trimesh.Trimesh, PriorError]:
    """A plausible-but-wrong copy of ``mesh`` in the same object frame.

    Parameters
    ----------
    mesh : true closed mesh (object frame, metres).
    scale_error : per-axis scale factors (about the bounding-box centre, after undoing the
        shrinking of the smoothing) are drawn from 1 +- U(scale_error / 4, scale_error).
    surface_noise_m : largest amplitude of the smooth normal displacement (at most 1.5 % of
        the smallest extent is used).
    faces : target face count of the decimation.
    """
    base = mesh
    while len(base.faces) < faces // 2:  # a low-poly box would not deform smoothly
        verts, tris = trimesh.remesh.subdivide(base.vertices, base.faces)
        base = trimesh.Trimesh(verts, tris, process=False)
    prior = _decimate(base, faces)
    trimesh.smoothing.filter_humphrey(prior, alpha=0.1, beta=0.5,
                                      iterations=int(rng.integers(3, 7)))
    # smoothing moves the bounding box a little: put it back on the truth's, then mis-scale
    centre = mesh.bounds.mean(axis=0)
    restore = mesh.extents / np.maximum(prior.extents, 1e-9)
    signs = rng.choice([-1.0, 1.0], size=3)
    scale = 1.0 + signs * rng.uniform(scale_error / 4, scale_error, size=3)
    verts = (np.asarray(prior.vertices) - prior.bounds.mean(axis=0)) * restore * scale + centre
    prior = trimesh.Trimesh(verts, prior.faces, process=False)
    amplitude = min(surface_noise_m, 0.015 * float(mesh.extents.min())) * rng.uniform(0.5, 1.0)
    disp = _surface_waves(verts, rng, amplitude) + rng.normal(0.0, 0.15 * amplitude, len(verts))
    prior = trimesh.Trimesh(verts + prior.vertex_normals * disp[:, None], prior.faces,
                            process=False)
    return prior, PriorError(scale=tuple(float(s) for s in scale),
                             surface_noise_m=float(amplitude), faces=int(len(prior.faces)))


def perturb_pose(world_from_object: np.ndarray, centre_in_object: np.ndarray,
                 rng: np.random.Generator, rotation_deg: tuple[float, float] = (10.0, 20.0),
                 translation_m: tuple[float, float] = (0.01, 0.04)
                 ) -> tuple[np.ndarray, float, float]:
    """A coarse world_from_prior: the true pose turned about ``centre_in_object`` and shifted.

    Returns
    -------
    (4, 4) world_from_prior, the rotation error in degrees, the translation error in metres
    (of the centre).
    """
    angle = float(rng.uniform(*rotation_deg))
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    shift = float(rng.uniform(*translation_m))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_rotvec(np.radians(angle) * axis).as_matrix()
    about = np.eye(4)
    about[:3, 3] = centre_in_object
    back = np.eye(4)
    back[:3, 3] = -np.asarray(centre_in_object)
    move = np.eye(4)
    move[:3, 3] = shift * direction
    return move @ world_from_object @ about @ turn @ back, angle, shift
