"""The scene as the judge will see it: a PyBullet world built from convex collision pieces.

Used by physopt to verify a candidate scene (does anything move over the judge's rollout?)
and to settle it (let the engine find the nearest rest state under strong damping).
Frames: poses are ``world_from_object`` (4, 4); COM in the object frame.
"""

from __future__ import annotations

import hashlib
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pybullet as pb
import trimesh

from r2s.metrics.stability import rotation_angle_deg
from r2s.sim.pybullet_bodies import (add_rigid_body, add_support_plane, body_world_from_object,
                                     connect_direct, set_body_pose)


@dataclass
class SimBody:
    """One object for the check. pieces: convex meshes in the object frame."""

    id: int
    pieces: Sequence[trimesh.Trimesh]
    world_from_object: np.ndarray
    mass_kg: float
    com_in_object: np.ndarray
    friction: float


@dataclass
class World:
    client: int
    body_ids: dict[int, int]
    coms: dict[int, np.ndarray]
    tmp: tempfile.TemporaryDirectory
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)

    def close(self) -> None:
        try:
            pb.disconnect(self.client)
        finally:
            self.tmp.cleanup()

    def poses(self) -> dict[int, np.ndarray]:
        return {i: body_world_from_object(self.client, b, self.coms[i])
                for i, b in self.body_ids.items()}

    def set_poses(self, poses: dict[int, np.ndarray]) -> None:
        for i, pose in poses.items():
            set_body_pose(self.client, self.body_ids[i], pose, self.coms[i])


def build_world(bodies: Sequence[SimBody], support_point: Sequence[float],
                support_normal: Sequence[float], support_friction: float,
                gravity: Sequence[float] = (0.0, 0.0, -9.81)) -> World:
    """A DIRECT PyBullet client holding the support plane and every body."""
    tmp = tempfile.TemporaryDirectory(prefix="r2s-pb-")
    client = connect_direct()
    pb.setGravity(*[float(g) for g in gravity], physicsClientId=client)
    add_support_plane(client, support_point, support_normal, support_friction)
    ids, coms = {}, {}
    for body in bodies:
        files = []
        for k, piece in enumerate(body.pieces):
            f = Path(tmp.name) / f"{body.id}_{k}.obj"
            f.write_bytes(obj_file_bytes(piece))
            files.append(f)
        ids[body.id] = add_rigid_body(client, files, body.world_from_object, body.mass_kg,
                                      body.com_in_object, body.friction)
        coms[body.id] = np.asarray(body.com_in_object, dtype=float)
    return World(client, ids, coms, tmp, tuple(float(g) for g in gravity))


_OBJ_TEXT: dict[bytes, bytes] = {}
"""OBJ files of convex pieces by content (the repair rounds build dozens of worlds from the
same pieces; trimesh's OBJ writer takes most of a world's Python time)."""


def obj_file_bytes(piece: trimesh.Trimesh) -> bytes:
    """The OBJ file of the piece's vertices and faces, as trimesh writes it for a plain
    piece (what ``piece.export`` wrote here before), remembered by those arrays."""
    v = np.ascontiguousarray(piece.vertices, dtype=np.float64)
    f = np.ascontiguousarray(piece.faces, dtype=np.int64)
    key = hashlib.sha1(v.tobytes() + b"|" + f.tobytes()).digest()
    text = _OBJ_TEXT.get(key)
    if text is None:
        if len(_OBJ_TEXT) >= 4096:
            _OBJ_TEXT.clear()
        data = trimesh.Trimesh(v, f, process=False).export(file_type="obj")
        text = _OBJ_TEXT[key] = data.encode() if isinstance(data, str) else data
    return text


def com_world(pose: np.ndarray, com: np.ndarray) -> np.ndarray:
    return pose[:3, :3] @ com + pose[:3, 3]


REST_SPEED_MPS = 2e-4
"""Below this linear speed (and ``REST_SPIN_RADPS``) for ``REST_WINDOW_S`` every body is
at rest: creeping at it for a whole 5 s check would move a body 1 mm, far under
physopt's 5 mm at-rest tolerance."""
REST_SPIN_RADPS = 2e-3
"""Angular counterpart of ``REST_SPEED_MPS`` (0.57 deg over 5 s, against 2 deg)."""
REST_WINDOW_S = 0.5
REST_POLL_STEPS = 12
PROBE_SPIN_RADPS = 0.02
"""The nudge of the rest probe (:func:`_rest_survives_nudge`): every body is given this spin
about a horizontal axis, ten times the rest threshold ``REST_SPIN_RADPS``."""
PROBE_S = 1.0
"""How long the nudged scene is followed."""
PROBE_GROWTH = 3.0
"""A body whose spin at any poll of the probe exceeds this multiple of the nudge (or whose
speed exceeds ``PROBE_GROWTH * PROBE_SPIN_RADPS * 0.1 m``) is gaining energy: it sat on an
unstable equilibrium (a cube balanced on an edge, nudged, spins 1.5 times the nudge after
40 steps and 14 times after 80). A ball nudged on a plane rolls on at about the nudge's
spin; a box on its face stops."""


