"""A carrier whose whole top is hidden by what lies on it (r2s/geometry/hidden_carrier.py).

A 60 mm deep, 50 mm tall brick carries a 30 mm slab that covers its top; the camera, 40 deg
above the table and looking along +x, sees the brick's front face and the slab. The truth
is known exactly (the meshes), so the completions are checked against it."""

from __future__ import annotations

import numpy as np
import trimesh

from helpers_init import SynthObject, pose, render_view
from r2s.geometry.camera import backproject, intrinsics, look_at
from r2s.geometry.carving import carve_view
from r2s.geometry.completion import complete_from_points
from r2s.geometry.hidden_carrier import hidden_tops

W, H = 320, 240
K = intrinsics(W, H, 45.0)
BRICK_DEPTH_M, BRICK_HEIGHT_M = 0.06, 0.05
NOISE_M = 0.001
"""Depth noise (1 sigma) of the rendered view."""


def _camera(elevation_deg: float = 40.0, distance_m: float = 0.45) -> np.ndarray:
    target = np.array([0.0, 0.0, 0.04])
    el = np.radians(elevation_deg)
    eye = target + distance_m * np.array([-np.cos(el), 0.0, np.sin(el)])
    return look_at(eye, target)


def _scene(slab_x_m: float = 0.003, slab_length_m: float = 0.066, behind: bool = False):
    """Brick (id 1) at the origin; slab (id 2, centred at ``slab_x_m``, ``slab_length_m``
    along x) on it, or (``behind``) a tall box standing on the table 40 mm behind the
    brick, seen above it. (depth, masks, camera, objects)."""
    brick = trimesh.creation.box((BRICK_DEPTH_M, 0.08, BRICK_HEIGHT_M))
    if behind:
        other = trimesh.creation.box((0.05, 0.084, 0.09))
        other_pose = pose([0.03 + 0.04 + 0.025, 0.0, 0.045])
    else:
        other = trimesh.creation.box((slab_length_m, 0.086, 0.03))
        other_pose = pose([slab_x_m, 0.0, BRICK_HEIGHT_M + 0.015])
    objs = [SynthObject(1, brick, pose([0.0, 0.0, BRICK_HEIGHT_M / 2]), color=(200, 60, 60)),
            SynthObject(2, other, other_pose, color=(60, 60, 200))]
    camera = _camera()
    _, depth, masks = render_view(objs, K, camera, W, H)
    depth = depth + np.random.default_rng(0).normal(0, NOISE_M, depth.shape)
    return depth.astype(np.float64), masks, camera, objs


def _points(depth, masks, camera, obj_id):
    return backproject(depth, K, camera, masks == obj_id, return_pixels=True)


def _tops(depth, masks, camera):
    pts = {i: _points(depth, masks, camera, i)[0] for i in (1, 2)}
    return pts, hidden_tops(pts, np.zeros(3), np.array([0.0, 0.0, 1.0]), camera[:3, 3])


def _complete(depth, masks, camera, obj_id, extra=None, below=None):
    pts, pix = _points(depth, masks, camera, obj_id)
    if extra is not None:
        pts = np.concatenate([pts, extra])
    view = carve_view(K, camera, depth, pix, plane=(np.zeros(3), np.array([0.0, 0.0, 1.0])))
    done = complete_from_points(pts, [0, 0, 0], [0, 0, 1], view=view,
                                below_points_world=below)
    world = done.mesh.copy()
    world.apply_transform(done.world_from_object)
    return world


def test_the_brick_under_a_slab_gets_its_hidden_top():
    """The brick shows only its front face; the slab's front edge touches its top edge.
    The brick gets a hidden top at its height (within 3 mm), reaching to within 6 mm of
    its back face, and no wider than it was seen (80 mm, within 6 mm)."""
    depth, masks, camera, _ = _scene()
    brick_px = np.count_nonzero(masks == 1)
    assert brick_px > 500  # the face is seen
    _, tops = _tops(depth, masks, camera)
    assert set(tops) == {1}
    top = tops[1]
    assert top.carried_id == 2
    assert abs(top.height_m - BRICK_HEIGHT_M) < 0.003
    x, y = top.points_world[:, 0], top.points_world[:, 1]
    assert x.max() > BRICK_DEPTH_M / 2 - 0.006
    assert y.max() - y.min() < 0.08 + 0.006


