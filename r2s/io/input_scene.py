"""Load and validate a scene's ``input/`` folder (SCENE_FORMAT.md).

Every problem raises :class:`r2s.errors.InputError` naming the file and what is wrong.
Nothing here writes anything.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
from PIL import Image
from scipy import ndimage
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator, model_validator

from r2s.errors import InputError
from r2s.io.paths import ScenePaths

MIN_MASK_PIXELS = 20
"""An instance with fewer pixels with valid depth than this is not reconstructed from depth
(a warning; init may build it from its silhouette)."""

TABLE_DEPTH_RANGE_M = (0.05, 10.0)
"""Median depth outside this range is an error: the depth unit is wrong (a tabletop seen
from 5 cm or from tens of metres is not a tabletop scene)."""

TABLE_DEPTH_WARN_M = 3.0
"""Median depth beyond this (and within the range above) gets a warning."""

DEPTH_AGREE_M = 0.002
"""depth.png and depth.npy agree when they differ by less than this (plus one depth unit)
on 99% of the pixels valid in both."""


def _check_matrix(value: list, rows: int, cols: int, name: str) -> list:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (rows, cols):
        raise ValueError(f"{name} must be {rows}x{cols}, got shape {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite entries")
    return value


def _check_rigid(value: list, name: str) -> list:
    arr = np.asarray(_check_matrix(value, 4, 4, name), dtype=float)
    rot = arr[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-3) or np.linalg.det(rot) < 0:
        raise ValueError(f"{name} rotation part is not a proper rotation")
    if not np.allclose(arr[3], [0, 0, 0, 1], atol=1e-6):
        raise ValueError(f"{name} last row must be [0, 0, 0, 1]")
    return value


class CameraFile(BaseModel):
    """``input/camera.json``."""

    model_config = ConfigDict(extra="allow")

    width: int
    height: int
    K: list[list[float]]
    world_from_camera: list[list[float]]
    depth_unit_m: float = 0.001

    @field_validator("width", "height")
    @classmethod
    def _positive(cls, v: int) -> int:
        if v <= 0:
            raise ValueError("must be positive")
        return v

    @field_validator("K")
    @classmethod
    def _k(cls, v: list) -> list:
        _check_matrix(v, 3, 3, "K")
        k = np.asarray(v)
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise ValueError("K focal lengths must be positive")
        return v

    @field_validator("world_from_camera")
    @classmethod
    def _pose(cls, v: list) -> list:
        return _check_rigid(v, "world_from_camera")

    @field_validator("depth_unit_m")
    @classmethod
    def _unit(cls, v: float) -> float:
        if not (v > 0 and np.isfinite(v)):
            raise ValueError("depth_unit_m must be positive")
        return v


class ObjectEntry(BaseModel):
    """One entry of ``input/objects.json``."""

    model_config = ConfigDict(extra="allow")

    id: int
    label: Optional[str] = None
    prior_mesh: Optional[str] = None
    world_from_prior: Optional[list[list[float]]] = None
    mass_kg: Optional[float] = None
    density_kg_m3: Optional[float] = None
    friction: Optional[float] = None

    @field_validator("mass_kg", "density_kg_m3", "friction")
    @classmethod
    def _positive(cls, v: Optional[float]) -> Optional[float]:
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError("mass_kg, density_kg_m3 and friction must be positive numbers")
        return v

    @field_validator("id")
    @classmethod
    def _id(cls, v: int) -> int:
        if v <= 0:
            raise ValueError("instance ids must be positive integers")
        return v

    @field_validator("world_from_prior")
    @classmethod
    def _pose(cls, v: Optional[list]) -> Optional[list]:
        return None if v is None else _check_rigid(v, "world_from_prior")


class ObjectsFile(BaseModel):
    """``input/objects.json``."""

    model_config = ConfigDict(extra="allow")

    objects: list[ObjectEntry] = []

    @model_validator(mode="after")
    def _unique(self) -> "ObjectsFile":
        ids = [o.id for o in self.objects]
        if len(ids) != len(set(ids)):
            raise ValueError("duplicate object ids")
        return self


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes
    ----------
    K : (3, 3) float intrinsics, pixels.
    world_from_camera : (4, 4) float, OpenCV camera frame (x right, y down, z forward) to world.
    width, height : image size in pixels.
    """

    K: np.ndarray
    world_from_camera: np.ndarray
    width: int
    height: int


@dataclass(frozen=True)
class ObjectSpec:
    """What ``input/`` says about one instance.

    ``prior_mesh`` is an absolute path or None; ``world_from_prior`` is (4, 4) or None.
    ``declared``: objects.json has an entry for this id (a label, a prior, a mass, ...);
    an id that only appears in masks.png is not declared.
    """

    id: int
    label: str
    prior_mesh: Optional[Path] = None
    world_from_prior: Optional[np.ndarray] = None
    declared: bool = False


