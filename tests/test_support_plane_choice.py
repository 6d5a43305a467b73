"""The support is the plane the objects stand on, not the largest level plane in view.

The hand-made scene of ``helpers_diagnose`` with a 0.36 m table and a floor 0.3 m below it,
seen past the table's edges: the floor holds about 9 times as many background pixels as the
table (measured: 64,000 against 7,000). Known answer: the table is ``z = 0`` with normal +z.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers_diagnose import render, write_scene
from r2s.diagnose.data import Residuals
from r2s.diagnose.measure.observe import support_residual, table_shape_residual
from r2s.diagnose.stats.structure_test import test_structure as structure_test
from r2s.geometry.camera import backproject
from r2s.geometry.plane import fit_plane_ransac, fit_support_plane, standing_gap_m
from r2s.io.input_scene import Camera, InputScene, ObjectSpec

FLOOR_DROP_M = 0.3


def _points(r: dict) -> tuple[np.ndarray, list[np.ndarray]]:
    depth = np.where(r["depth"] > 0, r["depth"], np.nan)
    background = backproject(depth, r["K"], r["world_from_camera"], r["masks"] == 0)
    objects = [backproject(depth, r["K"], r["world_from_camera"], r["masks"] == i)
               for i, _, _ in r["objects"]]
    return background, objects


@pytest.fixture(scope="module")
def floor_scene() -> dict:
    # a thin board: the side faces of a thick one would be a structure of their own
    return render(table_size_m=0.36, floor_drop_m=FLOOR_DROP_M, table_thickness_m=0.002,
                  noise_m=0.0005)


def test_the_objects_choose_the_table_over_a_larger_floor(floor_scene):
    background, objects = _points(floor_scene)
    viewpoint = floor_scene["world_from_camera"][:3, 3]
    largest = fit_plane_ransac(background, viewpoint=viewpoint, max_tilt_deg=45.0)
    assert largest.point[2] == pytest.approx(-FLOOR_DROP_M, abs=0.002)  # the test bites
    assert standing_gap_m(largest, objects) == pytest.approx(FLOOR_DROP_M, abs=0.01)
    support = fit_support_plane(background, objects, viewpoint=viewpoint, max_tilt_deg=45.0)
    assert support.point[2] == pytest.approx(0.0, abs=0.001)
    assert np.degrees(np.arccos(support.normal[2])) < 0.2
    assert 0.0 <= standing_gap_m(support, objects) < 0.015  # lowest visible points
    assert np.all(np.abs(background[support.inliers, 2]) < 0.006)
    only_largest = fit_support_plane(background, objects, viewpoint=viewpoint,
                                     max_tilt_deg=45.0, max_candidates=1)
    assert only_largest.point[2] == pytest.approx(-FLOOR_DROP_M, abs=0.002)


def test_a_table_filling_the_view_gives_the_largest_plane_unchanged():
    r = render(noise_m=0.0005)
    background, objects = _points(r)
    viewpoint = r["world_from_camera"][:3, 3]
    largest = fit_plane_ransac(background, viewpoint=viewpoint, max_tilt_deg=45.0)
    support = fit_support_plane(background, objects, viewpoint=viewpoint, max_tilt_deg=45.0)
    assert np.array_equal(support.point, largest.point)
    assert np.array_equal(support.normal, largest.normal)
    assert np.array_equal(support.inliers, largest.inliers)


def test_diagnose_measures_the_table_not_the_floor(floor_scene):
    r = floor_scene
    inp = InputScene(rgb=np.zeros((*r["depth"].shape, 3), np.uint8),
                     depth_m=np.where(r["depth"] > 0, r["depth"], np.nan).astype(np.float32),
                     masks=r["masks"].astype(np.int32),
                     camera=Camera(K=r["K"], world_from_camera=r["declared"],
                                   width=r["depth"].shape[1], height=r["depth"].shape[0]),
                     objects=[ObjectSpec(id=i, label=f"object_{i}") for i, _, _ in r["objects"]])
    support = support_residual(inp, np.array([0.0, 0.0, -9.81]), float(np.radians(0.3)))
    assert support.point[2] == pytest.approx(0.0, abs=0.001)
    world_from_camera = r["declared"]

    def heights(data) -> np.ndarray:
        pts = data.points_camera @ world_from_camera[:3, :3].T + world_from_camera[:3, 3]
        return pts[:, 2]

    # without the support, the "table" residual is mostly the floor
    assert np.mean(heights(table_shape_residual(inp, 0.0004)) < -0.2) > 0.5
    table = table_shape_residual(inp, 0.0004, support=support)
    assert np.all(np.abs(heights(table)) < 0.005)
    shape = structure_test(Residuals(table_shape=table))
    assert not shape.structured and shape.p_value > 0.01


def _init(scene, **options) -> tuple[dict, list[str]]:
    from r2s.runner.base import run_stage
    from r2s.runner.registry import get_stage

    init = get_stage("init")
    run_stage(init, scene, init.options_type(**options))
    state = json.loads((scene / "init" / "state.json").read_text())
    flags = json.loads((scene / "manifest.json").read_text())["stages"]["init"]["summary"]["flags"]
    return state["support"], flags


@pytest.mark.slow
def test_init_stands_the_objects_on_the_table(tmp_path):
    scene = write_scene(tmp_path / "scene", table_size_m=0.36, floor_drop_m=FLOOR_DROP_M,
                        table_thickness_m=0.002)
    support, flags = _init(scene)
    assert support["point"][2] == pytest.approx(0.0, abs=0.001)
    assert support["normal"][2] == pytest.approx(1.0, abs=1e-5)
    assert not any(f.startswith("support plane:") for f in flags)
    # the largest plane alone is the floor, and the objects floating above it are flagged
    support, flags = _init(scene, plane_candidates=1)
    assert support["point"][2] == pytest.approx(-FLOOR_DROP_M, abs=0.002)
    gap = [f for f in flags if f.startswith("support plane: the objects' lowest points are ")]
    assert len(gap) == 1
    assert float(gap[0].split(" are ")[1].split(" mm")[0]) == pytest.approx(1000 * FLOOR_DROP_M,
                                                                             abs=15)
