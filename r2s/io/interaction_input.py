"""Read and validate ``input/interaction/``: an observed push (r2s's own layout).

::

    input/interaction/
      push.json          the push that was made, in r2s predict's action format
                         (r2s.io.push_action); required
      depth_after.png    depth seen after the push, like input/depth.png (same camera,
       or .npy           same size, same depth_unit_m); optional
      masks_after.png    instance ids after the push, the ids of input/masks.png; optional,
                         needs the depth
      observed.json      {"pushed_id": 3,
                          "objects": [{"id": 3, "displacement_m": [dx, dy, dz]}, ...]}
                         centre-of-mass displacement of each object seen in both images,
                         world frame, metres (from a tracker, or from gt/ for a synthetic
                         scene); optional

Every problem raises :class:`r2s.errors.InputError` naming the file. Nothing here writes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from r2s.errors import InputError
from r2s.io.push_action import PushAction, read_action
from r2s.io.input_scene import (_first_error, load_camera, load_depth_file, load_masks,
                                read_json_file)
from r2s.io.paths import ScenePaths


class ObservedObject(BaseModel):
    model_config = ConfigDict(extra="forbid")

    id: int = Field(gt=0)
    displacement_m: list[float] = Field(min_length=3, max_length=3)


class ObservedFile(BaseModel):
    """``input/interaction/observed.json``."""

    model_config = ConfigDict(extra="allow")

    pushed_id: Optional[int] = Field(None, gt=0)
    objects: list[ObservedObject] = []


@dataclass(frozen=True)
class ObservedPush:
    """A validated ``input/interaction/`` folder.

    Attributes
    ----------
    action : the push.
    depth_after_m : (H, W) float32 metres along the camera z axis, NaN where no reading;
        None when not given.
    masks_after : (H, W) int32 instance ids after the push, 0 = no object; None when not given.
    displacement_m : object id -> (3,) observed COM displacement, world frame, metres.
    pushed_id : the object the push was aimed at, when known.
    """

    action: PushAction
    depth_after_m: Optional[np.ndarray] = None
    masks_after: Optional[np.ndarray] = None
    displacement_m: dict = field(default_factory=dict)
    pushed_id: Optional[int] = None


def read_observed(path: Path) -> ObservedFile:
    try:
        return ObservedFile.model_validate(read_json_file(Path(path)))
    except ValidationError as exc:
        raise InputError(path, _first_error(exc)) from None


def load_observed_push(scene_dir: Path) -> Optional[ObservedPush]:
    """The observed push of ``scene_dir``, or None when ``input/interaction/push.json`` is absent.

    The images are checked against ``input/camera.json`` (size, depth unit).
    """
    paths = ScenePaths(Path(scene_dir))
    if not paths.push_action.is_file():
        others = [p for p in (paths.depth_after_png, paths.depth_after_npy, paths.masks_after,
                              paths.observed_push) if p.is_file()]
        if others:
            raise InputError(paths.push_action, f"missing file ({others[0].name} is there, "
                                                "but not the push that was made)")
        return None
    action = read_action(paths.push_action)
    depth = masks = None
    if paths.depth_after_png.is_file() or paths.depth_after_npy.is_file():
        camera, unit = load_camera(paths.camera)
        depth = load_depth_file(paths.depth_after_png, paths.depth_after_npy, camera.width,
                                camera.height, unit)
        if paths.masks_after.is_file():
            masks = load_masks(paths.masks_after, camera.width, camera.height)
    elif paths.masks_after.is_file():
        raise InputError(paths.depth_after_png, "missing file (masks_after.png needs the "
                                                "depth after the push)")
    displacement, pushed = {}, None
    if paths.observed_push.is_file():
        obs = read_observed(paths.observed_push)
        ids = [o.id for o in obs.objects]
        if len(ids) != len(set(ids)):
            raise InputError(paths.observed_push, "objects: duplicate object ids")
        displacement = {o.id: np.asarray(o.displacement_m, dtype=np.float64)
                        for o in obs.objects}
        if not all(np.isfinite(d).all() for d in displacement.values()):
            raise InputError(paths.observed_push, "objects: non-finite displacement_m")
        pushed = obs.pushed_id
    return ObservedPush(action=action, depth_after_m=depth, masks_after=masks,
                        displacement_m=displacement, pushed_id=pushed)


@dataclass(frozen=True)
class TruePush:
    """``gt/push.json``: the push made on the ground truth and its true outcome.

    final : object id -> (4, 4) true ``world_from_object`` after the push and settling.
    """

    pushed_id: int
    action: PushAction
    final: dict


def read_true_push(path: Path) -> Optional[TruePush]:
    """``gt/push.json``, or None when absent."""
    path = Path(path)
    if not path.is_file():
        return None
    data = read_json_file(path)
    try:
        action = PushAction.model_validate(data["action"])
        final = {int(o["id"]): np.asarray(o["world_from_object"], dtype=np.float64)
                 for o in data["objects"]}
        return TruePush(int(data["pushed_id"]), action, final)
    except (KeyError, TypeError, ValueError, ValidationError) as exc:
        raise InputError(path, f"malformed true push: {str(exc).splitlines()[0]}") from None
