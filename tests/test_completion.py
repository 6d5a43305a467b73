"""Completion without a prior: ray-cast partial views of known solids."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from helpers_init import SynthObject, pose, render_view, rotation
from r2s.geometry.camera import backproject, intrinsics, look_at
from r2s.geometry.completion import (NO_BRIDGE, RELAXED_BRIDGE, complete_from_points,
                                     footprint_sdf)
from r2s.geometry.raycast import raycast_view

W, H = 160, 120
K = intrinsics(W, H, 50.0)
# 45 degrees of elevation, about 0.42 m from the objects
CAMERA = look_at([0.21, -0.21, 0.30], [0.0, 0.0, 0.03])


def _observe(objects: list[SynthObject], obj_id: int):
    rgb, depth, masks = render_view(objects, K, CAMERA, W, H)
    pts, pix = backproject(depth, K, CAMERA, masks == obj_id, return_pixels=True)
    margin = 0.25 * float(np.median(depth[masks == obj_id])) / K[0, 0]
    return pts, rgb[pix[:, 0], pix[:, 1]], margin


def _solid(mesh: trimesh.Trimesh, yaw_deg: float, xy=(0.01, 0.02)) -> SynthObject:
    return SynthObject(1, mesh, pose([xy[0], xy[1], -mesh.bounds[0, 2]],
                                     rotation([0, 0, 1], yaw_deg)), color=(40, 160, 220))


@pytest.mark.parametrize("shape", ["box", "cylinder"])
def test_box_and_cylinder_volumes(shape: str):
    mesh = (trimesh.creation.box((0.08, 0.12, 0.06)) if shape == "box"
            else trimesh.creation.cylinder(0.035, 0.1, sections=96))
    obj = _solid(mesh, 30.0)
    pts, colors, margin = _observe([obj], 1)
    done = complete_from_points(pts, [0, 0, 0], [0, 0, 1], colors=colors, hull_margin_m=margin)
    assert done.mesh.is_watertight and done.mesh.is_winding_consistent
    assert abs(done.mesh.volume / mesh.volume - 1.0) < 0.15
    world = done.mesh.copy()
    world.apply_transform(done.world_from_object)
    truth = mesh.copy()
    truth.apply_transform(obj.world_from_object)
    assert np.linalg.norm(world.center_mass - truth.center_mass) < 0.005
    np.testing.assert_allclose(world.bounds[:, 2], truth.bounds[:, 2], atol=0.004)
    # object frame: plane axes, origin at the footprint centre on the base
    assert abs(done.mesh.vertices[:, 2].min()) < 1e-6
    assert done.bottom_m == pytest.approx(0, abs=1e-6)
    np.testing.assert_allclose(done.world_from_object[:3, :3], np.eye(3), atol=1e-9)
    assert done.mesh.visual.kind == "vertex"
    vc = done.mesh.visual.vertex_colors[:, :3].astype(float)
    assert np.abs(vc.mean(axis=0) - [40, 160, 220]).max() < 60  # shaded object colour


def test_bowl_keeps_its_dip():
    profile = [(0.0, 0.0), (0.05, 0.0), (0.065, 0.045), (0.06, 0.045), (0.045, 0.008),
               (0.0, 0.008)]
    bowl = trimesh.creation.revolve(np.array(profile), sections=96)
    obj = _solid(bowl, 0.0, xy=(0.0, 0.0))
    pts, colors, margin = _observe([obj], 1)
    done = complete_from_points(pts, [0, 0, 0], [0, 0, 1], hull_margin_m=margin)
    assert done.mesh.is_watertight
    world = done.mesh.copy()
    world.apply_transform(done.world_from_object)
    # cast rays straight down: the rim is tall, the middle is low
    origins = np.array([[0.0, 0.0, 0.2], [0.0, 0.06, 0.2], [0.0, -0.06, 0.2]])
    depth, index, _ = _down_rays(world, origins)
    heights = 0.2 - depth
    assert heights[0] < 0.02          # the dip (true inside bottom: 8 mm)
    assert heights[1] > 0.035         # the far rim, seen
    assert heights[2] > 0.02          # the near rim, hidden inside, interpolated


def _down_rays(mesh: trimesh.Trimesh, origins: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, np.int32))
    scene.add_triangles(tm)
    rays = np.concatenate([origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1))], axis=1)
    ans = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    return ans["t_hit"].numpy(), ans["geometry_ids"].numpy(), ans["primitive_ids"].numpy()


def test_object_on_another_object_stands_on_it():
    lower = trimesh.creation.box((0.14, 0.14, 0.04))
    upper = trimesh.creation.box((0.05, 0.05, 0.03))
    objs = [SynthObject(1, upper, pose([0.0, 0.0, 0.055])),
            SynthObject(2, lower, pose([0.0, 0.0, 0.02]), color=(90, 90, 90))]
    _, depth, masks = render_view(objs, K, CAMERA, W, H)
    pts = backproject(depth, K, CAMERA, masks == 1)
    below = backproject(depth, K, CAMERA, masks == 2)
    done = complete_from_points(pts, [0, 0, 0], [0, 0, 1], below_points_world=below)
    assert done.bottom_m == pytest.approx(0.04, abs=0.004)
    assert abs(done.mesh.volume / upper.volume - 1.0) < 0.2
    alone = complete_from_points(pts, [0, 0, 0], [0, 0, 1])
    assert alone.bottom_m == pytest.approx(0.0, abs=1e-6)  # without: down to the table


def test_tilted_support_plane():
    """Everything tilted by 20 degrees: the mesh is built in the plane's frame."""
    tilt = pose(rot=rotation([1, 0, 0], 20.0))
    box = trimesh.creation.box((0.08, 0.06, 0.05))
    obj = SynthObject(1, box, tilt @ pose([0.0, 0.0, 0.025]))
    table = trimesh.creation.box((1.0, 1.0, 0.02))
    table.apply_transform(tilt @ pose([0.0, 0.0, -0.01]))
    cam = tilt @ CAMERA
    depth, index, _ = raycast_view([obj.mesh.copy().apply_transform(obj.world_from_object),
                                    table], K, cam, W, H)
    pts = backproject(depth, K, cam, index == 0)
    normal = tilt[:3, 2]
    done = complete_from_points(pts, [0, 0, 0], normal)
    assert done.mesh.is_watertight
    assert abs(done.mesh.volume / box.volume - 1.0) < 0.15
    np.testing.assert_allclose(done.world_from_object[:3, 2], normal, atol=1e-9)


