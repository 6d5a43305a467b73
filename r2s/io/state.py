"""The scene state that state-writing stages hand to each other (r2s's own format).

``<stage>/state.json`` (stage in init, geomopt, physopt, texture)::

    {"stage": "init", "gravity": [0, 0, -9.81],
     "support": {"type": "plane", "point": [..], "normal": [..], "friction": 0.8},
     "objects": [{"id": 3, "label": "mug", "mesh": "meshes/3.glb",
                  "world_from_object": 4x4, "mass_kg": 0.2, "com_in_object": [x, y, z],
                  "friction": 0.6, "source": "prior"|"completed", ...}]}

Mesh paths are relative to the stage folder. The mesh is in the object frame;
``world_from_object`` places it. Extra keys per object are kept (``extra="allow"``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError

from r2s.errors import StageError
from r2s.io.atomic import atomic_write_json
from r2s.io.finite import first_non_finite
from r2s.io.input_scene import read_json_file
from r2s.io.paths import STATE_FILE

DEFAULT_GRAVITY = (0.0, 0.0, -9.81)


class SupportPlane(BaseModel):
    """An infinite support plane: points x with normal . (x - point) = 0; normal points up."""

    model_config = ConfigDict(extra="allow")

    type: Literal["plane"] = "plane"
    point: list[float]
    normal: list[float]
    friction: float = 0.8


class ObjectState(BaseModel):
    """One object of a stage's state."""

    model_config = ConfigDict(extra="allow")

    id: int
    label: str
    mesh: str
    world_from_object: list[list[float]]
    mass_kg: Optional[float] = None
    com_in_object: Optional[list[float]] = None
    friction: Optional[float] = None
    restitution: float = 0.0
    source: str = "prior"

    @property
    def pose(self) -> np.ndarray:
        """(4, 4) world_from_object."""
        return np.asarray(self.world_from_object, dtype=np.float64)


class SceneState(BaseModel):
    """The full state written by a state stage."""

    model_config = ConfigDict(extra="allow")

    stage: str
    gravity: list[float] = list(DEFAULT_GRAVITY)
    support: SupportPlane
    objects: list[ObjectState]

    def object(self, obj_id: int) -> ObjectState:
        for o in self.objects:
            if o.id == obj_id:
                return o
        raise KeyError(obj_id)


def read_state(stage_dir: Path) -> SceneState:
    """Read ``stage_dir/state.json``; :class:`StageError` if it is missing or malformed."""
    path = Path(stage_dir) / STATE_FILE
    if not path.is_file():
        raise StageError(f"{path}: missing; run the '{Path(stage_dir).name}' stage first")
    data = read_json_file(path)
    bad = first_non_finite(data)
    if bad:
        raise StageError(f"{path}: non-finite number at {bad}; rerun the "
                         f"'{Path(stage_dir).name}' stage")
    try:
        return SceneState.model_validate(data)
    except ValidationError as exc:
        raise StageError(f"{path}: malformed state ({exc.errors()[0]['msg']})") from None


def write_state(stage_dir: Path, state: SceneState) -> None:
    """Write ``stage_dir/state.json``; :class:`StageError` if a number is NaN or inf (JSON
    would turn it into null, a state no later stage can read)."""
    data = state.model_dump()
    bad = first_non_finite(data)
    if bad:
        raise StageError(f"{Path(stage_dir).name} state: non-finite number at {bad} "
                         "(the optimisation diverged); nothing written")
    atomic_write_json(Path(stage_dir) / STATE_FILE, data)
