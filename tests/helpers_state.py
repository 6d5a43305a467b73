"""Hand-made ``init/`` state folders (SceneState + GLB meshes) for graph / geomopt tests.

The scene's manifest records 'init' as done, so downstream stages find it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh

from r2s.io.paths import ScenePaths
from r2s.io.state import ObjectState, SceneState, SupportPlane, write_state
from r2s.io.manifest import StageRecord, load_manifest, save_manifest


def pose(translation: Sequence[float] = (0, 0, 0), rotation: Optional[np.ndarray] = None) -> np.ndarray:
    out = np.eye(4)
    if rotation is not None:
        out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@dataclass
class StateObj:
    """One object: ``mesh`` in the object frame, placed by ``world_from_object``."""

    id: int
    mesh: trimesh.Trimesh
    world_from_object: np.ndarray
    label: str = "box"
    com_in_object: Optional[Sequence[float]] = None
    mass_kg: Optional[float] = 0.2
    friction: Optional[float] = 0.6
    source: str = "prior"


def box(id: int, extents: Sequence[float], centre: Sequence[float],
        rotation: Optional[np.ndarray] = None, label: str = "box") -> StateObj:
    """A box centred on its object-frame origin, its centre placed at ``centre``."""
    return StateObj(id=id, mesh=trimesh.creation.box(extents=extents),
                    world_from_object=pose(centre, rotation), label=label)


def write_init_state(scene: Path, objects: Sequence[StateObj], support_point=(0, 0, 0),
                     support_normal=(0, 0, 1), gravity=(0, 0, -9.81),
                     stage: str = "init") -> Path:
    """Write ``scene/<stage>/state.json`` + ``meshes/<id>.glb`` and mark the stage done."""
    paths = ScenePaths(scene)
    stage_dir = paths.stage_dir(stage)
    (stage_dir / "meshes").mkdir(parents=True, exist_ok=True)
    states = []
    for o in objects:
        (stage_dir / "meshes" / f"{o.id}.glb").write_bytes(o.mesh.export(file_type="glb"))
        states.append(ObjectState(
            id=o.id, label=o.label, mesh=f"meshes/{o.id}.glb",
            world_from_object=np.asarray(o.world_from_object, dtype=float).tolist(),
            mass_kg=o.mass_kg, friction=o.friction,
            com_in_object=None if o.com_in_object is None else list(o.com_in_object),
            source=o.source))
    write_state(stage_dir, SceneState(
        stage=stage, gravity=list(gravity),
        support=SupportPlane(point=list(support_point), normal=list(support_normal)),
        objects=states))
    manifest = load_manifest(paths.manifest)
    manifest.stages[stage] = StageRecord(status="done")
    save_manifest(paths.manifest, manifest)
    return scene
