"""Load ``export/scene.json`` into a PyBullet client, the way an outside judge would.

Only what SCENE_FORMAT.md promises is used: gravity, the support plane and its friction,
and per object its convex collision pieces (object frame), ``world_from_object``, mass,
COM, friction and restitution. Nothing else of r2s (no state, no contact graph) is read.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from r2s.errors import InputError
from r2s.io.scene_json import ExportScene, read_export_scene
from r2s.sim.pybullet_bodies import add_rigid_body, add_support_plane, body_world_from_object
from r2s.io.paths import EXPORT_SCENE_FILE


@dataclass(frozen=True)
class LoadedScene:
    """An export scene living in one PyBullet client.

    Attributes
    ----------
    scene : the parsed ``export/scene.json``.
    export_dir : the folder the scene was read from (paths in ``scene`` are relative to it).
    support_body : PyBullet body id of the static support plane.
    body_ids : object id -> PyBullet body id.
    com_in_object : object id -> (3,) float centre of mass in the object frame, metres.
    """

    scene: ExportScene
    export_dir: Path
    support_body: int
    body_ids: dict[int, int]
    com_in_object: dict[int, np.ndarray]

    @property
    def ids(self) -> list[int]:
        """Object ids in the order of ``export/scene.json``."""
        return [o.id for o in self.scene.objects]

    def initial_world_from_object(self) -> np.ndarray:
        """(N, 4, 4) ``world_from_object`` as written in scene.json, in :attr:`ids` order."""
        poses = [np.asarray(o.world_from_object, dtype=np.float64) for o in self.scene.objects]
        return np.stack(poses) if poses else np.zeros((0, 4, 4))

    def current_world_from_object(self, client: int) -> np.ndarray:
        """(N, 4, 4) ``world_from_object`` of the bodies now, in :attr:`ids` order."""
        poses = [body_world_from_object(client, self.body_ids[i], self.com_in_object[i])
                 for i in self.ids]
        return np.stack(poses) if poses else np.zeros((0, 4, 4))


def load_export_scene(client: int, export_dir: Path) -> LoadedScene:
    """Build the scene of ``export_dir/scene.json`` in ``client`` (which should be empty).

    Raises :class:`InputError` when scene.json is malformed, an object has no collision
    piece, a collision file is missing, or an object id repeats.
    """
    export_dir = Path(export_dir)
    scene_path = export_dir / EXPORT_SCENE_FILE
    scene = read_export_scene(scene_path)

    pb.setGravity(*[float(g) for g in scene.gravity], physicsClientId=client)
    support = scene.support
    support_body = add_support_plane(client, support.point, support.normal, support.friction)

    body_ids: dict[int, int] = {}
    coms: dict[int, np.ndarray] = {}
    for obj in scene.objects:
        if obj.id in body_ids:
            raise InputError(scene_path, f"object id {obj.id} appears twice")
        if not obj.collision_meshes:
            raise InputError(scene_path, f"object {obj.id} has no collision_meshes")
        files = [export_dir / rel for rel in obj.collision_meshes]
        for f in files:
            if not f.is_file():
                raise InputError(f, f"missing collision mesh of object {obj.id}")
        if not obj.mass_kg > 0:
            raise InputError(scene_path, f"object {obj.id} has non-positive mass_kg")
        com = np.asarray(obj.com_in_object, dtype=np.float64)
        body_ids[obj.id] = add_rigid_body(
            client, files, np.asarray(obj.world_from_object, dtype=np.float64),
            obj.mass_kg, com, obj.friction, obj.restitution,
        )
        coms[obj.id] = com
    return LoadedScene(scene=scene, export_dir=export_dir, support_body=support_body,
                       body_ids=body_ids, com_in_object=coms)
