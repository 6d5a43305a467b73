"""Using the twin: a push of a lone box moves it as far as the pusher travels after
contact; the removal order of a stack is top to bottom."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from r2s.errors import InputError
from r2s.interaction.declutter import declutter
from r2s.interaction.predict import predict
from r2s.io.mesh_io import save_mesh
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions


def _boxes_gt(root: Path, boxes: list[tuple[int, float, float, float]]) -> Path:
    """gt/ of cube boxes (id, edge m, x m, z of centre m), exported as is."""
    (root / "gt" / "meshes").mkdir(parents=True)
    objects = []
    for oid, edge, x, z in boxes:
        save_mesh(trimesh.creation.box([edge] * 3), root / "gt" / "meshes" / f"{oid}.glb")
        pose = np.eye(4)
        pose[0, 3], pose[2, 3] = x, z
        objects.append({"id": oid, "label": f"box{oid}", "mesh": f"meshes/{oid}.glb",
                        "world_from_object": pose.tolist(), "mass_kg": 0.3, "friction": 0.5,
                        "com_in_object": [0, 0, 0]})
    (root / "gt" / "scene.json").write_text(json.dumps({
        "gravity": [0, 0, -9.81], "objects": objects,
        "support": {"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1], "friction": 0.8}}))
    run_stage(EXPORT, root, ExportOptions(source="gt"))
    return root


def test_push_moves_a_lone_box_by_the_travel_after_contact(tmp_path: Path):
    root = _boxes_gt(tmp_path / "scene", [(1, 0.1, 0.0, 0.05)])
    action = tmp_path / "push.json"
    action.write_text(json.dumps({
        "end_effector": {"type": "sphere", "radius_m": 0.015},
        "start": [-0.12, 0.0, 0.04],
        "waypoints": [{"position": [0.05, 0.0, 0.04], "speed_mps": 0.05}],
        "settle_s": 0.5}))
    summary = predict(root, action)
    # contact when the sphere's front (x + 0.015) meets the back face (x = -0.05):
    # the pusher then travels 0.05 - (-0.065) = 0.115 m and the box goes with it;
    # the 0.05 m/s left when the pusher is removed slides it 0.3 mm more (mu g = 3.9 m/s^2)
    moved = summary["objects"][0]["displacement_m"]
    assert moved == pytest.approx(0.115, abs=0.01)
    final = np.asarray(summary["objects"][0]["world_from_object"])
    assert abs(final[1, 3]) < 0.01 and abs(final[2, 3] - 0.05) < 0.003
    assert (root / "predict" / "predicted.json").is_file()


def test_bad_action_file_is_one_clear_error(tmp_path: Path):
    root = _boxes_gt(tmp_path / "scene", [(1, 0.1, 0.0, 0.05)])
    action = tmp_path / "push.json"
    action.write_text(json.dumps({"start": [0, 0], "waypoints": []}))
    with pytest.raises(InputError, match="start"):
        predict(root, action)


def test_stack_is_cleared_top_to_bottom_and_replays_on_gt(tmp_path: Path):
    root = _boxes_gt(tmp_path / "scene", [(1, 0.1, 0.0, 0.05), (2, 0.08, 0.0, 0.14),
                                          (3, 0.06, 0.0, 0.21)])
    report = declutter(root)
    assert report["order"] == [3, 2, 1]
    assert report["success_rate"] == 1.0
    assert report["ground_truth"]["success_rate"] == 1.0
