"""``gt/scene.json`` and ``export/scene.json`` (the fixed contract of SCENE_FORMAT.md)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from pydantic import BaseModel, ConfigDict, ValidationError

from r2s.errors import InputError
from r2s.io.finite import first_non_finite
from r2s.io.input_scene import read_json_file
from r2s.io.state import SupportPlane


class GtObject(BaseModel):
    model_config = ConfigDict(extra="allow")

    id: int
    label: str = ""
    mesh: str
    world_from_object: list[list[float]]
    mass_kg: float
    friction: float
    com_in_object: list[float] = [0.0, 0.0, 0.0]


class GtScene(BaseModel):
    """``gt/scene.json``. Extra keys (injected effects) are kept but not interpreted here."""

    model_config = ConfigDict(extra="allow")

    gravity: list[float] = [0.0, 0.0, -9.81]
    objects: list[GtObject]
    support: SupportPlane


class ExportObject(BaseModel):
    model_config = ConfigDict(extra="allow")

    id: int
    label: str = ""
    visual_mesh: str
    collision_meshes: list[str]
    world_from_object: list[list[float]]
    mass_kg: float
    com_in_object: list[float]
    friction: float
    restitution: float = 0.0


class ExportScene(BaseModel):
    """``export/scene.json``; paths are relative to ``export/``."""

    model_config = ConfigDict(extra="allow")

    format: str = "r2s-scene"
    version: int = 1
    gravity: list[float]
    support: SupportPlane
    objects: list[ExportObject]


def read_gt_scene(path: Path) -> Optional[GtScene]:
    """The ground truth, or None if the scene has no ``gt/``."""
    path = Path(path)
    if not path.exists():
        return None
    data = read_json_file(path)
    _require_finite(path, data)
    try:
        return GtScene.model_validate(data)
    except ValidationError as exc:
        raise InputError(path, f"malformed gt scene: {exc.errors()[0]['msg']}") from None


def _require_finite(path: Path, data: object) -> None:
    bad = first_non_finite(data)
    if bad:
        raise InputError(path, f"non-finite number (NaN or inf) at {bad}")


def read_export_scene(path: Path) -> ExportScene:
    data = read_json_file(Path(path))
    _require_finite(path, data)
    try:
        return ExportScene.model_validate(data)
    except ValidationError as exc:
        raise InputError(path, f"malformed export scene: {exc.errors()[0]['msg']}") from None
