"""The free-space term of the pose optimisation (r2s.geomopt.free_space) against known answers.

Camera 1 m above the origin looking straight down (f = 500 px, image u along world +x).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from r2s.geometry.sdf import compute_sdf
from r2s.geomopt.free_space import FreeSpaceTerm, observed_view
from r2s.geomopt.optimise import TABLE, GeomParams, GeomProblem, optimise_poses
from r2s.metrics.observation import observe_scene
from r2s.render.gbuffer import rasterize

W, H, F = 160, 120, 500.0
K = np.array([[F, 0.0, 79.5], [0.0, F, 59.5], [0.0, 0.0, 1.0]])
CAMERA = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.0],
                   [0.0, 0.0, 0.0, 1.0]])


def world_at(u: float, v: float, depth: float) -> list[float]:
    return [(u - K[0, 2]) * depth / F, -(v - K[1, 2]) * depth / F, 1.0 - depth]


def test_cost_is_the_distance_outside_the_band_in_metres():
    masks = np.zeros((H, W), np.int32)
    masks[:, :60] = 1                                   # columns 0..59
    depth = np.full((H, W), 1.0)
    depth[:10] = np.nan                                 # no reading in the top rows
    depth[10:20] = 0.81                                 # only 10 mm behind a point at 0.8
    pts = torch.tensor([[world_at(70.0, 60, 0.8),       # 11 px from the mask: 9 px over
                         world_at(70.5, 60, 0.8),       # 11.5 px: 9.5 over
                         world_at(61.0, 60, 0.8),       # inside the 2 px band
                         world_at(30.0, 60, 0.8),       # inside the mask
                         world_at(90.0, 5, 0.8),        # no depth reading
                         world_at(90.0, 15, 0.8),       # observed surface too close behind
                         world_at(90.0, 60, 1.2)]],     # behind the observed surface
                       dtype=torch.float64, requires_grad=True)
    term = FreeSpaceTerm(observed_view(K, CAMERA, depth, masks, [1]), dtype=torch.float64)
    cost, violating = term(pts)
    expected = np.array([9.0, 9.5, 0, 0, 0, 0, 0]) * 0.8 / F
    assert cost.detach().numpy()[0] == pytest.approx(expected, abs=1e-9)
    assert violating.numpy()[0].tolist() == [True, True, False, False, False, False, False]
    cost[0, 0].backward()
    # d cost / d x_world = (z / f) * (f / z) = 1 along +x (away from the mask); nothing else
    assert pts.grad[0, 0].numpy() == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)


def _box_problem(shift_x_m: float, view):
    box = trimesh.creation.box(extents=[0.08, 0.06, 0.05])
    samples, _ = trimesh.sample.sample_surface(box, 1500, seed=0)
    init = np.eye(4)
    init[:3, 3] = [shift_x_m, 0.0, 0.025]
    grid = compute_sdf(box, resolution=40, padding_m=0.02)
    return GeomProblem(ids=[1], samples_object_m=np.asarray(samples)[None],
                       init_world_from_object=init[None], centres_world_m=init[None, :3, 3],
                       grids=[grid], plane_point=np.zeros(3), plane_normal=np.array([0, 0, 1.0]),
                       support_edges=[(0, TABLE)], view=view)


def test_optimisation_pulls_a_displaced_box_back_into_its_mask():
    truth = trimesh.creation.box(extents=[0.08, 0.06, 0.05])
    truth.apply_translation([0.0, 0.0, 0.025])
    table = trimesh.creation.box(extents=[1.0, 1.0, 0.01])
    table.apply_translation([0, 0, -0.005])
    g = rasterize([truth, table], K, CAMERA, W, H)
    masks = np.where(g.object_index == 0, 1, 0).astype(np.int32)
    depth = g.depth_m.astype(np.float64)
    view = observed_view(K, CAMERA, depth, masks, [1])
    shift = 0.025
    free = optimise_poses(_box_problem(shift, None), GeomParams())
    kept = optimise_poses(_box_problem(shift, view), GeomParams(lambda_free_space=30.0))
    x_free = free.world_from_object[0, 0, 3]
    x_kept = kept.world_from_object[0, 0, 3]
    assert x_free == pytest.approx(shift, abs=2e-3)      # nothing pulls it back
    assert abs(x_kept) < 0.5 * shift                    # the term pulls it towards its mask
    assert kept.free_space_after[0] < kept.free_space_before[0]
    assert abs(kept.world_from_object[0, 2, 3] - 0.025) < 2e-3   # still on the table

    def iou(pose):
        mesh = trimesh.creation.box(extents=[0.08, 0.06, 0.05]).apply_transform(pose)
        return observe_scene([mesh], [1], K, CAMERA, depth, masks).objects[0].iou

    assert iou(kept.world_from_object[0]) > iou(free.world_from_object[0]) + 0.1
