"""Observation consistency: does the reconstruction look like what the camera saw?

Measured for any scene with an input view, with or without ``gt/``:

* **UCD** (unilateral Chamfer distance, mm): mean distance from the observed points of an
  object (its mask pixels with valid depth, back-projected with the camera) to its
  world-frame visual mesh; given the support plane, also the same mean over the points
  more than ``SUPPORT_LEVEL_M`` above it, and the share of points at or below that level.
  A mask that takes in the table around or behind its object (bleed, a shadow) counts
  those table points at their distance, which at a low camera can be 0.1-0.3 m behind
  the object: the split tells the mask's share of a high UCD from the shape's;
* **silhouette IoU**: the z-buffered render of all objects at once (so an object hidden
  behind another in the reconstruction loses those pixels, as it did in the image) against
  the input masks, per object and pooled over all object pixels
  (``sum |R_i & M_i| / sum |R_i | M_i|``);
* **free-space violation**: pixels farther than ``band_px`` from the object's own mask where
  the rendered object lies at least ``margin_m`` in front of a valid observed depth (space
  the camera saw empty), divided by the object's mask area;
* **displacement** of each object from its init pose: how far the object's mesh centroid
  moved (m) and the angle of the relative rotation (deg).

Everything is a pure function on arrays (pixel ``(u, v)`` = column, row; depth along the
camera z axis; NaN = no reading), except :func:`render_objects`, which ray-casts the meshes
(:func:`r2s.render.gbuffer.rasterize`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Optional, Sequence

import numpy as np
import open3d as o3d
from PIL import Image, ImageDraw
from scipy import ndimage
import trimesh

from r2s.geometry.camera import backproject
from r2s.geometry.point_cleanup import PLANE_BAND_M
from r2s.render.gbuffer import rasterize

FREE_SPACE_BAND_PX = 2.0
"""Pixels within this distance of the object's own mask never count as violations."""
FREE_SPACE_MARGIN_M = 0.015
"""A rendered surface must be at least this far in front of the observed depth."""
SUPPORT_LEVEL_M = PLANE_BAND_M
"""An observed point at most this high above the support plane is at the table's level:
the band r2s/geometry/point_cleanup.py drops from completions (6 mm)."""
LARGE_MASK_PX = 1000
"""The worst-object IoU of a scene is taken over objects with at least this many mask px."""
SEEN_MOVE_M = 0.002
SEEN_TURN_DEG = 2.0
"""An object that moved less than this (and turned less than ``SEEN_TURN_DEG``) from its
init pose is not rendered back there for ``iou_seen``: its own move cost it nothing."""
PICTURE_PALETTE = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (148, 103, 189),
                   (140, 86, 75), (227, 119, 194), (188, 189, 34), (23, 190, 207),
                   (127, 127, 127), (255, 255, 255))
"""Object colours of :func:`observation_picture` (``id % 10``): no red, which marks violations."""