def test_footprint_sdf_of_a_square():
    eq = np.array([[1.0, 0, -1], [-1.0, 0, -1], [0, 1.0, -1], [0, -1.0, -1]])  # |x|,|y| <= 1
    xy = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.3], [2.0, 0.0]])
    np.testing.assert_allclose(footprint_sdf(eq, xy), [-1.0, -0.5, 0.0, 1.0])


def test_degenerate_input_is_an_error():
    with pytest.raises(ValueError):
        complete_from_points(np.zeros((5, 3)), [0, 0, 0], [0, 0, 1])
    line = np.c_[np.linspace(0, 0.1, 50), np.zeros(50), np.full(50, 0.02)]
    with pytest.raises(ValueError):
        complete_from_points(line, [0, 0, 0], [0, 0, 1])


def test_flying_pixels_do_not_stretch_the_footprint():
    """Mixed pixels along the box's silhouette, smeared towards the table behind it."""
    box = trimesh.creation.box((0.08, 0.12, 0.06))
    obj = _solid(box, 30.0)
    _, depth, masks = render_view([obj], K, CAMERA, W, H)
    edge = (masks == 1) & ~ndimage.binary_erosion(masks == 1)
    rng = np.random.default_rng(0)
    smeared = depth.copy()
    far = edge & (rng.random(edge.shape) < 0.5)
    smeared[far] += rng.uniform(0.02, 0.15, size=far.sum())  # between the box and the table
    pts = backproject(smeared, K, CAMERA, masks == 1)
    done = complete_from_points(pts, [0, 0, 0], [0, 0, 1])
    assert abs(done.mesh.volume / box.volume - 1.0) < 0.15
    raw = complete_from_points(pts, [0, 0, 0], [0, 0, 1], outlier_factor=0.0)
    assert raw.mesh.volume > 1.2 * box.volume  # what the filter prevents


