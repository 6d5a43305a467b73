"""The push action file (r2s's own format, read by ``r2s predict --action FILE``)::

    {"end_effector": {"type": "sphere", "radius_m": 0.015},          # or "box", "half_extents_m"
     "start": [x, y, z],                                               # world frame, metres
     "waypoints": [{"position": [x, y, z], "speed_mps": 0.05}, ...],
     "settle_s": 1.0}                                                  # simulated after the last waypoint
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from r2s.errors import InputError
from r2s.io.input_scene import read_json_file


class EndEffector(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    type: Literal["sphere", "box"] = "sphere"
    radius_m: float = Field(0.015, gt=0)
    half_extents_m: Optional[list[Annotated[float, Field(gt=0)]]] = Field(
        None, min_length=3, max_length=3)


class Waypoint(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    position: list[float] = Field(min_length=3, max_length=3)
    speed_mps: float = Field(0.05, gt=0)


class PushAction(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    end_effector: EndEffector = EndEffector()
    start: list[float] = Field(min_length=3, max_length=3)
    waypoints: list[Waypoint] = Field(min_length=1)
    settle_s: float = Field(1.0, ge=0)


def read_action(path: Path) -> PushAction:
    try:
        return PushAction.model_validate(read_json_file(Path(path)))
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err.get("loc", ()))
        raise InputError(path, f"{loc}: {err.get('msg')}") from None