def picture_colour(obj_id: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of an object in :func:`observation_picture`."""
    r, g, b = PICTURE_PALETTE[int(obj_id) % len(PICTURE_PALETTE)]
    return r / 255.0, g / 255.0, b / 255.0


@dataclass(frozen=True)
class RenderedObjects:
    """A z-buffered render of a list of objects.

    ids : (H, W) int64 instance id seen at each pixel, 0 = none.
    depth_m : (H, W) float64 camera-z depth of the seen surface, NaN = none.
    """

    ids: np.ndarray
    depth_m: np.ndarray


def render_objects(meshes_world: Sequence, ids: Sequence[int], K: np.ndarray,
                   world_from_camera: np.ndarray, width: int, height: int) -> RenderedObjects:
    """Z-buffered id and depth render of world-frame meshes (``vertices``, ``faces``)."""
    g = rasterize(list(meshes_world), K, world_from_camera, width, height)
    lookup = np.asarray([0] + [int(i) for i in ids], dtype=np.int64)
    return RenderedObjects(ids=lookup[g.object_index + 1], depth_m=g.depth_m.astype(np.float64))


def instance_ids(masks: np.ndarray) -> list[int]:
    """The instance ids present in an (H, W) int mask image (0 = none), ascending."""
    return [int(i) for i in np.unique(masks) if i > 0]


def silhouette_iou(rendered_ids: np.ndarray, masks: np.ndarray, ids: Sequence[int]
                   ) -> tuple[dict[int, Optional[float]], Optional[float]]:
    """Per-object and pooled IoU of rendered silhouettes against instance masks.

    Parameters
    ----------
    rendered_ids, masks : (H, W) int instance ids, 0 = none.
    ids : the objects to score.

    Returns
    -------
    per_object : id -> IoU (None when the object is neither rendered nor in the mask).
    pooled : ``sum_i |R_i & M_i| / sum_i |R_i | M_i|`` over ``ids`` (None when all empty).
    """
    per: dict[int, Optional[float]] = {}
    inter_sum = union_sum = 0
    for i in ids:
        r, m = rendered_ids == i, masks == i
        inter, union = int((r & m).sum()), int((r | m).sum())
        per[int(i)] = inter / union if union else None
        inter_sum += inter
        union_sum += union
    return per, (inter_sum / union_sum if union_sum else None)


def free_space_map(rendered: RenderedObjects, observed_depth_m: np.ndarray, masks: np.ndarray,
                   obj_id: int, band_px: float = FREE_SPACE_BAND_PX,
                   margin_m: float = FREE_SPACE_MARGIN_M) -> np.ndarray:
    """(H, W) bool: where object ``obj_id`` is rendered in space the camera saw empty.

    A pixel violates when the render shows ``obj_id`` there, the pixel is farther than
    ``band_px`` from every pixel of the object's own mask, the observed depth is valid and
    the rendered surface is at least ``margin_m`` in front of it.
    """
    own = masks == obj_id
    shown = rendered.ids == obj_id
    if not shown.any():
        return np.zeros_like(shown)
    if own.any():
        outside = ndimage.distance_transform_edt(~own) > band_px
    else:
        outside = np.ones_like(own)
    obs = np.asarray(observed_depth_m, dtype=np.float64)
    valid = np.isfinite(obs) & (obs > 0)
    with np.errstate(invalid="ignore"):
        in_front = rendered.depth_m <= np.where(valid, obs, np.inf) - margin_m
    return shown & outside & valid & in_front


def unilateral_chamfer_m(points_world: np.ndarray, mesh_world) -> Optional[float]:
    """Mean distance (m) from (N, 3) points to the surface of a world-frame mesh; None if N = 0."""
    pts = np.asarray(points_world, dtype=np.float32).reshape(-1, 3)
    faces = np.asarray(mesh_world.faces)
    if len(pts) == 0 or len(faces) == 0:
        return None
    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(mesh_world.vertices, np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(faces, np.int32))
    scene.add_triangles(tm)
    d = scene.compute_distance(o3d.core.Tensor(np.ascontiguousarray(pts))).numpy()
    return float(np.mean(d))


def pose_displacement(init_world_from_object: np.ndarray, world_from_object: np.ndarray,
                      centre_in_object: np.ndarray) -> tuple[float, float]:
    """(metres the object-frame point ``centre_in_object`` moved, relative rotation in deg)."""
    a = np.asarray(init_world_from_object, dtype=np.float64)
    b = np.asarray(world_from_object, dtype=np.float64)
    c = np.asarray(centre_in_object, dtype=np.float64)
    moved = np.linalg.norm((b[:3, :3] @ c + b[:3, 3]) - (a[:3, :3] @ c + a[:3, 3]))
    rel = b[:3, :3] @ a[:3, :3].T
    cos = np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0)
    return float(moved), float(np.degrees(np.arccos(cos)))


@dataclass
class ObjectObservation:
    """Observation consistency of one object (None where it cannot be measured)."""

    id: int
    mask_px: int
    rendered_px: int
    observed_points: int
    iou: Optional[float]
    ucd_mm: Optional[float]
    free_space_px: int
    free_space_violation: Optional[float]
    """free-space pixels / mask pixels (None for an empty mask)."""
    displacement_m: Optional[float] = None
    displacement_deg: Optional[float] = None
    iou_seen: Optional[float] = None
    """The silhouette IoU the object has when it alone is moved back to its init pose
    (where it was seen), every other object where it is now: against ``iou``, what its own
    move cost it, not what a neighbour moved in front of it hides (None without an init
    pose; ``iou`` itself when it moved less than ``SEEN_MOVE_M`` and ``SEEN_TURN_DEG``)."""
    missing: bool = False
    """True for an instance of the masks that the reconstruction has no object for: it
    counts as IoU 0 in the pooled and the worst IoU (nothing was rendered there)."""
    ucd_above_support_mm: Optional[float] = None
    """UCD over the observed points more than ``SUPPORT_LEVEL_M`` above the support plane
    (None without a plane or without such points)."""
    support_level_share: Optional[float] = None
    """Share of the observed points at most ``SUPPORT_LEVEL_M`` above the support plane
    (None without a plane or points): the table the mask took in."""


@dataclass
class SceneObservation:
    """Per-object metrics and the scene summary (see :func:`scene_summary`)."""

    objects: list[ObjectObservation]
    pooled_iou: Optional[float]
    violation_map: np.ndarray = field(repr=False)
    """(H, W) bool, union of every object's free-space violations."""
    rendered: RenderedObjects = field(repr=False)

    def summary(self) -> dict:
        """Scene-level numbers: pooled IoU, worst IoU over objects with >= LARGE_MASK_PX mask
        pixels (a missing object's is 0), mean free-space violation, mean UCD, largest
        displacement, and how many instances of the masks have no object."""
        def mean(vals: list) -> Optional[float]:
            vals = [v for v in vals if v is not None]
            return float(np.mean(vals)) if vals else None

        large = [o.iou if o.iou is not None else 0.0 for o in self.objects
                 if o.mask_px >= LARGE_MASK_PX]
        disp = [o.displacement_m for o in self.objects if o.displacement_m is not None]
        rot = [o.displacement_deg for o in self.objects if o.displacement_deg is not None]
        return {
            "silhouette_iou": self.pooled_iou,
            "min_silhouette_iou": float(min(large)) if large else None,
            "free_space_violation": mean([o.free_space_violation for o in self.objects]),
            "max_free_space_violation": max((o.free_space_violation for o in self.objects
                                             if o.free_space_violation is not None), default=None),
            "ucd_mm": mean([o.ucd_mm for o in self.objects]),
            "ucd_above_support_mm": mean([o.ucd_above_support_mm for o in self.objects]),
            "max_displacement_m": max(disp) if disp else None,
            "max_displacement_deg": max(rot) if rot else None,
            "missing_objects": len(self.missing_ids),
        }

    @property
    def missing_ids(self) -> list[int]:
        """Instances of the masks the reconstruction has no object for."""
        return [o.id for o in self.objects if o.missing]

    def object_dicts(self) -> list[dict]:
        return [asdict(o) for o in self.objects]


def observe_scene(meshes_world: Sequence, ids: Sequence[int], K: np.ndarray,
                  world_from_camera: np.ndarray, depth_m: np.ndarray, masks: np.ndarray,
                  init_world_from_object: Optional[dict[int, np.ndarray]] = None,
                  world_from_object: Optional[dict[int, np.ndarray]] = None,
                  centres_in_object: Optional[dict[int, np.ndarray]] = None,
                  band_px: float = FREE_SPACE_BAND_PX, margin_m: float = FREE_SPACE_MARGIN_M,
                  mask_ids: Optional[Sequence[int]] = None,
                  support: Optional[tuple[np.ndarray, np.ndarray]] = None) -> SceneObservation:
    """All observation metrics of world-frame meshes against one RGB-D view.

    Parameters
    ----------
    meshes_world : per object, its visual mesh in the world frame; ids : (M,) their ids.
    K : (3, 3); world_from_camera : (4, 4) OpenCV camera.
    depth_m : (H, W) observed depth, NaN = no reading; masks : (H, W) int ids, 0 = none.
    init_world_from_object, world_from_object, centres_in_object : per id, the init pose,
        the current pose (4, 4) and the object-frame point whose motion is the
        displacement (e.g. the mesh centroid); displacement is None for ids missing there.
    mask_ids : the instances the view shows (default: ``ids``). Those without a mesh are
        appended to the objects as ``missing`` (IoU 0, nothing rendered) and count in the
        pooled IoU with their whole mask: an object the reconstruction lost is a miss, not
        a blank in the score.
    support : (point (3,), upward normal (3,)) of the support plane, world frame, for the UCD
        split by height (``ucd_above_support_mm``, ``support_level_share``); None: no split.
    """
    height, width = masks.shape
    rendered = render_objects(meshes_world, ids, K, world_from_camera, width, height)
    lost = [int(i) for i in (mask_ids if mask_ids is not None else ()) if int(i) not in
            {int(j) for j in ids}]
    per_iou, pooled = silhouette_iou(rendered.ids, masks, [*ids, *lost])
    violation = np.zeros(masks.shape, dtype=bool)
    objects = []
    for k, (mesh, i) in enumerate(zip(meshes_world, ids)):
        own = masks == i
        mask_px = int(own.sum())
        pts = backproject(depth_m, K, world_from_camera, mask=own)
        ucd = unilateral_chamfer_m(pts, mesh)
        above_mm, share = _ucd_above_support(pts, mesh, support)
        fs = free_space_map(rendered, depth_m, masks, i, band_px, margin_m)
        violation |= fs
        disp = (None, None)
        if (init_world_from_object is not None and world_from_object is not None
                and centres_in_object is not None and i in init_world_from_object
                and i in world_from_object and i in centres_in_object):
            disp = pose_displacement(init_world_from_object[i], world_from_object[i],
                                     centres_in_object[i])
        iou_seen = None
        if disp[0] is not None:
            iou_seen = per_iou[int(i)]  # it did not move: its own move cost it nothing
            if disp[0] > SEEN_MOVE_M or disp[1] > SEEN_TURN_DEG:
                iou_seen = _iou_back_where_seen(meshes_world, ids, k, init_world_from_object[i],
                                                world_from_object[i], K, world_from_camera,
                                                masks)
        objects.append(ObjectObservation(
            id=int(i), mask_px=mask_px, rendered_px=int((rendered.ids == i).sum()),
            observed_points=int(len(pts)), iou=per_iou[int(i)],
            ucd_mm=None if ucd is None else 1000.0 * ucd,
            free_space_px=int(fs.sum()),
            free_space_violation=float(fs.sum()) / mask_px if mask_px else None,
            displacement_m=disp[0], displacement_deg=disp[1],
            iou_seen=iou_seen, ucd_above_support_mm=above_mm, support_level_share=share))
    for i in lost:
        mask_px = int((masks == i).sum())
        objects.append(ObjectObservation(
            id=i, mask_px=mask_px, rendered_px=0, observed_points=0, iou=0.0, ucd_mm=None,
            free_space_px=0, free_space_violation=None, missing=True))
    return SceneObservation(objects=objects, pooled_iou=pooled, violation_map=violation,
                            rendered=rendered)


def _ucd_above_support(points_world: np.ndarray, mesh,
                       support: Optional[tuple[np.ndarray, np.ndarray]]
                       ) -> tuple[Optional[float], Optional[float]]:
    """(UCD in mm over the points more than ``SUPPORT_LEVEL_M`` above the support plane,
    share of the points at most that high); (None, None) without a plane or points."""
    if support is None or len(points_world) == 0:
        return None, None
    normal = np.asarray(support[1], dtype=np.float64)
    height = (points_world - np.asarray(support[0], dtype=np.float64)) @ (
        normal / np.linalg.norm(normal))
    low = height <= SUPPORT_LEVEL_M
    ucd = unilateral_chamfer_m(points_world[~low], mesh) if (~low).any() else None
    return (None if ucd is None else 1000.0 * ucd), float(low.mean())


def _iou_back_where_seen(meshes_world: Sequence, ids: Sequence[int], k: int,
                         init_world_from_object: np.ndarray, world_from_object: np.ndarray,
                         K: np.ndarray, world_from_camera: np.ndarray,
                         masks: np.ndarray) -> Optional[float]:
    """Silhouette IoU of object ``k`` (index into ``meshes_world``/``ids``) moved back to
    its init pose (``init @ inv(current)`` applied to its world-frame mesh), every other
    object rendered where it is now: what the object's own move cost it."""
    to_seen = np.asarray(init_world_from_object, dtype=float) @ np.linalg.inv(
        np.asarray(world_from_object, dtype=float))
    mesh = meshes_world[k]
    back = list(meshes_world)
    back[k] = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).apply_transform(to_seen)
    height, width = masks.shape
    rendered = render_objects(back, ids, K, world_from_camera, width, height)
    per_iou, _ = silhouette_iou(rendered.ids, masks, [int(ids[k])])
    return per_iou[int(ids[k])]


