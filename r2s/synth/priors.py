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

from r2s.metrics.proximity import surface_distances_to


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


# ---- prior_model=single_image -------------------------------------------------------------
SINGLE_IMAGE_PROPORTION_ERROR = 0.15
"""Largest per-axis scale error of a single-image prior (proportions off by up to 15 %)."""
MAX_DEFORMATION = 0.8
"""Largest deformation amount (the weights of taper, bend and bulge have unit norm)."""
SINGLE_IMAGE_CHAMFER_MM = (10.0, 20.0)
"""Range of the target Chamfer distance (symmetric, mm) of a single-image prior to truth."""


@dataclass(frozen=True)
class SingleImagePriorError:
    """How a single-image prior differs from the truth (gt/ only): ``scale`` (3,) per
    object axis, ``deformation`` amplitude (see :func:`_deform`), ``chamfer_mm`` reached
    and ``target_chamfer_mm`` aimed at, ``smoothing_iterations``, ``faces``."""

    scale: tuple[float, float, float]
    deformation: float
    chamfer_mm: float
    target_chamfer_mm: float
    smoothing_iterations: int
    faces: int


def _chamfer_mm(mesh_a: trimesh.Trimesh, samples_a: np.ndarray, mesh_b: trimesh.Trimesh,
                samples_b: np.ndarray) -> float:
    """Symmetric Chamfer distance (the mean of the two one-sided mean point-to-surface
    distances, as r2s.metrics.geometry defines it), mm, from surface samples of each mesh."""
    return 500.0 * (float(np.mean(surface_distances_to(mesh_b, samples_a)))
                    + float(np.mean(surface_distances_to(mesh_a, samples_b))))


def _deform(unit: np.ndarray, coeffs: np.ndarray, amount: float) -> np.ndarray:
    """Low-frequency shape change of points in [-1, 1]^3 (bounding-box coordinates): taper,
    bend and bulge along each axis, weights ``coeffs`` (9,), scaled by ``amount``. Taper and
    bulge scale a cross-section by a positive factor (exp), so the surface never folds."""
    x = unit.copy()
    out = unit.copy()
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        t, bend, bulge = coeffs[3 * axis: 3 * axis + 3] * amount
        out[:, a] = out[:, a] * np.exp(t * x[:, axis]) + bend * (x[:, axis] ** 2 - 1.0 / 3.0)
        out[:, b] = out[:, b] * np.exp(bulge * (1.0 - x[:, axis] ** 2))
    return out


def make_single_image_prior(mesh: trimesh.Trimesh, rng: np.random.Generator,
                            proportion_error: float = SINGLE_IMAGE_PROPORTION_ERROR,
                            chamfer_mm: tuple[float, float] = SINGLE_IMAGE_CHAMFER_MM,
                            faces: int = 1500, samples: int = 2000
                            ) -> tuple[trimesh.Trimesh, SingleImagePriorError]:
    """The shape a single-image 3D model would give: detail smoothed away (Taubin
    smoothing), proportions off by up to ``proportion_error`` per axis, and a smooth
    low-frequency deformation (taper, bend, bulge, up to :data:`MAX_DEFORMATION`) whose
    size is searched so that the Chamfer distance to ``mesh`` reaches a target drawn from
    ``chamfer_mm``.

    The bounding box of the result is the truth's scaled by ``scale`` per axis about the
    truth's box centre, exactly. Where the proportions alone already exceed the target,
    they are shrunk towards 1 instead; where the largest deformation cannot reach it (an
    object of less than about 20 cm: the cap keeps the shape recognisable), the Chamfer
    reached is recorded.
    """
    base = mesh
    while len(base.faces) < faces // 2:
        verts, tris = trimesh.remesh.subdivide(base.vertices, base.faces)
        base = trimesh.Trimesh(verts, tris, process=False)
    smooth = _decimate(base, faces)
    iterations = int(rng.integers(10, 25))
    trimesh.smoothing.filter_taubin(smooth, lamb=0.5, nu=0.53, iterations=iterations)
    smooth_v = np.asarray(smooth.vertices)
    lo, hi = smooth_v.min(axis=0), smooth_v.max(axis=0)
    unit = 2.0 * (smooth_v - (lo + hi) / 2) / np.maximum(hi - lo, 1e-9)
    centre = mesh.bounds.mean(axis=0)
    extents = np.asarray(mesh.extents)
    signs = rng.choice([-1.0, 1.0], size=3)
    errors = signs * rng.uniform(proportion_error / 3.0, proportion_error, size=3)
    coeffs = rng.normal(size=9)
    coeffs /= np.linalg.norm(coeffs)
    target = float(rng.uniform(*chamfer_mm))
    truth_pts = np.asarray(trimesh.sample.sample_surface(mesh, samples, seed=rng)[0])
    bary_seed = int(rng.integers(2 ** 31))

    def build(alpha: float, amount: float) -> tuple[trimesh.Trimesh, np.ndarray]:
        shaped = _deform(unit, coeffs, amount)
        lo_s, hi_s = shaped.min(axis=0), shaped.max(axis=0)
        shaped = 2.0 * (shaped - (lo_s + hi_s) / 2) / np.maximum(hi_s - lo_s, 1e-9)
        scale = 1.0 + alpha * errors
        verts = shaped * (extents * scale / 2.0) + centre
        return trimesh.Trimesh(verts, smooth.faces, process=False), scale

    def chamfer(candidate: trimesh.Trimesh) -> float:
        pts = trimesh.sample.sample_surface(candidate, samples,
                                            seed=np.random.default_rng(bary_seed))[0]
        return _chamfer_mm(candidate, np.asarray(pts), mesh, truth_pts)

    def search(f, lo_v: float, hi_v: float) -> float:
        for _ in range(10):
            mid = 0.5 * (lo_v + hi_v)
            lo_v, hi_v = (mid, hi_v) if f(mid) < target else (lo_v, mid)
        return 0.5 * (lo_v + hi_v)

    alpha, amount = 1.0, 0.0
    if chamfer(build(1.0, 0.0)[0]) > target:
        alpha = search(lambda a: chamfer(build(a, 0.0)[0]), 0.0, 1.0)
    elif chamfer(build(1.0, MAX_DEFORMATION)[0]) <= target:
        amount = MAX_DEFORMATION
    else:
        amount = search(lambda e: chamfer(build(1.0, e)[0]), 0.0, MAX_DEFORMATION)
    prior, scale = build(alpha, amount)
    reached = chamfer(prior)
    return prior, SingleImagePriorError(
        scale=tuple(float(s) for s in scale), deformation=float(amount),
        chamfer_mm=float(reached), target_chamfer_mm=target,
        smoothing_iterations=iterations, faces=int(len(prior.faces)))
