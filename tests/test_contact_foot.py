"""A flat foot under a rolling object's lowest point (r2s/physopt/contact_foot.py).

Known answers: a sphere of radius r cut h above its lowest point has a cap whose base is a
disc of area pi (2 r h - h^2); the foot keeps the lowest point where it was; a box resting
on a face is its own foot (same volume); and, in PyBullet (the judge's engine), a ball
whose centre of mass sits 5 mm off its lowest point rolls away on a table without the foot
and rests on it with a 2 mm foot (12 mm radius).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.physopt.contact_foot import with_foot
from r2s.physopt.pybullet_world import SimBody, build_world, drift

R_M = 0.035
UP = np.array([0.0, 0.0, 1.0])


def _ball() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=R_M)


def test_a_ball_gets_a_disc_of_the_cap_area_at_its_lowest_point():
    ball = _ball()
    pose = np.eye(4)
    (footed,), area = with_foot([ball], pose, UP, height_m=0.002)
    expected = np.pi * (2 * R_M * 0.002 - 0.002 ** 2)
    assert area == pytest.approx(expected, rel=0.1)
    assert footed.vertices[:, 2].min() == pytest.approx(ball.vertices[:, 2].min(), abs=1e-9)
    assert footed.is_convex and footed.volume > ball.volume
    # the added material is a thin layer in the 2 mm band above the lowest point (a prism
    # of the disc would add area * h less the cap; the faceted sphere's lowest facets add
    # a little more)
    assert 0 < footed.volume - ball.volume < 2 * area * 0.002


def test_a_tilted_pose_puts_the_foot_under_the_world_lowest_point():
    ball = _ball()
    ball.apply_translation([0.0, 0.0, 0.01])  # off the object origin
    pose = np.eye(4)
    pose[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [1, 0, 0])[:3, :3]
    (footed,), area = with_foot([ball], pose, UP, height_m=0.002)
    world = footed.vertices @ pose[:3, :3].T
    bottom = world[:, 2].min()
    flat = world[np.abs(world[:, 2] - bottom) < 1e-6]
    assert len(flat) >= 8 and area > 0
    assert np.ptp(flat[:, 0]) == pytest.approx(2 * np.sqrt(2 * R_M * 0.002), rel=0.15)


def test_a_box_on_its_face_is_its_own_foot():
    box = trimesh.creation.box((0.08, 0.06, 0.05))
    (footed,), _ = with_foot([box], np.eye(4), UP, height_m=0.002)
    assert footed.volume == pytest.approx(box.volume, rel=1e-9)


def test_a_piece_out_of_reach_is_kept_as_it_is():
    low = trimesh.creation.box((0.04, 0.04, 0.04))
    high = trimesh.creation.box((0.02, 0.02, 0.02))
    high.apply_translation([0.0, 0.0, 0.05])
    pieces, _ = with_foot([low, high], np.eye(4), UP, height_m=0.002)
    assert pieces[1] is high


def _rolls(pieces) -> tuple[float, float]:
    pose = np.eye(4)
    pose[2, 3] = R_M  # resting on its lowest point on the table z = 0
    com = np.array([0.005, 0.0, 0.0])  # 5 mm off the contact
    world = build_world([SimBody(1, pieces, pose, 0.2, com, 0.8)], [0, 0, 0], [0, 0, 1], 0.9)
    try:
        return drift(world, {1: pose}, 3.0)[1]
    finally:
        world.close()


def test_pybullet_the_off_centre_ball_rolls_without_the_foot_and_rests_with_it():
    ball = _ball()
    moved_m, turned_deg = _rolls([ball])
    assert moved_m > 0.02 or turned_deg > 20.0
    footed, _ = with_foot([ball], np.eye(4), UP, height_m=0.002)
    moved_m, turned_deg = _rolls(footed)
    assert moved_m < 0.002 and turned_deg < 2.0


def test_physopt_gives_a_foot_to_what_moves_in_the_first_check_only():
    from r2s.io.state import SceneState, SupportPlane
    from r2s.physopt.params import ObjectParams, inner_box
    from r2s.physopt.repair import world_factory
    from r2s.physopt.settings import RepairSettings
    from r2s.physopt.solve import give_feet

    ball, box = _ball(), trimesh.creation.box((0.06, 0.06, 0.04))
    poses = {1: np.eye(4), 2: np.eye(4)}
    poses[1][:3, 3] = [0.0, 0.0, R_M]
    poses[2][:3, 3] = [0.2, 0.0, 0.02]
    params = {}
    for i, mesh, com in ((1, ball, [0.005, 0.0, 0.0]), (2, box, [0.0, 0.0, 0.0])):
        lo, hi = inner_box(mesh.bounds)
        params[i] = ObjectParams(world_from_object=poses[i], mass_kg=0.2, nominal_mass_kg=0.2,
                                 com_in_object=np.asarray(com), friction=0.8, com_lo=lo,
                                 com_hi=hi)
    state = SceneState(stage="physopt", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[])
    settings = RepairSettings(foot_height_m=0.002)
    pieces = {1: [ball], 2: [box]}
    make_world = world_factory(pieces, state, [1, 2], settings)
    log = {"objects": {1: [], 2: []}}
    give_feet(make_world, pieces, params, [1, 2], state, settings, log)
    assert list(log["feet"]) == ["1"]  # the box rests: no foot
    assert pieces[2][0] is box and pieces[1][0] is not ball
    assert log["feet"]["1"] == pytest.approx(1e6 * np.pi * (2 * R_M * 0.002 - 0.002 ** 2),
                                             rel=0.1)
