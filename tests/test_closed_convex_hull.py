"""closed_convex_hull: trimesh's hull when it is closed, else qhull's triangles rebuilt."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.geometry.convex import closed_convex_hull, convex_decomposition
from r2s.geometry.mass_properties import mass_properties


def _open_hull(self: trimesh.Trimesh) -> trimesh.Trimesh:
    """A convex hull with one face missing, as trimesh returned for a 2 mm completion of a
    long box (not watertight, encloses no volume)."""
    hull = trimesh.convex.convex_hull(self)
    return trimesh.Trimesh(hull.vertices, hull.faces[1:], process=False)


def _box_with_flat_grid() -> trimesh.Trimesh:
    """A 19.2 x 6 x 4 cm box with many vertices on each face (a subdivided box)."""
    box = trimesh.creation.box((0.192, 0.06, 0.04))
    for _ in range(3):
        box = box.subdivide()
    return box


def test_the_hull_of_a_closed_hull_is_kept():
    box = _box_with_flat_grid()
    hull = closed_convex_hull(box)
    assert hull.is_volume
    assert hull.volume == pytest.approx(0.192 * 0.06 * 0.04, rel=1e-9)


@pytest.fixture
def open_hulls(monkeypatch):
    monkeypatch.setattr(trimesh.Trimesh, "convex_hull", property(_open_hull))


def test_an_open_hull_is_rebuilt_closed(open_hulls):
    box = _box_with_flat_grid()
    assert not box.convex_hull.is_volume  # what the fallback is for
    hull = closed_convex_hull(box)
    assert hull.is_volume
    assert hull.volume == pytest.approx(0.192 * 0.06 * 0.04, rel=1e-9)
    np.testing.assert_allclose(hull.bounds, box.bounds, atol=1e-12)


def test_a_nearly_convex_shape_gets_one_closed_piece(open_hulls):
    pieces = convex_decomposition(_box_with_flat_grid())
    assert len(pieces) == 1 and pieces[0].is_volume
    assert pieces[0].volume == pytest.approx(0.192 * 0.06 * 0.04, rel=1e-9)


def test_mass_properties_of_an_open_mesh_fall_back_to_a_closed_hull(open_hulls):
    """An open box (top face missing) with no pieces: the hull's exact mass properties."""
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    top = box.face_normals[:, 2] > 0.9
    opened = trimesh.Trimesh(box.vertices, box.faces[~top], process=False)
    props = mass_properties(opened)
    assert props.volume_m3 == pytest.approx(0.1 * 0.06 * 0.04, rel=1e-9)
    np.testing.assert_allclose(props.com_in_object, 0.0, atol=1e-12)




def test_a_flat_mesh_keeps_trimeshs_hull(open_hulls):
    """Flat vertices enclose no volume: no rebuild is tried, and nothing raises."""
    flat = trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0]],
                           [[0, 1, 2], [1, 3, 2]], process=False)
    with np.errstate(invalid="ignore", divide="ignore"):  # trimesh: a flat hull's centre
        hull = closed_convex_hull(flat)
        assert not hull.is_volume
