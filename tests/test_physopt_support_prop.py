"""A hidden prop on a parent, under a child that falls off it (r2s/physopt/support_prop.py).

The scene: a parent whose top is a 20 mm wide pillar at one side (x 20..40 mm, top at
z = 60 mm) on an 80 x 80 mm base only 10 mm high, as a completed cup is where a box lying
across it hid its rim; a 100 x 40 x 10 mm plank lies on the pillar, centred at x = 0, so
its centre of mass is 20 mm off the pillar. Known answers: the prop's top is the plank's
underside clipped to the parent's 80 x 80 mm footprint (80 x 40 mm = 3200 mm^2) at
60 mm less the 0.5 mm gap; with a ``hidden`` that says the camera saw past x >= 0, only
the half x < 0 (1600 mm^2); in PyBullet the plank tips off without the prop and rests
with it.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.geometry.camera import intrinsics, look_at
from r2s.physopt.pybullet_world import SimBody, build_world, drift
from r2s.physopt.support_prop import GAP_M, depth_hidden, prop_points_world, with_prop

UP = np.array([0.0, 0.0, 1.0])
PARENT, CHILD = 1, 2


def _box(extents, centre) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents)
    box.apply_translation(centre)
    return box


def _parent() -> list[trimesh.Trimesh]:
    return [_box((0.08, 0.08, 0.01), (0.0, 0.0, 0.005)),
            _box((0.02, 0.08, 0.05), (0.03, 0.0, 0.035))]


def _child() -> tuple[list[trimesh.Trimesh], np.ndarray]:
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 0.065]
    return [trimesh.creation.box((0.10, 0.04, 0.01))], pose


def test_the_prop_is_the_childs_underside_over_the_parent_footprint():
    child, child_pose = _child()
    corners = prop_points_world(child, child_pose, _parent(), np.eye(4), UP)
    top = corners[corners[:, 2] > 0.055]
    assert np.allclose(top[:, 2], 0.06 - GAP_M, atol=1e-9)
    assert top[:, 0].min() == pytest.approx(-0.04, abs=0.0025)  # the parent's footprint
    assert top[:, 0].max() == pytest.approx(0.04, abs=0.0025)
    assert top[:, 1].min() == pytest.approx(-0.02, abs=0.0025)  # the plank's width
    assert top[:, 1].max() == pytest.approx(0.02, abs=0.0025)
    pieces, area_m2 = with_prop(child, child_pose, _parent(), np.eye(4), UP)
    assert len(pieces) == 3
    assert area_m2 == pytest.approx(0.08 * 0.04, rel=0.1)


def test_the_prop_leaves_out_what_the_camera_saw_past():
    child, child_pose = _child()
    _, area_m2 = with_prop(child, child_pose, _parent(), np.eye(4), UP,
                           hidden=lambda p: p[:, 0] < 0.0)
    assert area_m2 == pytest.approx(0.04 * 0.04, rel=0.1)
    parent = _parent()
    pieces, area_m2 = with_prop(child, child_pose, parent, np.eye(4), UP,
                                hidden=lambda p: np.zeros(len(p), dtype=bool))
    assert area_m2 == 0.0 and pieces is parent


def test_no_prop_under_a_child_beside_the_parent():
    child, child_pose = _child()
    child_pose[0, 3] = 0.2  # the plank lies 150 mm away, over nothing of the parent
    parent = _parent()
    pieces, area_m2 = with_prop(child, child_pose, parent, np.eye(4), UP)
    assert area_m2 == 0.0 and pieces is parent


def _plank_drift(parent_pieces) -> tuple[float, float]:
    child, child_pose = _child()
    world = build_world([SimBody(PARENT, parent_pieces, np.eye(4), 0.0, np.zeros(3), 0.8),
                         SimBody(CHILD, child, child_pose, 0.05, np.zeros(3), 0.8)],
                        [0, 0, 0], UP, 0.9)
    try:
        return drift(world, {PARENT: np.eye(4), CHILD: child_pose}, 3.0)[CHILD]
    finally:
        world.close()


def test_pybullet_the_plank_tips_off_without_the_prop_and_rests_with_it():
    moved_m, turned_deg = _plank_drift(_parent())
    assert moved_m > 0.01 or turned_deg > 20.0
    child, child_pose = _child()
    propped, _ = with_prop(child, child_pose, _parent(), np.eye(4), UP)
    moved_m, turned_deg = _plank_drift(propped)
    assert moved_m < 0.002 and turned_deg < 2.0


def test_depth_hidden_against_a_flat_observed_surface():
    # a camera 1 m above the table looking straight down sees a surface at z = 0.5 m,
    # except in the image's left half (no reading)
    K = intrinsics(64, 48, 60.0)
    world_from_camera = look_at(np.array([0.0, 0.0, 1.0]), np.zeros(3), up=(0.0, 1.0, 0.0))
    depth = np.full((48, 64), 0.5, dtype=np.float32)
    left = np.zeros((48, 64), dtype=bool)
    left[:, :32] = True
    depth[left] = np.nan
    hidden = depth_hidden(depth, K, world_from_camera)
    _, col = np.nonzero(~left)
    x_right = float(world_from_camera[:3, 0] @ [1.0, 0.0, 0.0])  # +x of the image, in world x
    probe = np.array([[0.05 * np.sign(x_right), 0.0, 0.40],   # behind the surface: hidden
                      [0.05 * np.sign(x_right), 0.0, 0.60],   # in front of it: seen past
                      [-0.05 * np.sign(x_right), 0.0, 0.60],  # where there is no reading
                      [5.0, 0.0, 0.40]])                       # outside the image
    assert hidden(probe).tolist() == [True, False, True, True]


def test_physopt_props_the_parent_of_what_falls_off_it_only():
    from r2s.io.state import SceneState, SupportPlane
    from r2s.physopt.params import ObjectParams, inner_box
    from r2s.physopt.repair import world_factory
    from r2s.physopt.settings import RepairSettings
    from r2s.physopt.solve import give_props

    child, child_pose = _child()
    lone = _box((0.04, 0.04, 0.04), (0.0, 0.0, 0.0))
    lone_pose = np.eye(4)
    lone_pose[:3, 3] = [0.3, 0.0, 0.02]
    pieces = {PARENT: _parent(), CHILD: child, 3: [lone]}
    poses = {PARENT: np.eye(4), CHILD: child_pose, 3: lone_pose}
    params = {}
    for i, object_pieces in pieces.items():
        lo, hi = inner_box(trimesh.util.concatenate(object_pieces).bounds)
        params[i] = ObjectParams(world_from_object=poses[i], mass_kg=0.05, nominal_mass_kg=0.05,
                                 com_in_object=np.zeros(3), friction=0.8, com_lo=lo, com_hi=hi,
                                 movable=i != PARENT)
    state = SceneState(stage="physopt", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[])
    settings = RepairSettings()
    make_world = world_factory(pieces, state, [PARENT, CHILD, 3], settings)
    log = {"objects": {i: [] for i in pieces}}
    give_props(make_world, pieces, params, [PARENT, CHILD, 3], {CHILD: PARENT, 3: 0}, state,
               settings, log, None)
    assert list(log["support_props"]) == [str(CHILD)]
    assert log["support_props"][str(CHILD)]["parent"] == PARENT
    assert len(pieces[PARENT]) == 3 and pieces[3] == [lone]


def test_the_solution_with_props_is_kept_when_it_rests_better_or_looks_no_worse():
    from r2s.physopt.swap_choice import SolutionSummary, prefer_propped

    without = SolutionSummary(flagged=1, moving=0, pooled_iou=0.80)
    assert prefer_propped(without, SolutionSummary(0, 0, 0.70))  # fewer flagged
    assert not prefer_propped(without, SolutionSummary(0, 1, 0.95))  # more still moving
    assert prefer_propped(without, SolutionSummary(1, 0, 0.80))  # alike: the view decides
    assert not prefer_propped(without, SolutionSummary(1, 0, 0.79))
    assert not prefer_propped(without, SolutionSummary(2, 0, 0.95))
    assert prefer_propped(SolutionSummary(1, 0, None), SolutionSummary(1, 0, None))


def test_props_are_tried_for_what_fell_off_another_and_was_left_flagged_or_moving():
    from r2s.physopt.solve import Solved
    from r2s.stages.physopt import Options, _fallen_and_left

    # first check: 2 fell 60 mm off object 1, 3 turned 40 deg off the table, 4 turned
    # 40 deg off object 1, 5 crept 3 mm on object 1
    log = {"rounds": [{"drift": {"2": [0.06, 10.0], "3": [0.001, 40.0], "4": [0.001, 40.0],
                                 "5": [0.003, 1.0]}}]}
    parents = {2: 1, 3: 0, 4: 1, 5: 1}
    opt = Options()
    solved = Solved(params={}, drift={2: (0.0, 0.0), 3: (0.0, 0.0), 4: (0.02, 9.0),
                                      5: (0.0, 0.0)},
                    flags={2: "moved", 3: "moved", 5: "moved"}, displacement={})
    assert _fallen_and_left(log, parents, solved, opt) == [2, 4]  # 3: the table; 5: no fall
    rested = Solved(params={}, drift={i: (0.0, 0.0) for i in parents}, flags={},
                    displacement={})
    assert _fallen_and_left(log, parents, rested, opt) == []


def test_props_that_carry_objects_farther_from_their_points_are_turned_down():
    from r2s.physopt.swap_choice import UCD_GROWTH, SolutionSummary, prefer_propped

    without = SolutionSummary(flagged=2, moving=0, pooled_iou=0.52, ucd_mm=20.0)
    # the measured case (fresh7 scene_03): more IoU, UCD 20 -> 34 mm
    assert not prefer_propped(without, SolutionSummary(2, 0, 0.56, 34.0))
    assert prefer_propped(without, SolutionSummary(2, 0, 0.56, 20.0 * UCD_GROWTH))
    assert prefer_propped(without, SolutionSummary(1, 0, 0.56, 34.0))  # fewer flagged first