def test_a_neighbour_beside_the_object_is_not_its_support():
    """A box (100 x 80 x 80 mm) on the table whose lower 25 mm are hidden, with the side of
    a lying can beside it reaching from 15 to 35 mm within 1 cm of its footprint: the can
    passes the level where the box's visible part ends, so it is beside the box, not under
    it, and the box goes down to the table. The same can points all below the box's
    visible part (a box seen down to 45 mm) say nothing about what is under it; a wider
    slab's top around it (30-35 mm, on every side within 1 cm) holds it up: the base lands
    on the slab's top within 3 mm."""
    rng = np.random.default_rng(0)
    n = 3000
    top = np.c_[rng.uniform(-0.05, 0.05, n), rng.uniform(-0.04, 0.04, n), np.full(n, 0.08)]
    front = np.c_[rng.uniform(-0.05, 0.05, n), np.full(n, -0.04), rng.uniform(0.025, 0.08, n)]
    box_pts = np.vstack([top, front])
    can_side = np.c_[rng.uniform(-0.04, 0.04, 400), rng.uniform(0.045, 0.048, 400),
                     rng.uniform(0.015, 0.035, 400)]
    beside = complete_from_points(box_pts, [0, 0, 0], [0, 0, 1], below_points_world=can_side)
    assert beside.bottom_m == pytest.approx(0.0, abs=1e-6)
    high = box_pts[box_pts[:, 2] >= 0.045]
    xy = rng.uniform([-0.06, -0.05], [0.06, 0.05], (4000, 2))
    ring = xy[(np.abs(xy[:, 0]) > 0.05) | (np.abs(xy[:, 1]) > 0.04)]
    slab = np.c_[ring, rng.uniform(0.030, 0.035, len(ring))]
    under = complete_from_points(high, [0, 0, 0], [0, 0, 1], below_points_world=slab)
    assert under.bottom_m == pytest.approx(0.035, abs=0.003)


def test_a_low_object_along_one_edge_does_not_carry_it():
    """The realistic benchmark's scene_04: a cup (here a 90 x 80 x 78 mm box) whose lowest
    23 mm are hidden behind a marker lying along its front (a 17 mm cylinder's top, 12-19
    mm, within 1 cm of the footprint and below everything seen of the box). The marker is
    under one edge only, not under the box's centre: the box goes down to the table. The
    same marker under the middle of the box, across it, holds it up."""
    rng = np.random.default_rng(0)
    n = 3000
    top = np.c_[rng.uniform(-0.045, 0.045, n), rng.uniform(-0.04, 0.04, n), np.full(n, 0.078)]
    front = np.c_[rng.uniform(-0.045, 0.045, n), np.full(n, -0.04),
                  rng.uniform(0.023, 0.078, n)]
    box_pts = np.vstack([top, front])
    marker = np.c_[rng.uniform(-0.06, 0.06, 600), rng.uniform(-0.049, -0.041, 600),
                   rng.uniform(0.012, 0.019, 600)]
    edge = complete_from_points(box_pts, [0, 0, 0], [0, 0, 1], below_points_world=[marker])
    assert edge.bottom_m == pytest.approx(0.0, abs=1e-6)
    across = np.c_[rng.uniform(-0.06, 0.06, 600), rng.uniform(-0.045, 0.045, 600),
                   rng.uniform(0.012, 0.019, 600)]
    held = complete_from_points(box_pts[box_pts[:, 2] >= 0.03], [0, 0, 0], [0, 0, 1],
                                below_points_world=[across])
    assert held.bottom_m == pytest.approx(0.019, abs=0.003)