@dataclass(frozen=True)
class InputScene:
    """A validated ``input/`` folder.

    Attributes
    ----------
    rgb : (H, W, 3) uint8.
    depth_m : (H, W) float32 metres along the camera z axis; NaN where there is no reading.
    masks : (H, W) int32 instance ids, 0 = no object.
    camera : :class:`Camera`.
    objects : one :class:`ObjectSpec` per instance id present in ``masks``, sorted by id.
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    masks: np.ndarray
    camera: Camera
    objects: list[ObjectSpec] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    skipped_ids: list[int] = field(default_factory=list)
    """Instances in ``masks`` left out (too few pixels with valid depth); named in
    ``warnings``."""
    skipped_objects: list[ObjectSpec] = field(default_factory=list)
    """Their :class:`ObjectSpec` (label, prior) for what can be made of a mask without
    depth (init's silhouette completion)."""
    merged_ids: dict[int, int] = field(default_factory=dict)
    """``{mask id: object id}`` of ids taken as pieces of another object (set by
    ``scene_model.corrected_input``; their pixels carry the object's id in ``masks``)."""
    corrected_from_declared: Optional[np.ndarray] = None
    """(4, 4) the rigid turn of the world that the scene's corrections applied (a kept
    ``camera_rotation``, or a declared pose that tilts the table beyond any real table:
    ``scene_model.levelled``): corrected world from the declared world of camera.json.
    None: the declared world is kept."""

    @property
    def ids(self) -> list[int]:
        return [o.id for o in self.objects]

    def object(self, obj_id: int) -> ObjectSpec:
        for o in self.objects:
            if o.id == obj_id:
                return o
        raise KeyError(obj_id)


INNER_EDGE_PX = 2
"""The mask's outline band: bleed and mixed readings put other surfaces' depth there."""
MIN_INNER_READ = 0.02
"""An instance whose mask has an inside (>= 100 px past its outline band) of which fewer
than this share (and fewer than MIN_MASK_PIXELS pixels) read depth is not reconstructed
from depth: its readings are the segmenter's bleed onto what is around it, and the object
itself (transparent, black, mirror-like) read nothing."""


def _unread_inside(mask: np.ndarray, depth_m: np.ndarray) -> str:
    """Why ``mask``'s own surface read no depth though some of its pixels did, or ""."""
    inner = ndimage.binary_erosion(mask, iterations=INNER_EDGE_PX)
    n = int(inner.sum())
    read = int((inner & np.isfinite(depth_m)).sum())
    if n < 100 or read >= MIN_MASK_PIXELS or read >= MIN_INNER_READ * n:
        return ""
    return (f"read depth on only {read} of the {n} pixels inside its outline (the rest of its "
            "readings are at its edge, where masks bleed): not reconstructed from depth")


def _first_error(exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err.get("loc", ()))
    msg = err.get("msg", "invalid").removeprefix("Value error, ")
    return f"{loc}: {msg}" if loc else msg


def read_json_file(path: Path) -> object:
    """Parse a JSON file or raise :class:`InputError` with the line of the syntax error."""
    if not path.is_file():
        raise InputError(path, "missing file")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(path, f"bad JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except UnicodeDecodeError:
        raise InputError(path, "not a UTF-8 text file") from None


def load_camera(path: Path) -> tuple[Camera, float]:
    """The camera and its ``depth_unit_m``."""
    data = read_json_file(path)
    try:
        cam = CameraFile.model_validate(data)
    except ValidationError as exc:
        raise InputError(path, _first_error(exc)) from None
    return Camera(
        K=np.asarray(cam.K, dtype=np.float64),
        world_from_camera=np.asarray(cam.world_from_camera, dtype=np.float64),
        width=cam.width,
        height=cam.height,
    ), cam.depth_unit_m


def _read_image(path: Path) -> Image.Image:
    if not path.is_file():
        raise InputError(path, "missing file")
    try:
        img = Image.open(path)
        img.load()
    except Exception:  # PIL raises many types for corrupt files
        raise InputError(path, "unreadable image") from None
    return img


PRINCIPAL_POINT_OFF_CENTRE = 0.15
"""A principal point farther than this fraction of the width (or height) from the image
centre is warned about: a camera's lies within a few % of it, unless the image was cropped."""


def check_principal_point(path: Path, camera: Camera) -> list[str]:
    """A warning line when K's principal point is far from the image centre, the mark of a
    K for another image size (a RealSense's 1280 x 720 intrinsics with its 640 x 480
    images, say), which shrinks or stretches every object across the view."""
    cx, cy = float(camera.K[0, 2]), float(camera.K[1, 2])
    mid_x, mid_y = (camera.width - 1) / 2, (camera.height - 1) / 2
    off_x, off_y = abs(cx - mid_x) / camera.width, abs(cy - mid_y) / camera.height
    if max(off_x, off_y) <= PRINCIPAL_POINT_OFF_CENTRE:
        return []
    line = (f"{path}: K's principal point ({cx:.1f}, {cy:.1f}) lies {100 * off_x:.0f} % of the "
            f"width and {100 * off_y:.0f} % of the height from the image centre ({mid_x:.1f}, "
            f"{mid_y:.1f}); a camera's lies within a few %, unless the image was cropped")
    if cx > 0 and cy > 0:
        sx, sy = mid_x / cx, mid_y / cy
        if abs(sx / sy - 1.0) < 0.05:
            scale = (sx + sy) / 2
            line += (f". Is K for another image size? K scaled by {scale:.2f} (K of a "
                     f"{camera.width / scale:.0f} x {camera.height / scale:.0f} image) would "
                     "centre it")
    return [line]


def load_rgb(path: Path, width: int, height: int) -> np.ndarray:
    img = _read_image(path)
    if img.mode not in ("RGB", "RGBA", "L", "P"):
        raise InputError(path, f"expected an 8-bit RGB image, got mode {img.mode}")
    arr = np.asarray(img.convert("RGB"))
    _check_size(path, arr, width, height)
    return arr


def _check_size(path: Path, arr: np.ndarray, width: int, height: int) -> None:
    if arr.shape[:2] != (height, width):
        raise InputError(
            path, f"wrong size {arr.shape[1]}x{arr.shape[0]}, camera.json says {width}x{height}"
        )


def load_depth(paths: ScenePaths, width: int, height: int, depth_unit_m: float) -> np.ndarray:
    """Depth in metres, float32 (H, W), NaN where invalid."""
    return load_depth_file(paths.depth_png, paths.depth_npy, width, height, depth_unit_m)


def load_depth_file(png: Path, npy: Path, width: int, height: int,
                    depth_unit_m: float) -> np.ndarray:
    """(H, W) float32 metres, NaN where invalid, from ``npy`` if it exists, else ``png``."""
    if npy.is_file():
        path = npy
        try:
            arr = np.load(path, allow_pickle=False)
        except Exception:
            raise InputError(path, "unreadable .npy file") from None
        if arr.ndim != 2:
            raise InputError(path, f"expected a 2-D H x W array, got shape {list(arr.shape)}")
        if arr.dtype.kind not in "fiu":
            raise InputError(path, f"expected float32 metres, got dtype {arr.dtype}")
        depth = arr.astype(np.float32)
    elif png.is_file():
        path = png
        img = _read_image(path)
        arr = np.asarray(img)
        if arr.ndim != 2 or arr.dtype not in (np.uint16, np.int32, np.uint8):
            raise InputError(path, f"expected a 16-bit single-channel PNG, got mode {img.mode}")
        if arr.dtype == np.uint8:
            raise InputError(path, "expected a 16-bit single-channel PNG, got an 8-bit one: "
                             f"8 bits hold at most 255 depth units ({255 * depth_unit_m:g} m "
                             "with depth_unit_m in camera.json); a depth visualisation?")
        depth = arr.astype(np.float32) * np.float32(depth_unit_m)
    else:
        raise InputError(png, f"missing file (neither {png.name} nor {npy.name} exists)")
    _check_size(path, depth, width, height)
    depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
    if np.isnan(depth).all():
        raise InputError(path, "no valid depth reading (all zero, NaN or inf)")
    return depth


def check_depth_files(paths: ScenePaths, depth_m: np.ndarray, width: int, height: int,
                      depth_unit_m: float) -> list[str]:
    """When both depth.png and depth.npy exist: depth.npy is the one used; a warning if the
    two agree, :class:`InputError` if they disagree (the scene would silently be built from
    one of two different observations)."""
    if not (paths.depth_png.is_file() and paths.depth_npy.is_file()):
        return []
    png = load_depth_file(paths.depth_png, paths.depth_png.with_suffix(".absent"), width,
                          height, depth_unit_m)
    both = np.isfinite(png) & np.isfinite(depth_m)
    diff = np.abs(png[both] - depth_m[both])
    tol = DEPTH_AGREE_M + depth_unit_m
    if both.sum() == 0 or np.quantile(diff, 0.99) > tol:
        median_mm = 1000 * float(np.median(diff)) if len(diff) else float("nan")
        raise InputError(paths.depth_png, f"both depth.png and depth.npy exist and disagree "
                         f"(median |difference| {median_mm:.0f} mm over {int(both.sum())} "
                         "pixels); keep only the right one")
    return [f"{paths.input}: both depth.png and depth.npy exist; they agree, depth.npy is used"]


def check_depth_range(path: Path, depth_m: np.ndarray, depth_unit_m: float) -> list[str]:
    """:class:`InputError` when the median depth is outside :data:`TABLE_DEPTH_RANGE_M`
    (a wrong depth unit), a warning when it is beyond :data:`TABLE_DEPTH_WARN_M`."""
    median = float(np.nanmedian(depth_m))
    unit = (f"with depth_unit_m {depth_unit_m:g} (camera.json)" if path.suffix == ".png"
            else "(depth.npy must hold metres)")
    lo, hi = TABLE_DEPTH_RANGE_M
    if not lo <= median <= hi:
        raise InputError(path, f"median depth {median:.4g} m {unit}: a tabletop is "
                         f"{lo:g}-{hi:g} m from the camera; is the depth unit right?")
    if median > TABLE_DEPTH_WARN_M:
        return [f"{path}: median depth {median:.2f} m {unit} is far for a tabletop; check "
                "the depth unit"]
    return []


def load_masks(path: Path, width: int, height: int) -> np.ndarray:
    img = _read_image(path)
    arr = np.asarray(img)
    if arr.ndim != 2:
        raise InputError(path, f"expected a single-channel 8- or 16-bit image, got mode {img.mode}")
    _check_size(path, arr, width, height)
    masks = arr.astype(np.int32)
    if not (masks > 0).any():
        raise InputError(path, "no instance in the mask (every pixel is 0)")
    return masks


def load_objects(paths: ScenePaths) -> dict[int, ObjectEntry]:
    if not paths.objects.exists():
        return {}
    data = read_json_file(paths.objects)
    try:
        parsed = ObjectsFile.model_validate(data)
    except ValidationError as exc:
        raise InputError(paths.objects, _first_error(exc)) from None
    return {o.id: o for o in parsed.objects}


def placeholder_label(obj_id: int) -> str:
    """The label of an id that objects.json gives none (or has no entry for)."""
    return f"object_{obj_id}"


def load_input(scene_dir: Path) -> InputScene:
    """Load and validate ``scene_dir/input``; raise :class:`InputError` on the first problem."""
    paths = ScenePaths(Path(scene_dir))
    if not paths.root.is_dir():
        raise InputError(paths.root, "scene directory does not exist")
    if not paths.input.is_dir():
        raise InputError(paths.input, "missing folder (a scene needs input/)")
    camera, depth_unit_m = load_camera(paths.camera)
    w, h = camera.width, camera.height
    rgb = load_rgb(paths.rgb, w, h)
    depth = load_depth(paths, w, h, depth_unit_m)
    warnings = check_principal_point(paths.camera, camera)
    warnings += check_depth_files(paths, depth, w, h, depth_unit_m)
    warnings += check_depth_range(paths.depth_npy if paths.depth_npy.is_file() else paths.depth_png,
                                  depth, depth_unit_m)
    masks = load_masks(paths.masks, w, h)
    entries = load_objects(paths)

    ids = sorted(int(i) for i in np.unique(masks) if i > 0)
    objects: list[ObjectSpec] = []
    skipped: list[int] = []
    skipped_specs: list[ObjectSpec] = []
    for obj_id in ids:
        visible = int(((masks == obj_id) & np.isfinite(depth)).sum())
        entry = entries.get(obj_id)
        prior, pose, label = None, None, placeholder_label(obj_id)
        if entry is not None:
            label = entry.label or label
            if entry.prior_mesh:
                prior = (paths.input / entry.prior_mesh).resolve()
                if not prior.is_file():
                    raise InputError(paths.input / entry.prior_mesh,
                                     f"missing prior mesh of object {obj_id}")
            if entry.world_from_prior is not None:
                pose = np.asarray(entry.world_from_prior, dtype=np.float64)
        spec = ObjectSpec(id=obj_id, label=label, prior_mesh=prior, world_from_prior=pose,
                          declared=entry is not None)
        unread = _unread_inside(masks == obj_id, depth) if visible >= MIN_MASK_PIXELS else None
        if visible < MIN_MASK_PIXELS or unread:
            skipped.append(obj_id)
            skipped_specs.append(spec)
            warnings.append(f"{paths.masks}: instance {obj_id} " + (
                unread or f"has only {visible} pixel{'' if visible == 1 else 's'} with valid "
                          f"depth (need {MIN_MASK_PIXELS} to reconstruct it from depth)"))
            continue
        objects.append(spec)
    if not objects:
        raise InputError(paths.masks, f"no instance has {MIN_MASK_PIXELS} pixels with valid "
                         f"depth (instances {', '.join(map(str, skipped))})")
    warnings += [
        f"{paths.objects}: object {i} does not appear in masks.png and is skipped"
        for i in sorted(set(entries) - set(ids))
    ]
    return InputScene(rgb=rgb, depth_m=depth, masks=masks, camera=camera, objects=objects,
                      warnings=warnings, skipped_ids=skipped, skipped_objects=skipped_specs)
