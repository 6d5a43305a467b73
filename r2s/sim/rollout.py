"""Roll a loaded export scene forward under gravity in PyBullet and record its trajectory."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from r2s.console import ProgressFn, silent_progress
from r2s.sim.pybullet_bodies import body_world_from_object
from r2s.sim.pybullet_scene import LoadedScene


@dataclass(frozen=True)
class Trajectory:
    """Recorded object states of one rollout (T samples, N objects).

    Attributes
    ----------
    ids : (N,) int object ids.
    times_s : (T,) float sample times; ``times_s[0] == 0`` is the state before any step.
    world_from_object : (T, N, 4, 4) float object poses.
    linear_velocity_mps : (T, N, 3) float velocity of each COM, world frame.
    angular_velocity_radps : (T, N, 3) float angular velocity, world frame.
    com_in_object : (N, 3) float centre of mass in each object frame, metres.
    """

    ids: np.ndarray
    times_s: np.ndarray
    world_from_object: np.ndarray
    linear_velocity_mps: np.ndarray
    angular_velocity_radps: np.ndarray
    com_in_object: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1])

    @property
    def com_world_m(self) -> np.ndarray:
        """(T, N, 3) COM positions in the world frame."""
        rot = self.world_from_object[..., :3, :3]
        origin = self.world_from_object[..., :3, 3]
        return np.einsum("tnij,nj->tni", rot, self.com_in_object) + origin


def _sample(client: int, loaded: LoadedScene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not loaded.ids:
        return np.zeros((0, 4, 4)), np.zeros((0, 3)), np.zeros((0, 3))
    poses, lin, ang = [], [], []
    for obj_id in loaded.ids:
        body = loaded.body_ids[obj_id]
        poses.append(body_world_from_object(client, body, loaded.com_in_object[obj_id]))
        v, w = pb.getBaseVelocity(body, physicsClientId=client)
        lin.append(v)
        ang.append(w)
    return np.stack(poses), np.asarray(lin, dtype=np.float64), np.asarray(ang, dtype=np.float64)


def rollout(client: int, loaded: LoadedScene, duration_s: float = 3.0, rate_hz: float = 240.0,
            record_hz: float = 60.0, progress: ProgressFn = silent_progress) -> Trajectory:
    """Step the client at ``1 / rate_hz`` for ``duration_s`` and record at ``record_hz``.

    The client's bodies are moved (the rollout is not undone). ``record_hz`` is rounded to
    a whole number of steps per sample; the last sample is always at the final step.
    """
    if duration_s <= 0 or rate_hz <= 0 or record_hz <= 0:
        raise ValueError("duration_s, rate_hz and record_hz must be positive")
    dt = 1.0 / float(rate_hz)
    n_steps = max(1, int(round(duration_s * rate_hz)))
    stride = max(1, int(round(rate_hz / record_hz)))
    pb.setTimeStep(dt, physicsClientId=client)

    times, poses, lins, angs = [0.0], [], [], []
    pose, lin, ang = _sample(client, loaded)
    poses.append(pose), lins.append(lin), angs.append(ang)
    for step in range(1, n_steps + 1):
        pb.stepSimulation(physicsClientId=client)
        if step % stride == 0 or step == n_steps:
            pose, lin, ang = _sample(client, loaded)
            times.append(step * dt)
            poses.append(pose), lins.append(lin), angs.append(ang)
            if step % (stride * 30) == 0:
                progress("rollout", step / n_steps)

    coms = [loaded.com_in_object[i] for i in loaded.ids]
    return Trajectory(
        ids=np.asarray(loaded.ids, dtype=np.int64),
        times_s=np.asarray(times, dtype=np.float64),
        world_from_object=np.stack(poses),
        linear_velocity_mps=np.stack(lins),
        angular_velocity_radps=np.stack(angs),
        com_in_object=np.stack(coms) if coms else np.zeros((0, 3)),
    )