def _box_seen_above(rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    """Points of a 100 x 80 mm box's top at 80 mm and of its front face down to 45 mm:
    its lower 45 mm are hidden."""
    top = np.c_[rng.uniform(-0.05, 0.05, n), rng.uniform(-0.04, 0.04, n), np.full(n, 0.08)]
    front = np.c_[rng.uniform(-0.05, 0.05, n), np.full(n, -0.04), rng.uniform(0.045, 0.08, n)]
    return np.vstack([top, front])


def test_an_occluder_in_front_is_judged_per_object_and_is_not_a_support():
    """The box's lower part is hidden by a wall in front of it (points 5-70 mm high, within
    the footprint's 1 cm margin): given per object, the wall rises past the box's lowest
    seen point (45 mm), so it stands in front, not under, and the box reaches the table.
    Mixed into one array with nothing else, only the wall's points below 55 mm are weighed
    and 14 % of them rise past 48 mm (under the 20 % share); they held the box up until
    they had to lie under its centre too (twenty-second session), and now they do not
    either. A slab under the box (all of it below 35 mm) given
    beside the wall still holds the box up: its base lands on the slab's top within 3 mm."""
    rng = np.random.default_rng(1)
    box_pts = _box_seen_above(rng)
    wall = np.c_[rng.uniform(-0.05, 0.05, 1500), np.full(1500, -0.046),
                 rng.uniform(0.005, 0.07, 1500)]
    mixed = complete_from_points(box_pts, [0, 0, 0], [0, 0, 1], below_points_world=wall)
    assert mixed.bottom_m == pytest.approx(0.0, abs=1e-6)
    alone = complete_from_points(box_pts, [0, 0, 0], [0, 0, 1], below_points_world=[wall])
    assert alone.bottom_m == pytest.approx(0.0, abs=1e-6)
    xy = rng.uniform([-0.06, -0.05], [0.06, 0.05], (4000, 2))
    ring = xy[(np.abs(xy[:, 0]) > 0.05) | (np.abs(xy[:, 1]) > 0.04)]
    slab = np.c_[ring, rng.uniform(0.030, 0.035, len(ring))]
    on_slab = complete_from_points(box_pts, [0, 0, 0], [0, 0, 1],
                                   below_points_world=[wall, slab])
    assert on_slab.bottom_m == pytest.approx(0.035, abs=0.003)


def test_an_object_lying_across_another_rests_on_it_column_by_column():
    """A 200 x 60 mm board whose top is seen at 100 mm lies across a 80 x 80 x 60 mm box
    under its left end (x < -0.02): completed with the box as a mesh under it, the board's
    base rests on the box's top (60 mm) in the box's columns and reaches the table
    elsewhere; without it, every column reaches the table. A box taller than the board's
    top (150 mm) is beside it, not under it, and changes nothing."""
    from r2s.geometry.sdf import occupancy, raycasting_scene

    rng = np.random.default_rng(2)
    n = 6000
    board = np.c_[rng.uniform(-0.1, 0.1, n), rng.uniform(-0.03, 0.03, n), np.full(n, 0.10)]
    under = trimesh.creation.box((0.08, 0.08, 0.06))
    under.apply_translation([-0.06, 0.0, 0.03])
    probes = np.array([[-0.06, 0.0, 0.03],   # inside the box under the board
                       [-0.06, 0.0, 0.08],   # between the box's top and the board's top
                       [0.06, 0.0, 0.03]])   # under the board's free end
    for meshes, expected in (([under], [False, True, True]), ([], [True, True, True])):
        done = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=meshes)
        world = done.mesh.copy().apply_transform(done.world_from_object)
        inside = occupancy(raycasting_scene(world.vertices, world.faces), probes)
        assert inside.tolist() == expected
    rest = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=[under])
    lowest_over_box = _lowest_at(rest, -0.06)
    assert lowest_over_box == pytest.approx(0.06, abs=0.004)
    tall = trimesh.creation.box((0.08, 0.08, 0.15))
    tall.apply_translation([-0.06, 0.0, 0.075])
    beside = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=[tall])
    assert _lowest_at(beside, -0.06) == pytest.approx(0.0, abs=0.004)


def test_an_object_across_two_supports_spans_the_gap_between_them():
    """The same board (top seen at 100 mm, 200 x 60 mm) across two 60 mm boxes under its
    ends (x < -0.04 and x > 0.04): it rests on both, its centre of mass lies between them,
    so the 80 mm gap under its middle stays empty: the board is 100 - 60 = 40 mm thick
    there too, and its underside in the gap is at 60 mm (within a cell, 4 mm). With one
    box only (the test above) its middle still reaches the table. A box 90 mm high under
    each end would make a 10 mm board, so the gap's underside is at 90 mm."""
    rng = np.random.default_rng(4)
    n = 6000
    board = np.c_[rng.uniform(-0.1, 0.1, n), rng.uniform(-0.03, 0.03, n), np.full(n, 0.10)]

    def boxes(height_m: float) -> list:
        out = []
        for x in (-0.07, 0.07):
            b = trimesh.creation.box((0.06, 0.08, height_m))
            out.append(b.apply_translation([x, 0.0, height_m / 2]))
        return out

    across = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=boxes(0.06))
    assert _lowest_at(across, 0.0) == pytest.approx(0.06, abs=0.004)
    assert _lowest_at(across, -0.07) == pytest.approx(0.06, abs=0.004)
    thin = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=boxes(0.09))
    assert _lowest_at(thin, 0.0) == pytest.approx(0.09, abs=0.004)
    alone = complete_from_points(board, [0, 0, 0], [0, 0, 1])
    assert _lowest_at(alone, 0.0) == pytest.approx(0.0, abs=0.004)


