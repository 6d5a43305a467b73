"""physopt on hand-built scenes: penetrations resolved, the PyBullet check passes, and the
result is recorded per object."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pybullet as pb
import trimesh

from r2s.io.mesh_io import save_mesh
from r2s.io.state import ObjectState, SceneState, SupportPlane, read_state, write_state
from r2s.physopt.hierarchy import descendants, order_root_to_leaves
from r2s.physopt.pybullet_world import SimBody, build_world, depenetrate, penetrations
from r2s.runner.base import run_stage
from r2s.io.manifest import StageRecord, load_manifest, save_manifest
from r2s.stages.physopt import STAGE as PHYSOPT, Options as PhysOptions


def _pose(z: float, x: float = 0.0) -> list:
    p = np.eye(4)
    p[0, 3], p[2, 3] = x, z
    return p.tolist()


def _box_scene(root: Path, boxes: list[tuple[int, str, float, list]]) -> Path:
    """init/ state of cube boxes (id, label, edge m, world_from_object), init marked done."""
    d = root / "init"
    (d / "meshes").mkdir(parents=True)
    objects = []
    for oid, label, edge_m, pose in boxes:
        save_mesh(trimesh.creation.box([edge_m] * 3), d / "meshes" / f"{oid}.glb")
        objects.append(ObjectState(id=oid, label=label, mesh=f"meshes/{oid}.glb",
                                   world_from_object=pose))
    write_state(d, SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                              objects=objects))
    m = load_manifest(root / "manifest.json")
    m.stages["init"] = StageRecord(status="done")
    save_manifest(root / "manifest.json", m)
    return root


def _stack_scene(root: Path) -> Path:
    """A 10 cm box sunk 4 mm into the table, a 6 cm box sunk 3 mm into it."""
    return _box_scene(root, [(1, "big", 0.1, _pose(0.046)), (2, "small", 0.06, _pose(0.127, 0.01))])


def test_depenetrate_moves_children_not_parents():
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    bodies = [SimBody(1, [box], np.array(_pose(0.045)), 1.0, np.zeros(3), 0.8),
              SimBody(2, [box], np.array(_pose(0.14)), 1.0, np.zeros(3), 0.8)]
    world = build_world(bodies, [0, 0, 0], [0, 0, 1], 0.8)
    try:
        assert len(penetrations(world)) == 2
        poses = depenetrate(world, [1, 2])
        assert not [p for p in penetrations(world) if p[2] > 1.5e-3]
        assert abs(poses[1][2, 3] - 0.05) < 1e-3  # pushed out of the table by 5 mm
        assert abs(poses[2][2, 3] - 0.15) < 1.5e-3  # pushed out of box 1 by ~10 mm
        assert abs(poses[1][0, 3]) < 1e-6 and abs(poses[2][0, 3]) < 1e-6
    finally:
        world.close()


def test_hierarchy_order_and_descendants():
    parents = {1: 0, 2: 1, 3: 2, 4: 0}
    order = order_root_to_leaves([3, 2, 4, 1], parents, {1: 0.0, 2: 0.1, 3: 0.2, 4: 0.0})
    assert order.index(1) < order.index(2) < order.index(3)
    assert descendants(2, parents) == {2, 3}


def test_physopt_stage_makes_stack_rest(tmp_path: Path):
    root = _stack_scene(tmp_path / "scene")
    result = run_stage(PHYSOPT, root, PhysOptions(use_diffsim=False))
    assert result.summary["still_moving"] == 0
    state = read_state(root / "physopt")
    z = {o.id: o.pose[2, 3] for o in state.objects}
    assert abs(z[1] - 0.05) < 2e-3 and abs(z[2] - 0.13) < 3e-3
    for o in state.objects:
        assert 0.2 <= o.friction <= 1.0 and o.mass_kg > 0 and len(o.com_in_object) == 3
    log = json.loads((root / "physopt" / "log.json").read_text())
    assert any("depenetrated" in line for line in log["objects"]["1"])
    # judge-style check on the result: 3 s, nothing moves more than 5 mm
    world = build_world([SimBody(o.id, [trimesh.creation.box([0.1] * 3 if o.id == 1 else [0.06] * 3)],
                                 o.pose, o.mass_kg, np.asarray(o.com_in_object), o.friction)
                         for o in state.objects], [0, 0, 0], [0, 0, 1], state.support.friction)
    try:
        start = world.poses()
        for _ in range(720):
            pb.stepSimulation(physicsClientId=world.client)
        end = world.poses()
        for i in start:
            assert np.linalg.norm(end[i][:3, 3] - start[i][:3, 3]) < 0.005
    finally:
        world.close()


def test_diffsim_pass_lowers_the_wrench_residual_of_an_overhanging_box(tmp_path: Path):
    """A 6 cm box whose COM hangs 10 mm past the edge of a 10 cm box cannot be balanced by
    contact forces; the differentiable pass lowers its wrench residual by moving the COM
    (within its bounds) and the pose back over the support, staying near the observation."""
    root = _box_scene(tmp_path / "scene", [(1, "base", 0.1, _pose(0.05)),
                                           (2, "overhang", 0.06, _pose(0.13, 0.06))])
    run_stage(PHYSOPT, root, PhysOptions(max_rounds=0))
    log = json.loads((root / "physopt" / "log.json").read_text())
    note = next(n for n in log["objects"]["2"] if n.startswith("diffsim"))
    before, after = (float(x) for x in note.split("residual ")[1].split(" (")[0].split(" -> "))
    assert before > 0.03 and after < 0.5 * before, note
    box = read_state(root / "physopt").object(2)
    com_world = box.pose[:3, :3] @ np.asarray(box.com_in_object) + box.pose[:3, 3]
    assert com_world[0] < 0.06 - 0.003  # the COM moved back towards the supporting box
    assert abs(box.pose[0, 3] - 0.06) < 0.01  # and the pose stayed near the observation
    assert 0.2 <= box.friction <= 1.0


def test_only_reruns_one_object_and_keeps_the_rest(tmp_path: Path):
    root = _stack_scene(tmp_path / "scene")
    run_stage(PHYSOPT, root, PhysOptions(use_diffsim=False))
    first = read_state(root / "physopt")
    result = run_stage(PHYSOPT, root, PhysOptions(use_diffsim=False, only=2))
    second = read_state(root / "physopt")
    assert np.array_equal(first.object(1).pose, second.object(1).pose)  # fixed, untouched
    assert abs(second.object(2).pose[2, 3] - 0.13) < 3e-3  # re-solved from init: on the box
    assert result.summary["still_moving"] == 0
    log = json.loads((root / "physopt" / "log.json").read_text())
    assert log["only"] == {"object": 2, "rerun": [2]}


def test_com_repair_keeps_an_off_balance_ball_where_it_was_seen(tmp_path: Path):
    """A 4 cm ball whose recorded COM sits 4 mm beside its contact would roll away (a
    quarter turn until the COM hangs under the centre). physopt moves the COM back over the
    contact and down instead, so the ball stays in the observed pose, and a fresh PyBullet
    rollout of the result (the judge's 3 s) leaves it in place."""
    root = tmp_path / "scene"
    d = root / "init"
    (d / "meshes").mkdir(parents=True)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    save_mesh(ball, d / "meshes" / "1.glb")
    write_state(d, SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                              objects=[ObjectState(id=1, label="ball", mesh="meshes/1.glb",
                                                   world_from_object=_pose(0.0405),
                                                   com_in_object=[0.004, 0.0, 0.0])]))
    m = load_manifest(root / "manifest.json")
    m.stages["init"] = StageRecord(status="done")
    save_manifest(root / "manifest.json", m)

    # without the repair the judge sees it roll
    bodies = [SimBody(1, [ball], np.array(_pose(0.04)), 0.1, np.array([0.004, 0, 0]), 0.6)]
    world = build_world(bodies, [0, 0, 0], [0, 0, 1], 0.9)
    try:
        from r2s.physopt.pybullet_world import drift
        moved_m, turned_deg = drift(world, {1: np.array(_pose(0.04))}, 3.0)[1]
    finally:
        world.close()
    assert turned_deg > 30.0

    result = run_stage(PHYSOPT, root, PhysOptions(use_diffsim=False))
    assert result.summary["still_moving"] == 0
    out = read_state(root / "physopt").object(1)
    from r2s.metrics.stability import rotation_angle_deg
    assert rotation_angle_deg(np.eye(3), out.pose[:3, :3]) < 5.0   # seen pose kept
    assert np.linalg.norm(out.pose[:2, 3]) < 0.005
    com_world = out.pose[:3, :3] @ np.asarray(out.com_in_object) + out.pose[:3, 3]
    assert np.linalg.norm(com_world[:2] - out.pose[:2, 3]) < 0.002  # over the contact
    assert com_world[2] < out.pose[2, 3] - 0.002                    # and below the centre
    world = build_world([SimBody(1, [ball], out.pose, out.mass_kg, np.asarray(out.com_in_object),
                                 out.friction)], [0, 0, 0], [0, 0, 1], out_support_friction(root))
    try:
        from r2s.physopt.pybullet_world import drift
        moved_m, turned_deg = drift(world, {1: out.pose}, 3.0)[1]
    finally:
        world.close()
    assert moved_m < 0.002 and turned_deg < 1.0


def out_support_friction(root: Path) -> float:
    return read_state(root / "physopt").support.friction
