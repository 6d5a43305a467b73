"""Drop bodies into a clutter in PyBullet, settle them, and prove the result is at rest.

:func:`drop_bodies` drops bodies one by one over a small disc (some straight onto an
earlier body, so that objects stack and lean) and lets each come to rest. :func:`verify_rest`
is the judge's test made stricter: from the given poses with zero velocity, a fresh
simulation of ``duration_s`` at 240 Hz must move no COM by ``tol_m`` or more and turn no
body by ``tol_deg`` or more. :func:`settle_and_verify` alternates the two and removes bodies
that keep moving.

Bodies are created with :func:`r2s.sim.pybullet_bodies.add_rigid_body` in list order, the
same way ``r2s evaluate`` loads an export, so the verified state is the one the judge sees.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import pybullet as pb
import trimesh
from scipy.spatial.transform import Rotation

from r2s.sim.pybullet_bodies import (TIME_STEP_S, add_rigid_body, add_support_plane,
                                     body_world_from_object, connect_direct)

GRAVITY = (0.0, 0.0, -9.81)
SETTLE_DAMPING = 0.4
"""Linear and angular damping while dropping (PyBullet's default 0.04 is restored after)."""
SETTLE_ROLLING_FRICTION = 0.003
"""Rolling and spinning friction while dropping, so that round objects stop near the pile
(PyBullet's default 0 is restored after; the rest check runs without it)."""
DEFAULT_DAMPING = 0.04
UPRIGHT_PROBABILITY = 0.65
"""Chance that a body drops in its catalogue orientation (turned about z) rather than in a
uniformly random one."""
REST_SPEED_MPS = 0.004
REST_SPIN_RADPS = 0.04
CONTACT_GAP_M = 0.001
"""Bodies closer than this count as touching in :func:`contact_summary`."""


@dataclass(frozen=True)
class Support:
    """The support plane: ``normal . (x - point) = 0``, normal (3,) unit pointing up."""

    point: np.ndarray
    normal: np.ndarray
    friction: float

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) world z of the plane at (N, 2) horizontal positions."""
        n, p = self.normal, self.point
        xy = np.atleast_2d(xy)
        return p[2] - (n[0] * (xy[:, 0] - p[0]) + n[1] * (xy[:, 1] - p[1])) / n[2]


@dataclass
class Body:
    """A rigid body of the scene (everything in its object frame).

    Attributes
    ----------
    name : catalogue name (the label).
    mesh : closed true shape.
    pieces : convex collision pieces (exactly the export's).
    piece_files : the pieces as .obj files, for PyBullet.
    mass_kg, com_in_object (3,), friction : physical properties.
    extra : generator bookkeeping (density, COM shift, ...).
    """

    name: str
    mesh: trimesh.Trimesh
    pieces: list[trimesh.Trimesh]
    piece_files: list[Path]
    mass_kg: float
    com_in_object: np.ndarray
    friction: float
    extra: dict = field(default_factory=dict)

    @property
    def hull_vertices(self) -> np.ndarray:
        """(M, 3) vertices of all collision pieces, object frame."""
        return np.vstack([p.vertices for p in self.pieces])


@dataclass(frozen=True)
class RestCheck:
    """Outcome of :func:`verify_rest`.

    Attributes
    ----------
    moved_m : (N,) COM displacement of each body, metres.
    turned_deg : (N,) rotation angle of each body, degrees.
    end_poses : (N, 4, 4) world_from_object at the end of the simulation.
    at_rest : (N,) bool, both below the tolerances.
    """

    moved_m: np.ndarray
    turned_deg: np.ndarray
    end_poses: np.ndarray
    at_rest: np.ndarray


def _world(support: Support) -> int:
    client = connect_direct()
    pb.setGravity(*GRAVITY, physicsClientId=client)
    add_support_plane(client, support.point, support.normal, support.friction)
    return client


def _add(client: int, body: Body, pose: np.ndarray) -> int:
    return add_rigid_body(client, body.piece_files, pose, body.mass_kg, body.com_in_object,
                          body.friction)


def _com_world(pose: np.ndarray, com: np.ndarray) -> np.ndarray:
    return pose[:3, :3] @ com + pose[:3, 3]


def rotation_angle_deg(rot_a: np.ndarray, rot_b: np.ndarray) -> float:
    """Angle of the relative rotation between two (3, 3) rotations, degrees."""
    cos = (np.trace(rot_a.T @ rot_b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def verify_rest(bodies: list[Body], poses: np.ndarray, support: Support, duration_s: float,
                tol_m: float, tol_deg: float) -> RestCheck:
    """Simulate the scene from rest and measure how far every body goes.

    Parameters
    ----------
    bodies : N bodies; poses : (N, 4, 4) world_from_object.
    duration_s : simulated time at PyBullet's 240 Hz.
    tol_m, tol_deg : a body is at rest if it moves less than ``tol_m`` and turns less than
        ``tol_deg``.
    """
    client = _world(support)
    try:
        ids = [_add(client, b, p) for b, p in zip(bodies, poses)]
        for _ in range(int(round(duration_s / TIME_STEP_S))):
            pb.stepSimulation(physicsClientId=client)
        end = np.stack([body_world_from_object(client, i, b.com_in_object)
                        for i, b in zip(ids, bodies)]) if ids else np.zeros((0, 4, 4))
    finally:
        pb.disconnect(client)
    moved = np.array([np.linalg.norm(_com_world(e, b.com_in_object)
                                     - _com_world(p, b.com_in_object))
                      for b, p, e in zip(bodies, poses, end)])
    turned = np.array([rotation_angle_deg(p[:3, :3], e[:3, :3]) for p, e in zip(poses, end)])
    at_rest = (moved < tol_m) & (turned < tol_deg)
    return RestCheck(moved_m=moved, turned_deg=turned, end_poses=end, at_rest=at_rest)


def _settle(client: int, ids: list[int], max_steps: int) -> None:
    """Step until every body is nearly still (checked every 12 steps) or ``max_steps``."""
    for step in range(0, max_steps, 12):
        for _ in range(12):
            pb.stepSimulation(physicsClientId=client)
        still = True
        for i in ids:
            lin, ang = pb.getBaseVelocity(i, physicsClientId=client)
            if np.linalg.norm(lin) > REST_SPEED_MPS or np.linalg.norm(ang) > REST_SPIN_RADPS:
                still = False
                break
        if still and step >= 48:
            return


def _drop_pose(body: Body, rotation: np.ndarray, xy: np.ndarray, support: Support,
               placed: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """world_from_object that puts the body just above whatever is under its footprint.

    ``placed`` holds (lo (3,), hi (3,)) world AABBs of the bodies already in the scene.
    """
    verts = body.hull_vertices @ rotation.T
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    foot_lo, foot_hi = xy + lo[:2], xy + hi[:2]
    corners = np.array([[foot_lo[0], foot_lo[1]], [foot_lo[0], foot_hi[1]],
                        [foot_hi[0], foot_lo[1]], [foot_hi[0], foot_hi[1]]])
    floor = float(support.height_at(corners).max())
    for other_lo, other_hi in placed:
        overlap = np.all(foot_lo <= other_hi[:2]) and np.all(other_lo[:2] <= foot_hi)
        if overlap:
            floor = max(floor, float(other_hi[2]))
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = [xy[0], xy[1], floor + 0.004 - lo[2]]
    return pose


def _world_aabb(body: Body, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    verts = body.hull_vertices @ pose[:3, :3].T + pose[:3, 3]
    return verts.min(axis=0), verts.max(axis=0)


def plane_rotation(normal: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking +z to the unit ``normal``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    s = np.linalg.norm(axis)
    if s < 1e-12:
        return np.eye(3)
    return Rotation.from_rotvec(axis / s * np.arcsin(min(s, 1.0))).as_matrix()


def _drop_xy(body: Body, rotation: np.ndarray, placed: list[tuple[np.ndarray, np.ndarray]],
             rng: np.random.Generator, cluster_radius_m: float, stack_probability: float,
             adjacent_probability: float) -> np.ndarray:
    """Horizontal drop position: on top of, next to, or anywhere near the earlier bodies."""
    u = rng.random()
    if placed and u < stack_probability + adjacent_probability:
        lo, hi = placed[int(rng.integers(len(placed)))]
        centre = (lo[:2] + hi[:2]) / 2
        if u < stack_probability:
            return centre + rng.normal(0.0, 0.012, size=2)
        verts = body.hull_vertices @ rotation.T
        own = 0.5 * float(np.max(verts.max(axis=0)[:2] - verts.min(axis=0)[:2]))
        other = 0.5 * float(np.max(hi[:2] - lo[:2]))
        a = rng.uniform(0, 2 * np.pi)
        return centre + (own + other) * rng.uniform(0.55, 0.95) * np.array([np.cos(a),
                                                                             np.sin(a)])
    r = cluster_radius_m * np.sqrt(rng.random())
    a = rng.uniform(0, 2 * np.pi)
    return np.array([r * np.cos(a), r * np.sin(a)])


def _set_settling(client: int, body_id: int, on: bool) -> None:
    damping = SETTLE_DAMPING if on else DEFAULT_DAMPING
    rolling = SETTLE_ROLLING_FRICTION if on else 0.0
    pb.changeDynamics(body_id, -1, linearDamping=damping, angularDamping=damping,
                      rollingFriction=rolling, spinningFriction=rolling, physicsClientId=client)


def drop_bodies(bodies: list[Body], poses: list[Optional[np.ndarray]], support: Support,
                rng: np.random.Generator, cluster_radius_m: float, stack_probability: float,
                adjacent_probability: float) -> np.ndarray:
    """Drop every body whose pose is None onto the others and the support, then settle.

    Parameters
    ----------
    bodies : N bodies.
    poses : N entries, (4, 4) world_from_object of bodies already in place, or None for
        the bodies to drop (in list order).
    cluster_radius_m : horizontal radius of the disc (around the origin) bodies drop over
        when they aim at no earlier body.
    stack_probability : chance that a dropped body aims at the top of an earlier body.
    adjacent_probability : chance that it drops next to an earlier body, footprints
        overlapping, so that it leans on it or lands against it.

    Returns
    -------
    (N, 4, 4) world_from_object of all bodies after settling (not yet verified).
    """
    client = _world(support)
    try:
        ids: list[int] = []
        placed_aabbs: list[tuple[np.ndarray, np.ndarray]] = []
        tilt = plane_rotation(support.normal)
        for body, pose in zip(bodies, poses):
            if pose is None:
                if rng.random() < UPRIGHT_PROBABILITY:
                    local = Rotation.from_euler("z", rng.uniform(0, 2 * np.pi)).as_matrix()
                else:
                    local = Rotation.random(random_state=rng).as_matrix()
                rotation = tilt @ local
                xy = _drop_xy(body, rotation, placed_aabbs, rng, cluster_radius_m,
                              stack_probability, adjacent_probability)
                pose = _drop_pose(body, rotation, xy, support, placed_aabbs)
                body_id = _add(client, body, pose)
                _set_settling(client, body_id, True)
                ids.append(body_id)
                _settle(client, ids, max_steps=720)
            else:
                body_id = _add(client, body, pose)
                _set_settling(client, body_id, True)
                ids.append(body_id)
            placed_aabbs = [_world_aabb(b, body_world_from_object(client, i, b.com_in_object))
                            for b, i in zip(bodies, ids)]
        for i in ids:
            _set_settling(client, i, False)
        _settle(client, ids, max_steps=960)
        return np.stack([body_world_from_object(client, i, b.com_in_object)
                         for i, b in zip(ids, bodies)])
    finally:
        pb.disconnect(client)


def out_of_bounds(bodies: list[Body], poses: np.ndarray, support: Support,
                  max_radius_m: float) -> np.ndarray:
    """(N,) bool: COM farther than ``max_radius_m`` from the origin horizontally, or below
    the support plane."""
    out = []
    for b, p in zip(bodies, poses):
        com = _com_world(p, b.com_in_object)
        below = float(np.dot(support.normal, com - support.point)) < 0.0
        out.append(bool(np.linalg.norm(com[:2]) > max_radius_m or below))
    return np.asarray(out, dtype=bool)


def settle_and_verify(bodies: list[Body], poses: np.ndarray, support: Support,
                      duration_s: float, tol_m: float, tol_deg: float, max_radius_m: float,
                      max_rounds: int = 8,
                      log: Callable[[str], None] = lambda _m: None,
                      ) -> tuple[list[Body], np.ndarray]:
    """Keep simulating from rest until every body passes :func:`verify_rest`.

    Each round verifies the current poses; if a body fails, the poses at the end of that
    simulation become the next start (the simulation settles them further). From the third
    round on, the body that moved most (relative to the tolerances) is removed. Bodies out
    of bounds are removed at once.

    Returns
    -------
    (kept bodies, (K, 4, 4) their verified world_from_object); possibly empty.
    """
    bodies, poses = list(bodies), np.asarray(poses)
    for round_index in range(max_rounds):
        if not bodies:
            break
        gone = out_of_bounds(bodies, poses, support, max_radius_m)
        if gone.any():
            log(f"removing {int(gone.sum())} bodies that left the table")
            bodies = [b for b, g in zip(bodies, gone) if not g]
            poses = poses[~gone]
            continue
        check = verify_rest(bodies, poses, support, duration_s, tol_m, tol_deg)
        if check.at_rest.all():
            return bodies, poses
        score = np.maximum(check.moved_m / tol_m, check.turned_deg / tol_deg)
        log(f"round {round_index}: {int((~check.at_rest).sum())} bodies still moving "
            f"(max {check.moved_m.max() * 1000:.1f} mm, {check.turned_deg.max():.1f} deg)")
        poses = check.end_poses
        if round_index >= 2:
            worst = int(np.argmax(score))
            log(f"removing {bodies[worst].name}")
            bodies.pop(worst)
            poses = np.delete(poses, worst, axis=0)
    if bodies:
        check = verify_rest(bodies, poses, support, duration_s, tol_m, tol_deg)
        keep = check.at_rest
        if keep.all():
            return bodies, poses
    return [], np.zeros((0, 4, 4))


def contact_summary(bodies: list[Body], poses: np.ndarray, support: Support) -> dict:
    """Who touches whom at the given poses (one collision pass, no stepping).

    Returns
    -------
    dict with ``pairs`` (list of [i, j] body indices in contact, i < j), ``on_support``
    (list of bool per body: touches the support plane) and ``stacked`` (indices of bodies
    resting only on other bodies).
    """
    client = _world(support)
    try:
        ids = [_add(client, b, p) for b, p in zip(bodies, poses)]
        pb.performCollisionDetection(physicsClientId=client)
        index = {body_id: k for k, body_id in enumerate(ids)}
        pairs, on_support = set(), [False] * len(ids)
        for c in pb.getContactPoints(physicsClientId=client):
            a, b, distance_m = c[1], c[2], c[8]
            if distance_m > CONTACT_GAP_M:
                continue
            if a in index and b in index:
                pairs.add(tuple(sorted((index[a], index[b]))))
            elif a in index or b in index:
                on_support[index[a] if a in index else index[b]] = True
    finally:
        pb.disconnect(client)
    touching = {k for pair in pairs for k in pair}
    stacked = [k for k in range(len(bodies)) if not on_support[k] and k in touching]
    return {"pairs": sorted([list(p) for p in pairs]), "on_support": on_support,
            "stacked": stacked}