def drift(world: World, start: dict[int, np.ndarray], duration_s: float,
          time_step_s: float = 1.0 / 240.0, stop_at_rest: bool = True
          ) -> dict[int, tuple[float, float]]:
    """Simulate ``duration_s`` from ``start`` (zero velocity); per object the COM translation
    (m) and rotation (deg) between the start and the end.

    With ``stop_at_rest`` the simulation ends early once every body has stayed below
    ``REST_SPEED_MPS`` and ``REST_SPIN_RADPS`` for ``REST_WINDOW_S`` (polled every
    ``REST_POLL_STEPS`` steps) and the rest survives a nudge (:func:`_rest_survives_nudge`):
    the rest of the run could not move anything measurably. A scene still at an unstable
    equilibrium (an orange balanced where numerical noise tips it late) is followed for the
    whole ``duration_s``, like the judge's rollout. The nudge is a probe only: the state is
    restored after it, so the drift is always that of the unperturbed run."""
    world.set_poses(start)
    steps = int(round(duration_s / time_step_s))
    window = int(round(REST_WINDOW_S / time_step_s))
    quiet = 0
    for k in range(1, steps + 1):
        pb.stepSimulation(physicsClientId=world.client)
        if stop_at_rest and k % REST_POLL_STEPS == 0:
            quiet = quiet + REST_POLL_STEPS if _all_at_rest(world) else 0
            if quiet >= window:
                if _rest_survives_nudge(world, time_step_s):
                    break
                stop_at_rest = False
    end = world.poses()
    out = {}
    for i, pose in end.items():
        c = world.coms[i]
        out[i] = (float(np.linalg.norm(com_world(pose, c) - com_world(start[i], c))),
                  float(rotation_angle_deg(start[i][:3, :3], pose[:3, :3])))
    return out


def _rest_survives_nudge(world: World, time_step_s: float) -> bool:
    """Whether every body at rest stays near rest when nudged: each is given a spin of
    ``PROBE_SPIN_RADPS`` about a horizontal axis (its own, fixed by its id, so the probe is
    deterministic) and followed for ``PROBE_S``; a body that at any poll spins
    ``PROBE_GROWTH`` times faster, or moves faster than ``PROBE_GROWTH`` times the nudge at
    0.1 m, is gaining energy from gravity: it was balanced on an unstable equilibrium. The
    world's state is restored before returning."""
    c = world.client
    saved = pb.saveState(physicsClientId=c)
    try:
        for i, b in world.body_ids.items():
            a = 0.7 * float(i) + 0.3
            pb.resetBaseVelocity(b, [0.0, 0.0, 0.0],
                                 [PROBE_SPIN_RADPS * np.cos(a), PROBE_SPIN_RADPS * np.sin(a), 0.0],
                                 physicsClientId=c)
        for k in range(1, int(round(PROBE_S / time_step_s)) + 1):
            pb.stepSimulation(physicsClientId=c)
            if k % REST_POLL_STEPS == 0 and not _all_below(
                    world, PROBE_GROWTH * PROBE_SPIN_RADPS * 0.1, PROBE_GROWTH * PROBE_SPIN_RADPS):
                return False
        return True
    finally:
        pb.restoreState(saved, physicsClientId=c)
        pb.removeState(saved, physicsClientId=c)


def _all_at_rest(world: World) -> bool:
    return _all_below(world, REST_SPEED_MPS, REST_SPIN_RADPS)


def _all_below(world: World, speed_mps: float, spin_radps: float) -> bool:
    for b in world.body_ids.values():
        lin, ang = pb.getBaseVelocity(b, physicsClientId=world.client)
        if np.linalg.norm(lin) > speed_mps or np.linalg.norm(ang) > spin_radps:
            return False
    return True


