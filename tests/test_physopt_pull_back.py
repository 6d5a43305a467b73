"""physopt's pull-back: poses the solve changed after depenetration go back to where it
started, as far as the scene still rests in the judge's worlds."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from r2s.io.state import SceneState, SupportPlane
from r2s.metrics.observation import pose_displacement
from r2s.physopt.params import ObjectParams, inner_box
from r2s.physopt.pull_back import interpolated_pose, moved_objects, pull_back
from r2s.physopt.repair import check, judge_orders, world_factory
from r2s.physopt.settings import RepairSettings


def _pose(x: float, y: float, z: float, rotvec_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    p = np.eye(4)
    p[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    p[:3, 3] = x, y, z
    return p


def test_interpolated_pose_moves_the_centre_straight_and_turns_on_the_shortest_arc():
    start = _pose(0.10, 0.0, 0.05)
    current = _pose(0.12, 0.01, 0.05, (0.0, 0.0, 40.0))
    centre = np.array([0.01, 0.0, 0.0])  # object frame
    assert np.allclose(interpolated_pose(start, current, centre, 0.0), current, atol=1e-12)
    assert np.allclose(interpolated_pose(start, current, centre, 1.0), start, atol=1e-12)
    half = interpolated_pose(start, current, centre, 0.5)
    def world_centre(p):
        return p[:3, :3] @ centre + p[:3, 3]
    assert np.allclose(world_centre(half), 0.5 * (world_centre(start) + world_centre(current)),
                       atol=1e-12)
    m, deg = pose_displacement(start, half, centre)
    assert deg == pytest.approx(20.0, abs=1e-6)  # half of 40 degrees about z
    assert m == pytest.approx(0.5 * np.hypot(0.02 + 0.01 * (np.cos(np.radians(40)) - 1),
                                             0.01 + 0.01 * np.sin(np.radians(40))), abs=1e-9)


def _boxes(start_poses: dict, current_poses: dict, seen_poses: dict | None = None,
           one_by_one: bool = False):
    """Two 6 cm cubes on the table (z = 0); ``current_poses`` where the repairs left them,
    ``start_poses`` where the solve started, ``seen_poses`` where init saw them; the
    one-by-one step only when asked (the other tests are about the group candidates)."""
    cube = trimesh.creation.box([0.06] * 3)
    lo, hi = inner_box(cube.bounds)
    params = {i: ObjectParams(world_from_object=current_poses[i], mass_kg=0.2,
                              nominal_mass_kg=0.2, com_in_object=np.zeros(3), friction=0.6,
                              com_lo=lo, com_hi=hi) for i in (1, 2)}
    state = SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[])
    settings = RepairSettings()
    make_world = world_factory({1: [cube], 2: [cube]}, state, [1, 2], settings)
    drift = check(make_world, params, judge_orders([1, 2]), settings.verify_duration_s)
    assert settings.moving(drift) == []  # the repaired state rests
    log = {"objects": {1: [], 2: []}, "rounds": []}
    centres = {1: np.zeros(3), 2: np.zeros(3)}
    out, out_drift = pull_back(make_world, params, drift, start_poses, centres, [1, 2],
                               settings, log, seen=seen_poses, one_by_one=one_by_one)
    return params, out, out_drift, log, settings


@pytest.mark.slow
def test_objects_that_rest_where_the_solve_started_go_back_there():
    start = {1: _pose(0.0, 0.0, 0.03), 2: _pose(0.1, 0.0, 0.03, (0, 0, 10))}
    current = {1: _pose(0.004, 0.002, 0.03, (0, 0, 3)), 2: _pose(0.1, 0.0, 0.03, (0, 0, 10))}
    params, out, drift, log, settings = _boxes(start, current)
    assert log["pull_back"]["moved"] == [1]
    assert log["pull_back"]["kept"] == "all"
    assert np.allclose(out[1].world_from_object, start[1], atol=1e-9)
    assert out[2] is params[2]  # not moved by the repairs: untouched
    assert settings.moving(drift) == []
    assert any("pulled back" in line for line in log["objects"][1])


@pytest.mark.slow
def test_a_start_pose_that_would_not_rest_is_not_restored():
    # started balanced on an edge, 30 degrees from flat: it falls from there, and from the
    # halfway pose (15 degrees); the repaired pose, flat on the table, stands
    start = {1: _pose(0.0, 0.0, 0.03 * np.sqrt(2) * np.cos(np.radians(15)) + 0.0005,
                     (0, 30, 0)), 2: _pose(0.15, 0.0, 0.03)}
    current = {1: _pose(0.0, 0.0, 0.03), 2: _pose(0.15, 0.0, 0.03)}
    params, out, drift, log, settings = _boxes(start, current)
    assert log["pull_back"]["moved"] == [1]
    assert log["pull_back"]["kept"] is None
    assert [t["candidate"] for t in log["pull_back"]["tried"]] == ["all", "halfway"]
    assert all(t["moving"] == [1] for t in log["pull_back"]["tried"])
    assert np.allclose(out[1].world_from_object, current[1])
    assert settings.moving(drift) == []


def test_moved_objects_uses_the_thresholds_and_skips_fixed_objects_or_ones_without_a_start():
    cube = trimesh.creation.box([0.06] * 3)
    lo, hi = inner_box(cube.bounds)

    def params_at(pose, movable=True):
        return ObjectParams(world_from_object=pose, mass_kg=0.2, nominal_mass_kg=0.2,
                            com_in_object=np.zeros(3), friction=0.6, com_lo=lo, com_hi=hi,
                            movable=movable)
    start = {i: _pose(0, 0, 0.03) for i in (1, 2, 3, 4)}
    params = {1: params_at(_pose(0.0004, 0, 0.03)),        # 0.4 mm: not moved
              2: params_at(_pose(0.0006, 0, 0.03)),        # 0.6 mm: moved
              3: params_at(_pose(0, 0, 0.03, (0, 0, 0.6))),  # 0.6 deg: moved
              4: params_at(_pose(0.01, 0, 0.03), movable=False),
              5: params_at(_pose(0.01, 0, 0.03))}          # no start pose
    assert moved_objects(params, start, {i: np.zeros(3) for i in params}) == [2, 3]


@pytest.mark.slow
def test_objects_go_back_to_where_init_saw_them_when_that_rests():
    # init saw cube 1 at x = -5 mm, turned 8 deg; geomopt and the depenetration started the
    # solve 6 mm away, the repairs moved it 3 mm more: both poses rest, the seen one is kept
    seen = {1: _pose(-0.005, 0.0, 0.03, (0, 0, 8)), 2: _pose(0.1, 0.0, 0.03)}
    start = {1: _pose(0.001, 0.0, 0.03), 2: _pose(0.1, 0.0, 0.03)}
    current = {1: _pose(0.004, 0.0, 0.03), 2: _pose(0.1, 0.0, 0.03)}
    params, out, drift, log, settings = _boxes(start, current, seen)
    assert log["pull_back"]["away_from_seen"] == [1]
    assert log["pull_back"]["kept"] == "seen"
    assert np.allclose(out[1].world_from_object, seen[1], atol=1e-9)
    assert out[2] is params[2]
    assert settings.moving(drift) == []
    assert any("towards its seen pose" in line for line in log["objects"][1])


@pytest.mark.slow
def test_a_seen_pose_that_would_not_rest_leaves_the_start_candidates():
    # seen balanced on an edge, 30 degrees from flat (it falls from there); the solve's
    # start, flat 4 mm from the repaired pose, rests: "seen" fails, "all" is kept
    seen = {1: _pose(0.0, 0.0, 0.03 * np.sqrt(2) * np.cos(np.radians(15)) + 0.0005,
                     (0, 30, 0)), 2: _pose(0.15, 0.0, 0.03)}
    start = {1: _pose(0.0, 0.0, 0.03), 2: _pose(0.15, 0.0, 0.03)}
    current = {1: _pose(0.004, 0.0, 0.03), 2: _pose(0.15, 0.0, 0.03)}
    params, out, drift, log, settings = _boxes(start, current, seen)
    assert [t["candidate"] for t in log["pull_back"]["tried"]] == ["seen", "all"]
    assert log["pull_back"]["tried"][0]["moving"] == [1]
    assert log["pull_back"]["kept"] == "all"
    assert np.allclose(out[1].world_from_object, start[1], atol=1e-9)
    assert settings.moving(drift) == []


@pytest.mark.slow
def test_a_seen_pose_inside_the_table_is_left_out_before_any_check():
    # init saw cube 1 sunk 4 mm into the table; the depenetrated start rests: "seen" is
    # refused for the overlap (no rollout), then "all" goes back to the start
    seen = {1: _pose(0.0, 0.0, 0.026), 2: _pose(0.15, 0.0, 0.03)}
    start = {1: _pose(0.0, 0.0, 0.03), 2: _pose(0.15, 0.0, 0.03)}
    current = {1: _pose(0.004, 0.0, 0.03), 2: _pose(0.15, 0.0, 0.03)}
    params, out, drift, log, settings = _boxes(start, current, seen)
    tried = log["pull_back"]["tried"]
    assert tried[0]["candidate"] == "seen" and tried[0]["overlapping"] == [1]
    assert log["pull_back"]["kept"] == "all"
    assert np.allclose(out[1].world_from_object, start[1], atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("seen_x, closer_refused, kept_fraction, kept_x", [
    (0.056, False, 0.75, 0.061),  # 4 mm into cube 2 where seen; at 3/4 a 1 mm gap rests
    (0.046, True, 0.5, 0.061),    # 14 mm into it; at 3/4 still 6.5 mm in, halfway rests
])
def test_one_object_goes_as_far_back_as_rests_when_its_seen_pose_overlaps_a_neighbour(
        seen_x, closer_refused, kept_fraction, kept_x):
    # init saw cube 1 partly inside cube 2 (60 mm cubes); the solve started and ended at
    # 76 mm. Every group candidate is refused for the overlap; one by one, the seen pose is
    # refused too, halfway rests and is kept, and three quarters of the way (half of what
    # is left) is tried next and kept where it neither overlaps nor moves.
    seen = {1: _pose(seen_x, 0.0, 0.03), 2: _pose(0.0, 0.0, 0.03)}
    start = {1: _pose(0.076, 0.0, 0.03), 2: _pose(0.0, 0.0, 0.03)}
    params, out, drift, log, settings = _boxes(start, dict(start), seen, one_by_one=True)
    record = log["pull_back"]
    assert record["away_from_seen"] == [1]
    assert [(t["candidate"], t["fraction"]) for t in record["tried"]] == [
        ("seen", 1.0), ("object 1", 1.0), ("object 1", 0.5), ("object 1 closer", 0.5)]
    assert record["tried"][1]["overlapping"] == [1]
    assert ("overlapping" in record["tried"][3]) is closer_refused
    assert record["one_by_one"] == [{"id": 1, "fraction": kept_fraction}]
    assert out[1].world_from_object[:3, 3] == pytest.approx([kept_x, 0.0, 0.03], abs=1e-9)
    assert out[2] is params[2]
    assert settings.moving(drift) == []
