"""export's per-object ``observation`` block and its flags, on a hand-made scene.

A 6 x 6 x 6 cm box seen on a table (input/ ray-cast from the truth); init/ holds it where
it was seen, physopt/ where a repair left it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from helpers_init import SynthObject, pose, write_input_scene
from helpers_state import StateObj, write_init_state
from r2s.physopt.observation_bound import OBSERVATION_FLAG_KEY, displacement_flags
from r2s.io.state import read_state, write_state
from r2s.runner.base import run_stage
from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions

CUBE = 0.06


def _scene(root: Path, moved_m: float, flag: str | None = None) -> Path:
    truth = pose((0.0, 0.0, CUBE / 2))
    write_input_scene(root, [SynthObject(1, trimesh.creation.box([CUBE] * 3), truth)],
                      width=160, height=120)
    write_init_state(root, [StateObj(1, trimesh.creation.box([CUBE] * 3), truth)])
    write_init_state(root, [StateObj(1, trimesh.creation.box([CUBE] * 3),
                                     pose((moved_m, 0.0, CUBE / 2)))], stage="physopt")
    if flag is not None:
        state = read_state(root / "physopt")
        data = state.model_dump()
        data["objects"][0][OBSERVATION_FLAG_KEY] = flag
        write_state(root / "physopt", type(state).model_validate(data))
    return root


def _block(root: Path) -> tuple[dict, dict]:
    result = run_stage(EXPORT, root, ExportOptions(source="physopt"))
    scene = json.loads((root / "export" / "scene.json").read_text())
    return scene["objects"][0]["observation"], result.summary


def test_object_where_it_was_seen_is_not_flagged(tmp_path):
    block, summary = _block(_scene(tmp_path / "s", 0.0))
    assert block["iou"] > 0.97          # same mesh, same pose: only edge pixels differ
    assert block["ucd_mm"] < 0.5
    assert block["free_space_violation"] == 0.0
    assert block["displacement_m"] == pytest.approx(0.0, abs=1e-9)
    assert block["flagged"] is False and block["reason"] is None
    assert summary["flagged_objects"] == 0 and summary["warnings"] == []


def test_object_moved_beyond_tolerance_is_flagged_with_its_displacement(tmp_path):
    block, summary = _block(_scene(tmp_path / "s", 0.035))
    assert block["displacement_m"] == pytest.approx(0.035, abs=1e-6)
    assert block["displacement_deg"] == pytest.approx(0.0, abs=1e-6)
    assert block["flagged"] is True
    assert "moved 35 mm" in block["reason"]
    assert block["iou"] < 0.7 and block["free_space_violation"] > 0.1
    assert summary["flagged_objects"] == 1
    assert len(summary["warnings"]) == 1 and summary["warnings"][0].startswith("object 1:")
    # 10 mm is within the default 20 mm tolerance, and 0.5 IoU / 0.5 free space
    block, _ = _block(_scene(tmp_path / "t", 0.010))
    assert block["flagged"] is False


def test_earlier_flag_is_kept_in_the_block(tmp_path):
    flags, disp = displacement_flags({1: pose((0, 0, 0))}, {1: pose((0.0, 0.03, 0.0))},
                                     {1: np.zeros(3)}, 0.02, 15.0)
    assert disp[1] == pytest.approx((0.03, 0.0))
    assert flags[1] == "physopt moved 30 mm (> 20 mm) from where it was seen to make it rest"
    block, _ = _block(_scene(tmp_path / "s", 0.0, flag=flags[1]))
    assert block["flagged"] is True and block["reason"] == flags[1]


def test_displacement_flags_on_rotation():
    turned = np.eye(4)
    a = np.radians(20.0)
    turned[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    flags, disp = displacement_flags({1: np.eye(4), 2: np.eye(4)}, {1: turned, 2: np.eye(4)},
                                     {1: np.zeros(3), 2: np.zeros(3)}, 0.02, 15.0)
    assert disp[1][1] == pytest.approx(20.0)
    assert "turned 20 deg" in flags[1] and 2 not in flags


def test_evaluate_reports_the_observation_metrics(tmp_path):
    from r2s.stages.evaluate import STAGE as EVALUATE

    root = _scene(tmp_path / "s", 0.035)
    block, _ = _block(root)
    result = run_stage(EVALUATE, root)
    metrics = json.loads((root / "evaluate" / "metrics.json").read_text())
    assert result.summary["silhouette_iou"] == pytest.approx(block["iou"], abs=1e-4)
    assert metrics["free_space_violation"] == pytest.approx(block["free_space_violation"], abs=1e-4)
    assert metrics["ucd_mm"] == pytest.approx(block["ucd_mm"], abs=1e-3)
    assert metrics["flagged_objects"] == 1
    obj = metrics["objects"][0]
    assert obj["displacement_m"] == pytest.approx(0.035, abs=1e-5) and obj["flagged"] is True
    masks = np.asarray(Image.open(root / "input" / "masks.png"))
    assert obj["mask_px"] == int((masks == 1).sum())
    assert obj["free_space_px"] == pytest.approx(obj["free_space_violation"] * obj["mask_px"])
    assert (root / "evaluate" / "observation.png").is_file()
