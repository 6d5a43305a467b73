"""Geometry accuracy of a reconstructed object against its ground truth.

Every function takes trimesh meshes already posed in the WORLD frame (use :func:`posed`).

- Chamfer distance (mm): ``(mean d(recon -> gt) + mean d(gt -> recon)) / 2`` where
  ``d(a -> b)`` is the distance from each of ``n_samples`` area-uniform surface samples of
  ``a`` to the nearest point of the *surface* of ``b`` (exact point-to-triangle distance,
  :mod:`r2s.metrics.proximity`, so there is no sampling floor: a mesh against itself
  reads 0 up to rounding).
- F-score at ``threshold_mm`` (default 10 mm): harmonic mean of precision (share of recon
  samples within the threshold of gt) and recall (share of gt samples within it of recon).
- Volumetric IoU: ``n_samples`` points uniform in the union of the two bounding boxes,
  classified inside/outside each mesh by :func:`r2s.metrics.occupancy.contains`; meant
  for closed meshes.
- Pose errors: distance between the area-weighted surface centroids (mm), and the angle of
  ``R_gt^T R_recon`` (deg), which only means something when the recon object frame is the
  gt object frame (an object built on a prior mesh).

All sampling is seeded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from r2s.metrics.occupancy import contains
from r2s.metrics.proximity import surface_distances_to
from r2s.metrics.stability import rotation_angle_deg


def posed(mesh: trimesh.Trimesh, world_from_object: np.ndarray) -> trimesh.Trimesh:
    """A copy of ``mesh`` (object frame) moved into the world by (4, 4) ``world_from_object``."""
    out = mesh.copy()
    out.apply_transform(np.asarray(world_from_object, dtype=np.float64))
    return out


def surface_distances_m(mesh_a: trimesh.Trimesh, mesh_b: trimesh.Trimesh, n_samples: int = 10000,
                        seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n,) distances a-samples -> surface b and (n,) b-samples -> surface a, metres."""
    rng = np.random.default_rng(seed)
    samples_a, _ = trimesh.sample.sample_surface(mesh_a, n_samples, seed=rng)
    samples_b, _ = trimesh.sample.sample_surface(mesh_b, n_samples, seed=rng)
    return surface_distances_to(mesh_b, samples_a), surface_distances_to(mesh_a, samples_b)


@dataclass(frozen=True)
class SurfaceMetrics:
    chamfer_mm: float
    fscore: float
    precision: float
    recall: float
    threshold_mm: float


def surface_metrics_from_distances(d_recon_to_gt_m: np.ndarray, d_gt_to_recon_m: np.ndarray,
                                   threshold_mm: float = 10.0) -> SurfaceMetrics:
    """Chamfer and F-score from the two one-sided distance arrays (metres)."""
    chamfer_mm = 500.0 * (float(np.mean(d_recon_to_gt_m)) + float(np.mean(d_gt_to_recon_m)))
    tau = threshold_mm / 1000.0
    precision = float(np.mean(d_recon_to_gt_m < tau))
    recall = float(np.mean(d_gt_to_recon_m < tau))
    total = precision + recall
    fscore = 2.0 * precision * recall / total if total > 0 else 0.0
    return SurfaceMetrics(chamfer_mm=chamfer_mm, fscore=fscore, precision=precision,
                          recall=recall, threshold_mm=float(threshold_mm))


def surface_metrics(recon: trimesh.Trimesh, gt: trimesh.Trimesh, threshold_mm: float = 10.0,
                    n_samples: int = 10000, seed: int = 0) -> SurfaceMetrics:
    """Chamfer distance and F-score of ``recon`` against ``gt`` (both world frame)."""
    d_rg, d_gr = surface_distances_m(recon, gt, n_samples, seed)
    return surface_metrics_from_distances(d_rg, d_gr, threshold_mm)


def chamfer_distance_mm(mesh_a: trimesh.Trimesh, mesh_b: trimesh.Trimesh, n_samples: int = 10000,
                        seed: int = 0) -> float:
    """Symmetric chamfer distance, millimetres (see the module docstring)."""
    return surface_metrics(mesh_a, mesh_b, 10.0, n_samples, seed).chamfer_mm


def fscore(recon: trimesh.Trimesh, gt: trimesh.Trimesh, threshold_mm: float = 10.0,
           n_samples: int = 10000, seed: int = 0) -> float:
    """F-score in [0, 1] at ``threshold_mm``."""
    return surface_metrics(recon, gt, threshold_mm, n_samples, seed).fscore


def volumetric_iou(mesh_a: trimesh.Trimesh, mesh_b: trimesh.Trimesh, n_samples: int = 10000,
                   seed: int = 0) -> float:
    """Intersection over union of the two solids, estimated by seeded uniform sampling.

    The standard error is about ``sqrt(iou (1 - iou) / (n_samples * f))`` with ``f`` the
    share of the union bounding box the union fills. NaN if no sample is inside either.
    """
    lo = np.minimum(mesh_a.bounds[0], mesh_b.bounds[0])
    hi = np.maximum(mesh_a.bounds[1], mesh_b.bounds[1])
    points = np.random.default_rng(seed).uniform(lo, hi, size=(n_samples, 3))
    in_a, in_b = contains(mesh_a, points), contains(mesh_b, points)
    union = int(np.count_nonzero(in_a | in_b))
    if union == 0:
        return float("nan")
    return float(np.count_nonzero(in_a & in_b)) / union


def centroid_error_mm(recon: trimesh.Trimesh, gt: trimesh.Trimesh) -> float:
    """Distance between the area-weighted surface centroids of two world-frame meshes, mm."""
    return 1000.0 * float(np.linalg.norm(np.asarray(recon.centroid) - np.asarray(gt.centroid)))


def rotation_error_deg(world_from_recon: np.ndarray, world_from_gt: np.ndarray) -> float:
    """Angle of ``R_gt^T R_recon`` in degrees ((4, 4) or (3, 3) inputs)."""
    r_recon = np.asarray(world_from_recon, dtype=np.float64)[:3, :3]
    r_gt = np.asarray(world_from_gt, dtype=np.float64)[:3, :3]
    return float(rotation_angle_deg(r_gt, r_recon))
