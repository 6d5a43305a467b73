"""Instances that are the table, the floor or a wall: a segmenter's mask of the background.

Conventions: masks (H, W) instance ids, 0 = background (SCENE_FORMAT.md); depth in metres
along the camera z axis; world frame as ``world_from_camera`` declares it.

Panoptic and "segment everything" networks give the table (or the floor, or a wall) a mask
of its own. Taken as an object, it would be completed as a slab, and the support plane
would be fitted to the few pixels left between the masks. An instance is taken as
background when all of these hold:

- it covers at least :data:`MIN_AREA_FRACTION` of the image;
- it runs off at least :data:`MIN_BORDERS` of the image's four sides (a table or floor
  continues past the picture; a tray or a book on the table is seen whole);
- at least :data:`PLANAR_FRACTION` of its points lie within :data:`PLANAR_TOLERANCE_M` of
  one plane;
- every other instance stands on the camera's side of that plane (the median over them of
  their lowest points, the 5th percentile of each one's heights, is not below it by more
  than the tolerance): the other objects are on it or in front of it, not beside and
  below it, as they would be around the top of a big box.

No test of its orientation: a wall segmented as an instance is background too, and a
declared pose that is wrong (:mod:`r2s.geometry.declared_level`) must not hide the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from r2s.geometry.camera import backproject, instance_points
from r2s.geometry.plane import fit_plane_ransac, standing_gap_m

MIN_AREA_FRACTION = 0.2
MIN_BORDERS = 2
BORDER_SHARE = 0.05
"""A side counts as run off when the mask holds at least this share of its pixels."""
PLANAR_FRACTION = 0.9
PLANAR_TOLERANCE_M = 0.01
MAX_POINTS = 20000


@dataclass(frozen=True)
class BackgroundInstance:
    """An instance taken as background: its id, the share of the image it covers, how many
    sides of the image it runs off, and the share of its points on its plane."""

    id: int
    area_fraction: float
    borders: int
    planar_fraction: float

    def note(self) -> str:
        """The warning line."""
        return (f"masks.png: instance {self.id} covers {100 * self.area_fraction:.0f} % of the "
                f"image, runs off {self.borders} of its sides and is a plane "
                f"({100 * self.planar_fraction:.0f} % of its points within "
                f"{1000 * PLANAR_TOLERANCE_M:.0f} mm) that the other objects stand on or in "
                "front of: taken as the table, floor or wall (background), not reconstructed")


def _borders_run_off(mask: np.ndarray) -> int:
    sides = (mask[0, :], mask[-1, :], mask[:, 0], mask[:, -1])
    return sum(int(np.mean(side) >= BORDER_SHARE) for side in sides)


def background_instances(masks: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
                         world_from_camera: np.ndarray, ids: list[int], seed: int = 0
                         ) -> list[BackgroundInstance]:
    """The instances among ``ids`` that are background (module docstring)."""
    masks = np.asarray(masks)
    total = masks.size
    rng = np.random.default_rng(seed)
    found = []
    points_of: dict[int, np.ndarray] | None = None
    for obj_id in ids:
        mask = masks == obj_id
        area = float(mask.sum()) / total
        if area < MIN_AREA_FRACTION:
            continue
        borders = _borders_run_off(mask)
        if borders < MIN_BORDERS:
            continue
        pts = backproject(depth_m, K, world_from_camera, mask)
        if len(pts) < 100:
            continue
        if len(pts) > MAX_POINTS:
            pts = pts[rng.choice(len(pts), size=MAX_POINTS, replace=False)]
        try:
            plane = fit_plane_ransac(pts, threshold_m=PLANAR_TOLERANCE_M, iterations=200,
                                     seed=seed, viewpoint=np.asarray(world_from_camera)[:3, 3])
        except ValueError:
            continue
        planar = float(plane.inliers.mean())
        if planar < PLANAR_FRACTION:
            continue
        if points_of is None:  # every instance's points, once, all of them
            points_of = dict(zip(ids, instance_points(depth_m, K, world_from_camera, masks,
                                                      ids, rng, masks.size)))
        others = [points_of[other] for other in ids if other != obj_id]
        # the median over the others of their lowest points (5th percentile of heights)
        gap = standing_gap_m(plane, others, point_percentile=5.0, object_quantile=0.5)
        if not gap >= -PLANAR_TOLERANCE_M:  # NaN (no other points) fails too
            continue
        found.append(BackgroundInstance(obj_id, area, borders, planar))
    return found
