"""Penetration and floating of a loaded export scene, against hand-placed boxes."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest
import trimesh
from helpers_export import Obj, pose, write_export

from r2s.metrics.penetration import (SUPPORT_ID, SceneDistances, penetration_metrics,
                                     scene_distances)
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import load_export_scene

BOX_M = 0.1
TOL_MM = 0.5


def _metrics(tmp_path, objects, **support):
    write_export(tmp_path / "export", objects, **support)
    client = connect_direct()
    try:
        loaded = load_export_scene(client, tmp_path / "export")
        dist = scene_distances(client, loaded)
    finally:
        pb.disconnect(client)
    return dist, penetration_metrics(dist)


def _box(size=BOX_M):
    return trimesh.creation.box([size, size, size])


def test_two_boxes_overlapping_5mm(tmp_path):
    objs = [Obj(1, _box(), pose([0, 0, BOX_M / 2])),
            Obj(2, _box(), pose([BOX_M - 0.005, 0, BOX_M / 2]))]
    _, m = _metrics(tmp_path, objs)
    assert m.max_penetration_mm == pytest.approx(5.0, abs=TOL_MM)
    assert m.object_max_penetration_mm == pytest.approx(5.0, abs=TOL_MM)
    # both rest exactly on the plane: that is contact, not penetration
    assert [(a, b) for a, b, _ in m.penetrating_pairs] == [(1, 2)]
    assert m.mean_penetration_mm == pytest.approx(5.0, abs=TOL_MM)
    np.testing.assert_allclose(m.per_object_penetration_mm, [5.0, 5.0], atol=TOL_MM)
    assert m.floating_objects == 0


def test_box_5mm_above_plane_floats(tmp_path):
    dist, m = _metrics(tmp_path, [Obj(1, _box(), pose([0, 0, BOX_M / 2 + 0.005]))])
    assert dist.object_support_m[0] == pytest.approx(0.005, abs=TOL_MM / 1000)
    assert m.per_object_gap_mm[0] == pytest.approx(5.0, abs=TOL_MM)
    assert bool(m.floating[0]) and m.floating_objects == 1
    assert m.max_penetration_mm == 0.0


def test_resting_box_touches(tmp_path):
    _, m = _metrics(tmp_path, [Obj(1, _box(), pose([0, 0, BOX_M / 2]))])
    assert m.per_object_gap_mm[0] == pytest.approx(0.0, abs=0.01)
    assert m.floating_objects == 0 and m.max_penetration_mm == 0.0


def test_small_box_sunk_3mm_into_tilted_plane(tmp_path):
    """Margin correction holds for another size and a plane not through the origin."""
    normal = np.array([0.0, np.sin(0.3), np.cos(0.3)])
    point = np.array([0.2, -0.1, 0.05])
    rot = trimesh.geometry.align_vectors([0, 0, 1], normal)[:3, :3]
    centre = point + normal * (0.01 - 0.003)  # 2 cm cube, 3 mm into the plane
    objs = [Obj(4, _box(0.02), pose(centre, rot), mass_kg=0.01)]
    _, m = _metrics(tmp_path, objs, support_point=point, support_normal=normal)
    assert m.max_penetration_mm == pytest.approx(3.0, abs=0.3)
    assert m.penetrating_pairs[0][:2] == [4, SUPPORT_ID]
    assert m.object_max_penetration_mm == 0.0


def test_compound_body_uses_all_pieces(tmp_path):
    """Object 1 is two convex halves; its +x half overlaps object 2 by 4 mm."""
    left = trimesh.creation.box([BOX_M / 2, BOX_M, BOX_M])
    left.apply_translation([-BOX_M / 4, 0, 0])
    right = left.copy()
    right.apply_translation([BOX_M / 2, 0, 0])
    objs = [Obj(1, _box(), pose([0, 0, BOX_M / 2 + 0.02]), pieces=[left, right]),
            Obj(2, _box(), pose([BOX_M - 0.004, 0, BOX_M / 2 + 0.02]))]
    _, m = _metrics(tmp_path, objs)
    assert m.max_penetration_mm == pytest.approx(4.0, abs=TOL_MM)
    np.testing.assert_allclose(m.per_object_gap_mm, [0.0, 0.0])  # touching each other


def test_penetration_metrics_pure():
    inf = np.inf
    dist = SceneDistances(
        ids=np.array([3, 5, 7]),
        object_object_m=np.array([[inf, -0.002, 0.010], [-0.002, inf, -0.004],
                                  [0.010, -0.004, inf]]),
        object_support_m=np.array([-0.006, 0.003, 2e-7]),
    )
    m = penetration_metrics(dist, floating_gap_mm=2.0)
    assert m.max_penetration_mm == pytest.approx(6.0)
    assert m.mean_penetration_mm == pytest.approx((6 + 2 + 4) / 3)
    assert m.object_max_penetration_mm == pytest.approx(4.0)
    assert m.object_mean_penetration_mm == pytest.approx(3.0)
    assert [p[:2] for p in m.penetrating_pairs] == [[3, SUPPORT_ID], [5, 7], [3, 5]]
    np.testing.assert_allclose(m.per_object_penetration_mm, [6.0, 4.0, 4.0])
    np.testing.assert_allclose(m.per_object_gap_mm, [0.0, 0.0, 0.0])
    assert m.floating_objects == 0

    apart = SceneDistances(ids=np.array([1, 2]),
                           object_object_m=np.array([[inf, 0.05], [0.05, inf]]),
                           object_support_m=np.array([0.001, 0.0035]))
    m = penetration_metrics(apart, floating_gap_mm=2.0)
    np.testing.assert_allclose(m.per_object_gap_mm, [1.0, 3.5])
    assert m.floating.tolist() == [False, True] and m.max_penetration_mm == 0.0
