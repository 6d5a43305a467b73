"""An observed push (``input/interaction/push.json``) and its simulation.

The file (r2s's own layout, see docs/diagnose.md)::

    {"pusher": {"radius_m": 0.01, "path_m": [[x, y, z], ...], "speed_mps": 0.1},
     "settle_s": 1.0,
     "observed": {"objects": [{"id": 3, "displacement_m": [dx, dy, dz]}, ...]}}

``path_m`` are world waypoints of a spherical pusher's centre, followed at ``speed_mps``;
afterwards the scene settles for ``settle_s``. ``displacement_m`` is each object's
observed centre-of-mass displacement between the images before and after (an object not
listed was not observed). The pusher is a heavy sphere dragged along the path by a stiff
constraint, so it cannot pass through what it pushes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from r2s.diagnose.data import PhysicsModel
from r2s.diagnose.measure.physics import WorldSpec, _poses, build_client, motion_between
from r2s.errors import InputError
from r2s.io.input_scene import read_json_file


class _Pusher(BaseModel):
    model_config = ConfigDict(extra="allow")
    radius_m: float = Field(0.01, gt=0)
    path_m: list[list[float]]
    speed_mps: float = Field(0.1, gt=0)


class _Observed(BaseModel):
    model_config = ConfigDict(extra="allow")
    id: int
    displacement_m: list[float]


class _ObservedSet(BaseModel):
    model_config = ConfigDict(extra="allow")
    objects: list[_Observed] = []


class PushFile(BaseModel):
    """``input/interaction/push.json``."""

    model_config = ConfigDict(extra="allow")
    pusher: _Pusher
    settle_s: float = Field(1.0, ge=0)
    observed: _ObservedSet = _ObservedSet()


@dataclass(frozen=True)
class Push:
    """A push: (P, 3) waypoints, pusher radius and speed, settle time."""

    path_m: np.ndarray
    radius_m: float = 0.01
    speed_mps: float = 0.1
    settle_s: float = 1.0

    def to_json(self, observed: dict) -> dict:
        return {"pusher": {"radius_m": self.radius_m, "path_m": self.path_m.tolist(),
                           "speed_mps": self.speed_mps},
                "settle_s": self.settle_s,
                "observed": {"objects": [{"id": int(i), "displacement_m": list(map(float, d))}
                                         for i, d in sorted(observed.items())]}}


def read_push(path: Path) -> tuple[Push, dict]:
    """The push and ``{id: (3,) observed displacement}``; :class:`InputError` if malformed."""
    try:
        data = PushFile.model_validate(read_json_file(Path(path)))
    except ValidationError as exc:
        raise InputError(path, f"malformed push: {exc.errors()[0]['msg']}") from None
    path_m = np.asarray(data.pusher.path_m, dtype=np.float64)
    if path_m.ndim != 2 or path_m.shape[1] != 3 or len(path_m) < 2:
        raise InputError(path, "pusher.path_m must hold at least two [x, y, z] points")
    observed = {o.id: np.asarray(o.displacement_m, dtype=np.float64) for o in data.observed.objects}
    return Push(path_m, data.pusher.radius_m, data.pusher.speed_mps, data.settle_s), observed


def _waypoints(push: Push, dt: float) -> np.ndarray:
    """(T, 3) pusher targets, one per step, at constant speed along the path."""
    seg = np.diff(push.path_m, axis=0)
    length = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    n = max(2, int(np.ceil(cum[-1] / (push.speed_mps * dt))) + 1)
    s = np.linspace(0.0, cum[-1], n)
    return np.stack([np.interp(s, cum, push.path_m[:, k]) for k in range(3)], axis=1)


def simulate_push(spec: WorldSpec, model: PhysicsModel, push: Push,
                  rate_hz: float = 240.0, pusher_mass_kg: float = 5.0) -> dict:
    """{object id: (3,) COM displacement} of the push under ``model``."""
    dt = 1.0 / rate_hz
    c = build_client(spec, model)
    try:
        client = c.client
        pb.setTimeStep(dt, physicsClientId=client)
        targets = _waypoints(push, dt)
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=push.radius_m,
                                        physicsClientId=client)
        pusher = pb.createMultiBody(pusher_mass_kg, shape, basePosition=list(targets[0]),
                                    physicsClientId=client)
        pb.changeDynamics(pusher, -1, lateralFriction=0.5, physicsClientId=client)
        cid = pb.createConstraint(pusher, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                                  list(targets[0]), physicsClientId=client)
        force = pusher_mass_kg * 200.0
        start = _poses(c)
        for target in targets[1:]:
            pb.changeConstraint(cid, list(map(float, target)), maxForce=force,
                                physicsClientId=client)
            pb.stepSimulation(physicsClientId=client)
        pb.removeConstraint(cid, physicsClientId=client)
        pb.removeBody(pusher, physicsClientId=client)
        for _ in range(int(round(push.settle_s * rate_hz))):
            pb.stepSimulation(physicsClientId=client)
        end = _poses(c)
    finally:
        c.close()
    return {i: motion_between(start[i], end[i], c.coms[i]).translation_m for i in start}


def plan_push(com_world: np.ndarray, radius_m: float, camera_center: np.ndarray,
              up: np.ndarray, speed_mps: float = 0.6, approach_m: float = 0.03,
              pusher_radius_m: float = 0.01, settle_s: float = 1.0) -> Push:
    """A strike at an object: a horizontal pass at its COM height, away from the camera.

    The pusher starts ``approach_m`` outside the object's bounding sphere and ends at a
    third of its radius from the COM, so it hits the object at ``speed_mps`` and lets it
    slide; how far it slides depends on its friction.
    """
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    away = np.asarray(com_world, dtype=np.float64) - np.asarray(camera_center, dtype=np.float64)
    away -= (away @ up) * up
    d = away / max(np.linalg.norm(away), 1e-9)
    com = np.asarray(com_world, dtype=np.float64)
    start = com - (radius_m + approach_m + pusher_radius_m) * d
    end = com - radius_m / 3.0 * d
    return Push(np.stack([start, end]), pusher_radius_m, speed_mps, settle_s)
