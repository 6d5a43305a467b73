"""Replay a pusher trajectory on a scene loaded in PyBullet.

The pusher is a heavy dynamic body dragged by a fixed constraint whose target moves along
the waypoints at their speeds, so it pushes with physical contact forces (a teleported
kinematic body would not).
"""

from __future__ import annotations

import numpy as np
import pybullet as pb

from r2s.io.push_action import PushAction
from r2s.sim.pybullet_bodies import TIME_STEP_S, body_world_from_object
from r2s.sim.pybullet_scene import LoadedScene

PUSHER_MASS_KG = 5.0
PUSHER_MAX_FORCE_N = 500.0


def _add_pusher(client: int, action: PushAction) -> tuple[int, int]:
    ee = action.end_effector
    if ee.type == "sphere":
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=ee.radius_m, physicsClientId=client)
    else:
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=ee.half_extents_m or [0.01] * 3,
                                        physicsClientId=client)
    body = pb.createMultiBody(PUSHER_MASS_KG, shape, basePosition=action.start,
                              physicsClientId=client)
    pb.changeDynamics(body, -1, lateralFriction=0.5, physicsClientId=client)
    cid = pb.createConstraint(body, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                              action.start, physicsClientId=client)
    return body, cid


def path_targets(action: PushAction, time_step_s: float = TIME_STEP_S) -> np.ndarray:
    """(S, 3) pusher target per simulation step along the waypoints at their speeds."""
    points, here = [], np.asarray(action.start, dtype=float)
    for wp in action.waypoints:
        goal = np.asarray(wp.position, dtype=float)
        steps = max(1, int(np.ceil(np.linalg.norm(goal - here) / (wp.speed_mps * time_step_s))))
        points.append(here + (goal - here) * (np.arange(1, steps + 1) / steps)[:, None])
        here = goal
    return np.concatenate(points)


def run_push(client: int, action: PushAction, body_ids: dict[int, int],
             com_in_object: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Run the push on the bodies of ``client``, then ``settle_s`` more.

    ``body_ids``: object id -> PyBullet body id; ``com_in_object``: object id -> (3,) COM in
    the object frame. Returns object id -> (4, 4) final ``world_from_object``.
    """
    pusher, cid = _add_pusher(client, action)
    for target in path_targets(action):
        pb.changeConstraint(cid, list(target), maxForce=PUSHER_MAX_FORCE_N, physicsClientId=client)
        pb.stepSimulation(physicsClientId=client)
    pb.removeConstraint(cid, physicsClientId=client)
    pb.removeBody(pusher, physicsClientId=client)
    for _ in range(int(round(action.settle_s / TIME_STEP_S))):
        pb.stepSimulation(physicsClientId=client)
    return {i: body_world_from_object(client, b, com_in_object[i]) for i, b in body_ids.items()}


def replay_push(client: int, loaded: LoadedScene, action: PushAction) -> dict[int, np.ndarray]:
    """Run the push on a loaded export scene, then ``settle_s`` more; returns the final
    (4, 4) ``world_from_object`` per object id."""
    return run_push(client, action, loaded.body_ids, loaded.com_in_object)