def settle(world: World, start: dict[int, np.ndarray], duration_s: float,
           reset_every: int = 8, time_step_s: float = 1.0 / 240.0) -> dict[int, np.ndarray]:
    """Quasi-static settling: every velocity is reset to zero every ``reset_every`` steps.

    Little momentum builds up (at most ``g * reset_every * dt``), so each body slides down
    the energy landscape into the nearest rest state supported by its contacts instead of
    rolling or tumbling away. Returns the rest poses.
    """
    world.set_poses(start)
    for k in range(int(round(duration_s / time_step_s))):
        if k % reset_every == 0:
            for b in world.body_ids.values():
                pb.resetBaseVelocity(b, [0, 0, 0], [0, 0, 0], physicsClientId=world.client)
        pb.stepSimulation(physicsClientId=world.client)
    return world.poses()


def settle_damped(world: World, start: dict[int, np.ndarray], duration_s: float,
                  damping: float = 0.9, time_step_s: float = 1.0 / 240.0) -> dict[int, np.ndarray]:
    """Full dynamics with strong linear and angular damping (Bullet's per-second velocity
    loss factor, 0-1): bodies roll, rock and topple as they would, but the energy drains
    away and the scene comes to a true dynamic rest. The last resort for bodies that
    quasi-static settling cannot hold (a ball rocking on an eccentric COM, a wedge that
    slips late). Returns the rest poses."""
    world.set_poses(start)
    for b in world.body_ids.values():
        pb.changeDynamics(b, -1, linearDamping=damping, angularDamping=damping,
                          physicsClientId=world.client)
    for _ in range(int(round(duration_s / time_step_s))):
        pb.stepSimulation(physicsClientId=world.client)
    return world.poses()


def penetrations(world: World, plane_body: int = 0) -> list[tuple[int, int, float, np.ndarray]]:
    """Every penetrating pair: (id_a, id_b or 0 for the plane, depth_m > 0, normal (3,)).

    ``normal`` points from b towards a (the direction that separates a from b).
    """
    out = []
    items = list(world.body_ids.items())
    for ia, (id_a, body_a) in enumerate(items):
        others = [(0, plane_body)] + items[ia + 1:]
        for id_b, body_b in others:
            pts = pb.getClosestPoints(body_a, body_b, 0.0, physicsClientId=world.client)
            if not pts:
                continue
            deepest = min(pts, key=lambda p: p[8])
            if deepest[8] < 0:
                out.append((id_a, id_b, -float(deepest[8]), np.asarray(deepest[7], dtype=float)))
    return out


BULLET_MARGIN_M = 1e-3
"""Bullet reports resting convex meshes as overlapping by about its 1 mm collision margin."""


def depenetrate(world: World, order: Sequence[int], tolerance_m: float = 1.5e-3,
                max_iterations: int = 60, movable: set[int] | None = None
                ) -> dict[int, np.ndarray]:
    """Push bodies apart along contact normals until no penetration exceeds ``tolerance_m``
    (measured as Bullet reports it, i.e. including its ~1 mm margin; bodies are pushed to
    an overlap of :data:`BULLET_MARGIN_M`, which is where Bullet itself rests them).

    Of two penetrating objects the one later in ``order`` (the child) moves, so that parents
    stay fixed as in the hierarchical optimisation; the plane and objects outside
    ``movable`` (when given) never move. Translation only.
    Returns the new poses.
    """
    rank = {i: k for k, i in enumerate(order)}
    poses = world.poses()
    for _ in range(max_iterations):
        pens = [p for p in penetrations(world) if p[2] > tolerance_m
                and (movable is None or p[0] in movable or p[1] in movable)]
        if not pens:
            break
        push: dict[int, np.ndarray] = {}
        for id_a, id_b, depth_m, normal in pens:
            can_a = movable is None or id_a in movable
            can_b = id_b != 0 and (movable is None or id_b in movable)
            if can_a and (not can_b or rank.get(id_a, 0) > rank.get(id_b, 0)):
                mover, direction = id_a, normal
            elif can_b:
                mover, direction = id_b, -normal
            else:
                continue
            amount = depth_m - BULLET_MARGIN_M
            cur = push.get(mover, np.zeros(3))
            # combine pushes: add only what the push so far lacks along this direction
            push[mover] = cur + direction * max(amount - max(np.dot(cur, direction), 0.0), 0.0)
        for i, delta in push.items():
            poses[i] = poses[i].copy()
            poses[i][:3, 3] += delta
        world.set_poses({i: poses[i] for i in push})
    return poses


def world_gravity(world: World) -> np.ndarray:
    """The gravity vector the world was built with (world frame, m/s^2)."""
    return np.asarray(world.gravity, dtype=float)

