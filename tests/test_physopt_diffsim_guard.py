"""physopt's guard on the differentiable step: PyBullet's check decides, per object, whether
the step's parameters or the ones before it are kept."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from r2s.io.state import SceneState, SupportPlane
from r2s.physopt.diffsim_guard import keep_diffsim_where_it_rests
from r2s.physopt.params import ObjectParams, inner_box
from r2s.physopt.repair import check, judge_orders, world_factory
from r2s.physopt.settings import RepairSettings

HALF_M = 0.03  # the cubes' half edge


def _on_edge(x: float, tilt_deg: float, lift_m: float = 0.0) -> np.ndarray:
    """A cube turned ``tilt_deg`` about the world x axis with its lowest edge ``lift_m``
    above the table (z = 0); 0 deg: flat on the table."""
    t = np.radians(tilt_deg)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec([t, 0.0, 0.0]).as_matrix()
    pose[:3, 3] = x, 0.0, HALF_M * (np.cos(t) + np.sin(t)) + lift_m
    return pose


def _params(poses: dict[int, np.ndarray]) -> dict[int, ObjectParams]:
    lo, hi = inner_box(np.array([[-HALF_M] * 3, [HALF_M] * 3]))
    return {i: ObjectParams(world_from_object=p, mass_kg=0.2, nominal_mass_kg=0.2,
                            com_in_object=np.zeros(3), friction=0.6, com_lo=lo, com_hi=hi)
            for i, p in poses.items()}


def _guard(before: dict, after: dict, eligible=(1, 2)):
    cube = trimesh.creation.box([2 * HALF_M] * 3)
    state = SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[])
    settings = RepairSettings()
    make_world = world_factory({1: [cube], 2: [cube]}, state, [1, 2], settings)
    log = {"objects": {1: [], 2: []}, "rounds": []}
    before_p, after_p = _params(before), _params(after)
    out = keep_diffsim_where_it_rests(make_world, before_p, after_p, [1, 2], eligible,
                                      settings, log)
    drift = check(make_world, out, judge_orders([1, 2]), settings.verify_duration_s)
    return before_p, after_p, out, log, settings.moving(drift)


@pytest.mark.slow
def test_an_object_the_step_tipped_onto_an_edge_goes_back_to_where_it_rested():
    # the step left cube 1 balanced on an edge at 20 deg: PyBullet lets it fall flat
    before = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 0.0)}
    after = {1: _on_edge(0.0, 20.0), 2: _on_edge(0.15, 0.0)}
    before_p, after_p, out, log, moving = _guard(before, after)
    assert log["diffsim_reverted"] == [1]
    assert out[1] is before_p[1]
    assert out[2] is after_p[2]  # it rested after the step: the step's result stays
    assert moving == []
    assert any("diffsim step reverted" in line for line in log["objects"][1])


@pytest.mark.slow
def test_nothing_changes_when_the_step_left_everything_at_rest():
    before = {1: _on_edge(0.0, 20.0), 2: _on_edge(0.15, 0.0)}  # the step fixed cube 1
    after = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 0.0)}
    _, after_p, out, log, moving = _guard(before, after)
    assert log["diffsim_reverted"] == []
    assert out is after_p
    assert moving == []


@pytest.mark.slow
def test_a_start_that_falls_further_is_not_restored():
    # after the step cube 2 tips from a 15 deg edge (about 15 deg, under 1 cm); before it, it
    # hung 20 cm above the table and would fall that far: the step's result stays
    before = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 45.0, lift_m=0.2)}
    after = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 15.0)}
    _, after_p, out, log, moving = _guard(before, after)
    assert log["diffsim_reverted"] == []
    assert out is after_p
    assert moving == [2]


@pytest.mark.slow
@pytest.mark.parametrize("lift_before_m, restored", [(0.15, False), (0.05, True)])
def test_a_start_is_restored_only_when_it_falls_at_most_half_as_far(lift_before_m, restored):
    # cube 2 drops 20 cm after the step; without it 15 cm (more than half: the step's
    # result stays) or 5 cm (under half: put back, and the repair rounds take it from
    # there); STEP_FACTOR
    before = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 0.0, lift_m=lift_before_m)}
    after = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 0.0, lift_m=0.2)}
    before_p, after_p, out, log, moving = _guard(before, after)
    assert log["diffsim_reverted"] == ([2] if restored else [])
    assert out[2] is (before_p[2] if restored else after_p[2])
    assert out[1] is after_p[1]
    assert moving == [2]


@pytest.mark.slow
def test_a_registered_prior_is_left_as_the_step_left_it():
    # the same tipped cube as the first test, but a prior (not eligible): kept tipped
    before = {1: _on_edge(0.0, 0.0), 2: _on_edge(0.15, 0.0)}
    after = {1: _on_edge(0.0, 20.0), 2: _on_edge(0.15, 0.0)}
    _, after_p, out, log, moving = _guard(before, after, eligible=(2,))
    assert log["diffsim_reverted"] == []
    assert out is after_p
    assert moving == [1]
