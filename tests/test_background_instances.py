"""A segmenter's mask of the table is background, not an object (geometry/background_instances.py).

The hand-made scene of ``helpers_diagnose`` (320 x 240, four objects on a 1.2 m table that
fills the view) with the table's pixels given an instance id of their own, as panoptic
networks do. Known answer: that id is taken as background and the four objects stay; a
tray-sized piece of the same table under the objects (seen whole, off no side of the
image) stays an object.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from helpers_diagnose import input_scene
from r2s.geometry.background_instances import background_instances
from r2s.io.input_scene import ObjectSpec
from r2s.scene_model import corrected_input

TABLE_ID = 9


def _with_table_instance(window: tuple[slice, slice] | None = None):
    scene = input_scene(noise_m=0.0005)
    masks = scene.masks.copy()
    table = masks == 0
    if window is not None:
        inside = np.zeros_like(table)
        inside[window] = True
        table &= inside
    masks[table] = TABLE_ID
    objects = scene.objects + [ObjectSpec(TABLE_ID, "segment")]
    return replace(scene, masks=masks, objects=objects)


def test_a_table_segmented_as_an_instance_is_background():
    scene = _with_table_instance()
    cam = scene.camera
    found = background_instances(scene.masks, scene.depth_m, cam.K, cam.world_from_camera,
                                 scene.ids)
    assert [b.id for b in found] == [TABLE_ID]
    assert found[0].borders == 4 and found[0].area_fraction > 0.6
    assert found[0].planar_fraction > 0.95
    out = corrected_input(scene, {})
    assert out.ids == [1, 2, 3, 4]
    assert not (out.masks == TABLE_ID).any()
    assert np.array_equal(out.masks == 0, scene.masks == TABLE_ID)
    assert any(w.startswith(f"masks.png: instance {TABLE_ID} covers ") for w in out.warnings)


def test_a_tray_seen_whole_stays_an_object():
    # the table's pixels in a window around the objects: a plane under them, but seen whole
    rows, cols = np.nonzero(input_scene().masks > 0)
    window = (slice(rows.min() - 40, rows.max() + 40), slice(cols.min() - 40, cols.max() + 40))
    scene = _with_table_instance(window)
    assert (scene.masks == TABLE_ID).mean() > 0.2  # as large as a table would need to be
    cam = scene.camera
    assert background_instances(scene.masks, scene.depth_m, cam.K, cam.world_from_camera,
                                scene.ids) == []
    assert TABLE_ID in corrected_input(scene, {}).ids


def test_objects_are_never_taken_as_background():
    scene = input_scene(noise_m=0.0005)
    cam = scene.camera
    assert background_instances(scene.masks, scene.depth_m, cam.K, cam.world_from_camera,
                                scene.ids) == []
