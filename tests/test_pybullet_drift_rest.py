"""physopt's PyBullet check ends a rollout early once every body is at rest
(r2s/physopt/pybullet_world.py ``drift(stop_at_rest=True)``): the drift it reports must be
the full rollout's, and a body that is still moving must not be cut short."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import trimesh

from r2s.physopt.pybullet_world import SimBody, build_world, drift


def _pose(z: float, tilt_deg: float = 0.0) -> np.ndarray:
    p = np.eye(4)
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    p[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    p[2, 3] = z
    return p


def _drift_and_steps(body: trimesh.Trimesh, pose: np.ndarray, stop_at_rest: bool):
    world = build_world([SimBody(1, [body], pose, 0.2, np.zeros(3), 0.8)],
                        [0, 0, 0], [0, 0, 1], 0.8)
    calls = [0]
    step = pb.stepSimulation

    def counted(*args, **kwargs):
        calls[0] += 1
        return step(*args, **kwargs)

    pb.stepSimulation = counted
    try:
        out = drift(world, {1: pose}, 3.0, stop_at_rest=stop_at_rest)[1]
    finally:
        pb.stepSimulation = step
        world.close()
    return out, calls[0]


def test_a_resting_box_stops_early_with_the_full_rollouts_drift():
    """A 60 mm cube set on the table: the early stop ends well before 3 s (720 steps; the
    count includes the rest probe's nudge, 240 steps) and reports the full rollout's drift
    within 0.2 mm and 0.1 deg."""
    box = trimesh.creation.box([0.06] * 3)
    (t_full, r_full), n_full = _drift_and_steps(box, _pose(0.03), stop_at_rest=False)
    (t_early, r_early), n_early = _drift_and_steps(box, _pose(0.03), stop_at_rest=True)
    assert n_full == 720 and n_early < 360 + 240
    assert abs(t_early - t_full) < 2e-4 and abs(r_early - r_full) < 0.1
    assert t_full < 0.002


def test_a_toppling_slab_is_not_cut_short():
    """A 20 x 60 x 120 mm slab standing on its 20 x 60 end, tipped 25 deg (its centre of
    mass is past the edge: tan(25 deg) * 60 mm = 28 mm > 10 mm), falls flat: the rollout
    runs until it lies still and both runs agree it turned about 65-90 deg."""
    slab = trimesh.creation.box([0.02, 0.06, 0.12])
    z = 0.06 * np.cos(np.radians(25)) + 0.01 * np.sin(np.radians(25))
    (t_full, r_full), _ = _drift_and_steps(slab, _pose(z, 25.0), stop_at_rest=False)
    (t_early, r_early), n_early = _drift_and_steps(slab, _pose(z, 25.0), stop_at_rest=True)
    assert 60.0 < r_full < 95.0 and abs(r_early - r_full) < 1.0
    assert abs(t_early - t_full) < 1e-3 and n_early > 120


def test_a_cube_balanced_on_its_edge_is_not_taken_for_at_rest():
    """A 50 mm cube turned 45 deg onto an edge, its centre of mass exactly above it: the
    first 0.5 s are still (an unstable equilibrium), then numerical noise tips it onto a
    face (45 deg). The nudge probe sees the equilibrium is unstable, so the early-stopping
    run is followed to the end and reports the full rollout's drift exactly (the probe's
    state is restored); without the probe it would report about 0 deg."""
    cube = trimesh.creation.box([0.05] * 3)
    pose = _pose(0.025 * np.sqrt(2.0), 45.0)
    (t_full, r_full), _ = _drift_and_steps(cube, pose, stop_at_rest=False)
    (t_early, r_early), n_early = _drift_and_steps(cube, pose, stop_at_rest=True)
    assert abs(r_full - 45.0) < 1.0
    assert r_early == r_full and t_early == t_full
    assert n_early > 720