def observation_picture(rgb: np.ndarray, rendered_ids: np.ndarray, violation: np.ndarray,
                        masks: np.ndarray, colours: dict[int, tuple[float, float, float]],
                        caption: str = "") -> np.ndarray:
    """(H + 18, W, 3) uint8: the rendered silhouettes over the (dimmed) image.

    Each object's render is tinted with its colour (``colours``: id -> RGB in [0, 1]), its
    input mask outlined in the same colour, free-space violations painted red, and each id
    written at the centre of its mask (or of its render when the mask is empty).
    """
    img = np.asarray(rgb, dtype=np.float64) * 0.6
    for i, colour in colours.items():
        c = np.asarray(colour[:3], dtype=np.float64) * 255.0
        shown = rendered_ids == i
        img[shown] = 0.45 * img[shown] + 0.55 * c
        own = masks == i
        outline = own & ~ndimage.binary_erosion(own)
        img[outline] = c
    img[violation] = (255.0, 0.0, 0.0)
    height, width = masks.shape
    canvas = Image.new("RGB", (width, height + 18), (255, 255, 255))
    canvas.paste(Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)), (0, 0))
    draw = ImageDraw.Draw(canvas)
    for i in colours:
        region = masks == i
        if not region.any():
            region = rendered_ids == i
        if not region.any():
            continue
        rows, cols = np.nonzero(region)
        x, y = float(cols.mean()), float(rows.mean())
        text = str(i)
        draw.rectangle([x - 3, y - 6, x + 7 * len(text) + 2, y + 7], fill=(0, 0, 0))
        draw.text((x, y - 5), text, fill=(255, 255, 255))
    draw.text((4, height + 3), caption, fill=(0, 0, 0))
    return np.asarray(canvas)