def test_what_overhangs_the_block_it_rests_on_does_not_hang_below_the_blocks_top():
    """A clamp-like object lies on a 80 x 80 x 208 mm block (x < 0): its top is seen at
    250 mm over the block and at 220 mm where it overhangs the block's edge (0 < x <
    60 mm). Where it rests it is 250 - 208 = 42 mm thick; the overhang, taken as thick,
    would end at 178 mm, 30 mm below the block's top, and catch on its edge. Its
    underside there is at the block's top instead (within a cell, 4 mm), and over the
    block it still rests on the block's top."""
    rng = np.random.default_rng(5)
    on = np.c_[rng.uniform(-0.07, 0.0, 4000), rng.uniform(-0.02, 0.02, 4000), np.full(4000, 0.25)]
    out = np.c_[rng.uniform(0.0, 0.06, 3000), rng.uniform(-0.02, 0.02, 3000), np.full(3000, 0.22)]
    block = trimesh.creation.box((0.08, 0.08, 0.208)).apply_translation([-0.04, 0.0, 0.104])
    done = complete_from_points(np.r_[on, out], [0, 0, 0], [0, 0, 1], under_meshes_world=[block])
    assert _lowest_at(done, -0.04) == pytest.approx(0.208, abs=0.004)
    assert _lowest_at(done, 0.04) == pytest.approx(0.208, abs=0.004)


def test_the_looser_bridge_guards_span_a_gap_the_strict_ones_leave_to_the_table():
    """The board (top seen at 100 mm) across two boxes only 40 mm high: it would be 60 mm
    thick, 0.6 of its height over the gap. The strict guards (at most 0.5) take that for
    a tall thing beside low ones, and its middle reaches the table; the looser ones
    (0.7), which make init's second completion, span the gap with its underside at the
    boxes' top (within a cell, 4 mm). ``bridged`` says which happened."""
    board, boxes = _board_over_two_boxes(0.10, seed=6)
    strict = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=boxes)
    loose = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=boxes,
                                 bridge_guards=RELAXED_BRIDGE)
    assert not strict.bridged and loose.bridged
    assert _lowest_at(strict, 0.0) == pytest.approx(0.0, abs=0.004)
    assert _lowest_at(loose, 0.0) == pytest.approx(0.04, abs=0.004)
    assert _lowest_at(loose, -0.07) == pytest.approx(0.04, abs=0.004)


def test_a_bridged_completion_and_its_alternative_reaching_the_table():
    """A thin board (top seen at 60 mm) across two 40 mm boxes is bridged by the strict
    guards: its middle ends 20 mm under its top, over the gap. With the guards that never
    bridge (init's alternative for a bridged object, tried by physopt where the bridged
    one cannot rest near where it was seen) the middle reaches the table (within a cell,
    4 mm), and over the boxes it still rests on them."""
    board, boxes = _board_over_two_boxes(0.06, seed=7)
    strict = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=boxes)
    table = complete_from_points(board, [0, 0, 0], [0, 0, 1], under_meshes_world=boxes,
                                 bridge_guards=NO_BRIDGE)
    assert strict.bridged and not table.bridged
    assert _lowest_at(strict, 0.0) == pytest.approx(0.04, abs=0.004)
    assert _lowest_at(table, 0.0) == pytest.approx(0.0, abs=0.004)
    assert _lowest_at(table, -0.07) == pytest.approx(0.04, abs=0.004)


def _board_over_two_boxes(top_m: float, seed: int) -> tuple[np.ndarray, list]:
    """(6000, 3) points of a board's top seen at ``top_m`` (200 x 60 mm, world frame, the
    table at z = 0) and two 60 x 80 x 40 mm boxes under its ends (centres at x = +-70 mm)."""
    rng = np.random.default_rng(seed)
    n = 6000
    board = np.c_[rng.uniform(-0.1, 0.1, n), rng.uniform(-0.03, 0.03, n), np.full(n, top_m)]
    boxes = [trimesh.creation.box((0.06, 0.08, 0.04)).apply_translation([x, 0.0, 0.02])
             for x in (-0.07, 0.07)]
    return board, boxes


def _lowest_at(done, x: float) -> float:
    """Height of the completed mesh's underside at (x, 0), cast upward from below."""
    import open3d as o3d
    from r2s.geometry.sdf import raycasting_scene

    world = done.mesh.copy().apply_transform(done.world_from_object)
    scene = raycasting_scene(world.vertices, world.faces)
    ray = np.array([[x, 0.0, -1.0, 0.0, 0.0, 1.0]], dtype=np.float32)
    return float(scene.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0]) - 1.0
