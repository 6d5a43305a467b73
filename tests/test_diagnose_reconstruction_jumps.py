"""A diagnose step whose rerun moved an object's reconstruction further than its observed
points moved is reverted (r2s/diagnose/measure/reconstruction_jumps.py and the loop's
guard in r2s/runner/diagnose_loop.py), on hand-made init/ folders: a depth correction that
moves every object's points 4 mm along z, one object's fit flipping 50 mm up, off the
table (reverted), or 50 mm down onto it (kept)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from r2s.diagnose.measure.reconstruction_jumps import reconstruction_jumps
from r2s.diagnose.stats.steps import StepJudgement
from r2s.runner.diagnose_loop import LoopConfig, _FlipRetries, _unless_jumped


def _init_dir(root: Path, centres: dict[int, tuple], points_shift_z: float) -> Path:
    """``root/init`` with one 4 cm cube per id at ``centres`` and its observed points (the
    cube's top face, 25 points) shifted by ``points_shift_z`` along z."""
    stage = root / "init"
    (stage / "meshes").mkdir(parents=True)
    (stage / "points").mkdir()
    objects = []
    for i, c in centres.items():
        trimesh.creation.box(extents=(0.04, 0.04, 0.04)).export(stage / "meshes" / f"{i}.glb")
        g = np.linspace(-0.015, 0.015, 5)
        top = np.array([(x, y, 0.02) for x in g for y in g]) + (0.3 * i, 0.0, 0.02)
        np.save(stage / "points" / f"{i}.npy", top + (0.0, 0.0, points_shift_z))
        pose = np.eye(4)
        pose[:3, 3] = c
        objects.append({"id": i, "label": "cube", "mesh": f"meshes/{i}.glb",
                        "world_from_object": pose.tolist(), "source": "prior",
                        "observed_points": f"points/{i}.npy", "num_observed_points": 25})
    state = {"stage": "init", "support": {"point": [0, 0, 0], "normal": [0, 0, 1]},
             "objects": objects}
    (stage / "state.json").write_text(json.dumps(state))
    return stage


def _scenes(tmp_path: Path) -> tuple[Path, Path]:
    before = tmp_path / "before"
    after = tmp_path / "after"
    _init_dir(before, {1: (0.3, 0.0, 0.02), 2: (0.6, 0.0, 0.02)}, 0.0)
    # object 1 moves with its points (4 mm); object 2's fit flips 50 mm up
    _init_dir(after, {1: (0.3, 0.0, 0.024), 2: (0.6, 0.0, 0.074)}, 0.004)
    return before, after


def test_a_fit_that_moves_beyond_its_points_is_a_jump(tmp_path):
    before, after = _scenes(tmp_path)
    jumps = reconstruction_jumps(before / "init", after / "init", tolerance_m=0.02)
    assert [j.object_id for j in jumps] == [2]
    assert abs(jumps[0].jump_m - 0.050) < 1e-6
    assert abs(jumps[0].points_moved_m - 0.004) < 1e-6
    assert "moved 50 mm more than its observed points (4 mm) (25 points)" in jumps[0].describe()
    # the cube's bottom went from the table (0) to 54 mm above it: it left its support
    assert abs(jumps[0].gap_m[0]) < 1e-9 and abs(jumps[0].gap_m[1] - 0.054) < 1e-9
    assert jumps[0].lifts_off()
    # every object, tolerance 0: object 1 moved exactly with its points
    all_ = {j.object_id: j.jump_m for j in reconstruction_jumps(before / "init",
                                                                after / "init", 0.0)}
    assert all_[2] > 0.049 and all_.get(1, 0.0) < 1e-9


def test_the_loop_reverts_a_step_whose_rerun_jumped(tmp_path):
    before, after = _scenes(tmp_path)
    kept = StepJudgement(("registration",), 37.1, 31.0, 30.7, True,
                         "the claimed residual fell 37.1 -> 30.7 (predicted 31.0)")
    out = _unless_jumped(kept, before, after, ["init"], LoopConfig())
    assert not out.kept and out.flipped
    assert out.reason.startswith("reverted: the claimed residual fell")
    assert "object 2's reconstruction moved 50 mm" in out.reason
    # a decisive fall (a 12 % depth scale: 99.0 -> 24.3) keeps the step, the flip named
    decisive = StepJudgement(("table_height", "registration"), 99.0, 23.4, 24.3, True,
                             "the claimed residual fell 99.0 -> 24.3 (predicted 23.4)")
    out = _unless_jumped(decisive, before, after, ["init"], LoopConfig())
    assert out.kept and not out.flipped
    assert "kept although object 2's reconstruction moved 50 mm" in out.reason
    assert "a fall of 74.7 is decisive" in out.reason
    assert not _unless_jumped(decisive, before, after, ["init"],
                              LoopConfig(decisive_fall=0)).kept
    # a claimed residual that fell to nothing is the largest fall, not none
    to_zero = StepJudgement(("support",), 361.7, 0.0, 0.0, True,
                            "the claimed residual fell 361.7 -> 0.0 (predicted 0.0)")
    assert _unless_jumped(to_zero, before, after, ["init"], LoopConfig()).kept
    assert not _unless_jumped(decisive, before, after, ["init"],
                              LoopConfig(decisive_fall=80.0)).kept
    # off, or no init rerun: the judgement stands
    assert _unless_jumped(kept, before, after, ["init"], LoopConfig(jump_tolerance_m=0)).kept
    assert _unless_jumped(kept, before, after, ["physopt"], LoopConfig()).kept
    # a fit that jumps down onto its support (a floating prior brought down) is no loss
    down = tmp_path / "down"
    _init_dir(down, {1: (0.3, 0.0, 0.024), 2: (0.6, 0.0, 0.074)}, 0.0)
    settled = tmp_path / "settled"
    _init_dir(settled, {1: (0.3, 0.0, 0.024), 2: (0.6, 0.0, 0.024)}, 0.004)
    jumped = reconstruction_jumps(down / "init", settled / "init")
    assert [j.object_id for j in jumped] == [2] and not jumped[0].lifts_off()
    assert _unless_jumped(kept, down, settled, ["init"], LoopConfig()).kept
    # a step that moved every fit with its points stays kept
    steady = tmp_path / "steady"
    _init_dir(steady, {1: (0.3, 0.0, 0.024), 2: (0.6, 0.0, 0.024)}, 0.004)
    assert _unless_jumped(kept, before, steady, ["init"], LoopConfig()).kept


def test_an_effect_reverted_for_a_flip_is_tried_once_more_after_a_kept_step():
    flip = StepJudgement(("table_shape",), 311.0, 19.4, 18.7, False, "reverted: flipped",
                         flipped=True)
    missed = StepJudgement(("registration",), 40.0, 30.0, 39.5, False, "reverted: missed")
    retries, excluded, notes = _FlipRetries(), set(), []
    for effect, judgement in (("lens_distortion", flip), ("depth_offset", missed)):
        excluded.add(effect)
        retries.after_reverted(effect, judgement)
    retries.after_kept("depth_scale", excluded, notes)
    # the flipped one is back in the ranking, the one whose residual stayed is not
    assert excluded == {"depth_offset"}
    assert notes == ["lens_distortion is tried again with depth_scale in the model: its first "
                     "rerun flipped an object's fit off its support"]
    # a second flip of the same effect is final
    excluded.add("lens_distortion")
    retries.after_reverted("lens_distortion", flip)
    retries.after_kept("camera_rotation", excluded, notes)
    assert excluded == {"depth_offset", "lens_distortion"} and len(notes) == 1
