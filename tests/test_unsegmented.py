"""Unmasked things on the table: a segmenter's missed objects (geometry/unsegmented.py).

The hand-made scene of ``helpers_diagnose`` (320 x 240, ray cast, 0.5 mm depth noise),
once as made and once with a small box stacked on a larger one. Known answers: with every
object masked, nothing is found, also with the masks eroded by 2 px (a segmenter's tight
masks leave a ring of object pixels unmasked) and with a wall behind the table; with one
object's mask removed, exactly one region is found where it stands, as tall as it is;
an object stacked on the unmasked one is named as resting on it, its neighbour on the
table is not.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from scipy import ndimage

import helpers_diagnose
from helpers_diagnose import input_scene
from r2s.geometry.plane import fit_plane_ransac
from r2s.geometry.camera import backproject
from r2s.geometry.unsegmented import unsegmented_regions
from r2s.stages import init as init_stage


def _regions(scene):
    cam = scene.camera
    pts = backproject(scene.depth_m, cam.K, cam.world_from_camera, scene.masks == 0)
    plane = fit_plane_ransac(pts, threshold_m=0.005, seed=0)
    return unsegmented_regions(scene.depth_m, cam.K, cam.world_from_camera, scene.masks,
                               plane.point, plane.normal)


def _without(scene, obj_id: int):
    masks = scene.masks.copy()
    masks[masks == obj_id] = 0
    return replace(scene, masks=masks, objects=[o for o in scene.objects if o.id != obj_id])


def test_nothing_is_found_when_every_object_is_masked():
    scene = input_scene()
    assert _regions(scene) == []
    eroded = scene.masks.copy()
    for i in scene.ids:
        inner = ndimage.binary_erosion(scene.masks == i, iterations=2)
        eroded[(scene.masks == i) & ~inner] = 0
    assert _regions(replace(scene, masks=eroded)) == []


def test_a_wall_behind_the_table_is_not_an_object(monkeypatch):
    render = helpers_diagnose.render
    monkeypatch.setattr(helpers_diagnose, "render",
                        lambda **kw: render(wall_y_m=0.25, table_size_m=0.6, **kw))
    scene = input_scene()
    assert (scene.masks == 0).mean() > 0.5
    assert _regions(scene) == []


def test_an_unmasked_box_is_found_where_it_stands():
    scene = input_scene()
    box_pixels = scene.masks == 1
    found = _regions(_without(scene, 1))
    assert len(found) == 1
    region = found[0]
    # the box is 50 mm tall: its top face is the top of the region (noise 0.5 mm)
    assert region.height_m == pytest.approx(0.05, abs=0.003)
    # its mask, less what stands under 15 mm (the sides' foot) and the 4 px kept from the
    # other masks (object 3 stands in front of its corner)
    assert 0.6 * box_pixels.sum() <= region.area_px <= box_pixels.sum()
    rows, cols = np.nonzero(box_pixels)
    r0, c0, r1, c1 = region.box_px
    assert r0 >= rows.min() and r1 <= rows.max() and c0 >= cols.min() and c1 <= cols.max()
    # the box stands at (-0.09, 0.06); the region's points are its visible faces
    assert np.linalg.norm(region.centre_world[:2] - [-0.09, 0.06]) < 0.02
    assert 1 not in region.touching_ids
    # the box standing on the table that holds what was seen: the 80 x 60 x 50 mm box at
    # yaw 20 deg (its top face is seen whole; 1st-99th percentiles across)
    size = np.sort(region.size_m[:2])[::-1]
    assert size == pytest.approx([0.08, 0.06], abs=0.006)
    assert region.size_m[2] == pytest.approx(0.05, abs=0.003)
    long_axis = region.world_from_box[:3, 0] if region.size_m[0] >= region.size_m[1] \
        else region.world_from_box[:3, 1]
    yaw = np.degrees(np.arctan2(long_axis[1], long_axis[0])) % 180.0
    assert yaw == pytest.approx(20.0, abs=5.0)
    assert region.world_from_box[:3, 3] == pytest.approx([-0.09, 0.06, 0.025], abs=0.006)


def test_an_object_stacked_on_an_unmasked_one_is_named(monkeypatch):
    def stacked(with_ball: bool = True):
        base = trimesh.creation.box((0.12, 0.10, 0.05))
        top = trimesh.creation.box((0.05, 0.05, 0.04))
        beside = trimesh.creation.cylinder(0.03, 0.09, sections=32)
        pose_top = np.eye(4)
        pose_top[:3, 3] = [-0.02, 0.0, 0.05 + 0.02]
        return [(1, base, helpers_diagnose._placed(base, (-0.02, 0.0), 0.0)),
                (2, top, pose_top),
                (3, beside, helpers_diagnose._placed(beside, (0.06, 0.09), 0.0))]

    monkeypatch.setattr(helpers_diagnose, "scene_objects", stacked)
    scene = _without(input_scene(), 1)
    options = init_stage.Options()
    plane, _ = init_stage._fit_support(scene, options)
    observed = {o.id: init_stage._object_points(scene, o.id, options, plane)
                for o in scene.objects}
    lines: list[str] = []
    extra, pixels = init_stage._unsegmented(scene, plane, observed, options, lines)
    records = extra["unsegmented"]
    assert pixels.shape == scene.masks.shape and pixels.sum() == records[0]["area_px"]
    assert len(records) == 1 and len(lines) == 1
    assert 2 in records[0]["touching_ids"]
    assert records[0]["rests_on_it"] == [2]
    assert records[0]["height_m"] == pytest.approx(0.05, abs=0.003)
    assert lines[0].startswith("unsegmented: ") and "object 2 may rest on it" in lines[0]
    off = init_stage.Options(find_unsegmented=False)
    assert init_stage._unsegmented(scene, plane, observed, off, lines) == ({}, None)
    assert len(lines) == 1


def test_the_fit_picture_tints_and_outlines_the_unmasked_pixels():
    from r2s.geometry.overlay import UNMASKED_COLOR, fit_overlay

    rgb = np.full((40, 60, 3), 100, np.uint8)
    masks = np.zeros((40, 60), np.int32)
    masks[5:15, 5:15] = 1
    rendered = np.where(masks == 1, 0, -1)
    unmasked = np.zeros((40, 60), bool)
    unmasked[20:35, 30:50] = True
    plain = fit_overlay(rgb, rendered, masks, [1])
    marked = fit_overlay(rgb, rendered, masks, [1], unmasked=unmasked)
    assert np.array_equal(plain[~unmasked], marked[~unmasked])
    assert (marked[20, 30] == UNMASKED_COLOR).all()  # the outline
    inside = marked[27, 40].astype(float)  # tinted: 0.6 grey + 0.4 magenta
    assert inside == pytest.approx(0.6 * 100 + 0.4 * UNMASKED_COLOR, abs=1)


def test_the_export_file_lists_the_boxes(tmp_path):
    from r2s.io.unmodelled import UNMODELLED_FILE, write_unmodelled

    record = {"area_px": 500, "box_px": [1, 2, 3, 4], "height_m": 0.05,
              "centre_world": [0.0, 0.0, 0.02], "touching_ids": [2], "rests_on_it": [],
              "world_from_box": np.eye(4).tolist(), "size_m": [0.08, 0.06, 0.05]}
    write_unmodelled(tmp_path, [record])
    data = json.loads((tmp_path / UNMODELLED_FILE).read_text())
    assert data["format"] == "r2s-unmodelled" and data["version"] == 1
    (region,) = data["regions"]
    assert region["size_m"] == [0.08, 0.06, 0.05] and region["world_from_box"] == np.eye(4).tolist()
    assert "centre_world" not in region and region["touching_ids"] == [2]