def test_the_brick_is_completed_as_deep_as_it_is_and_the_slab_rests_on_it():
    """Completed with its hidden top, the brick is within 10 % of its true depth (60 mm;
    without it: a slab under half as deep), and the slab, standing on those points,
    has its base within 5 mm of the brick's top (without them it reaches the table)."""
    depth, masks, camera, _ = _scene()
    pts, tops = _tops(depth, masks, camera)
    hidden = tops[1].points_world
    brick = _complete(depth, masks, camera, 1, extra=hidden)
    depth_m = brick.bounds[1, 0] - brick.bounds[0, 0]
    assert abs(depth_m - BRICK_DEPTH_M) < 0.1 * BRICK_DEPTH_M, depth_m
    assert abs(brick.bounds[1, 2] - BRICK_HEIGHT_M) < 0.005
    thin = _complete(depth, masks, camera, 1)
    assert thin.bounds[1, 0] - thin.bounds[0, 0] < 0.5 * BRICK_DEPTH_M

    support = tops[1].support_world(pts[1], np.zeros(3), np.array([0.0, 0.0, 1.0]))
    slab = _complete(depth, masks, camera, 2, below=[support])
    assert abs(slab.bounds[0, 2] - BRICK_HEIGHT_M) < 0.005, slab.bounds
    column = _complete(depth, masks, camera, 2, below=[pts[1]])
    assert column.bounds[0, 2] < 0.01


def test_no_hidden_top_for_a_box_standing_behind_with_a_gap():
    """A taller box standing on the table 40 mm behind the brick, seen above it, does not
    touch the brick's top edge: nothing is added (the brick's top is hidden only by the
    angle of view, and the box stands on the table)."""
    depth, masks, camera, _ = _scene(behind=True)
    _, tops = _tops(depth, masks, camera)
    assert tops == {}


def test_no_hidden_top_when_the_carriers_top_is_seen():
    """A 20 mm slab lying along the back of the brick leaves 40 mm of the brick's top seen
    in front of it: the brick is a box seen from above, not a face, and gets nothing."""
    depth, masks, camera, _ = _scene(slab_x_m=0.02, slab_length_m=0.02)
    _, tops = _tops(depth, masks, camera)
    assert 1 not in tops


def test_init_completes_the_brick_with_its_hidden_top(tmp_path):
    """Through the init stage (no priors): the brick's back comes out within 6 mm of the
    true one (x = 30 mm) and its depth within 15 % of the truth (the outline snapped onto
    the mask moves its front face a few millimetres), and the slab lies on it (its
    lowest vertex within 5 mm of the brick's top);
    with ``completion_hidden_tops`` off, the brick is under half as deep and the slab
    reaches down to the table."""
    from helpers_init import write_input_scene
    from r2s.io.mesh_io import load_mesh
    from r2s.io.paths import ScenePaths
    from r2s.io.state import read_state
    from r2s.runner.base import run_stage
    from r2s.stages.init import STAGE, Options

    _, _, camera, objs = _scene()
    scene = write_input_scene(tmp_path / "scene", objs, width=W, height=H, K=K,
                              world_from_camera=camera, depth_noise_m=NOISE_M)

    records = {}

    def bounds(**options) -> dict[int, np.ndarray]:
        run_stage(STAGE, scene, Options(**options), force=True)
        out = ScenePaths(scene).stage_dir("init")
        state = read_state(out)
        records.update({o.id: getattr(o, "hidden_top", None) for o in state.objects})
        return {o.id: load_mesh(out / o.mesh).apply_transform(o.pose).bounds
                for o in state.objects}

    found = bounds()
    assert records[1]["carries"] == 2 and records[2] is None  # the state says it was inferred
    assert abs(records[1]["height_m"] - BRICK_HEIGHT_M) < 0.003
    brick_depth = found[1][1, 0] - found[1][0, 0]
    assert abs(found[1][1, 0] - BRICK_DEPTH_M / 2) < 0.006, found[1]
    assert abs(brick_depth - BRICK_DEPTH_M) < 0.15 * BRICK_DEPTH_M, found[1]
    assert abs(found[2][0, 2] - BRICK_HEIGHT_M) < 0.005, found[2]
    off = bounds(completion_hidden_tops=False)
    assert records[1] is None
    assert off[1][1, 0] - off[1][0, 0] < 0.5 * BRICK_DEPTH_M
    assert off[2][0, 2] < 0.01
