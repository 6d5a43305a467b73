"""Hidden space claimed by two completed objects (r2s/geometry/hidden_partition.py): it
goes to the object whose observed surface is nearer; a prior keeps all of its inside."""

from __future__ import annotations

import numpy as np
import trimesh

from r2s.geometry.hidden_partition import Claimant, exclusion, overlaps


def _face_points(x_m: float) -> np.ndarray:
    """Observed points on the plane x = x_m (a seen face), 5 mm grid."""
    y, z = np.meshgrid(np.linspace(-0.05, 0.05, 21), np.linspace(0.0, 0.05, 11))
    return np.c_[np.full(y.size, x_m), y.ravel(), z.ravel()]


def test_hidden_space_goes_to_the_nearer_observed_surface():
    """This object was seen at x = 0, the other at x = 0.1 and its completed box spans
    x = 0.03..0.13. Nodes inside that box at x = 0.04 (4 cm from this object's surface, 6
    from the other's) stay; at x = 0.08 they are the other's; outside the box (x = 0.2,
    x = 0.02) nothing is excluded. Were the other a prior, all of its inside is its own."""
    box = trimesh.creation.box((0.10, 0.2, 0.1))
    box.apply_translation((0.08, 0.0, 0.025))
    nodes = np.array([[0.04, 0.0, 0.02], [0.08, 0.0, 0.02], [0.2, 0.0, 0.02],
                      [0.02, 0.0, 0.02]])
    other = Claimant(box, _face_points(0.1))
    np.testing.assert_array_equal(exclusion(_face_points(0.0), [other])(nodes),
                                  [False, True, False, False])
    prior = Claimant(box, _face_points(0.1), is_prior=True)
    np.testing.assert_array_equal(exclusion(_face_points(0.0), [prior])(nodes),
                                  [True, True, False, False])


def test_overlap_is_judged_on_vertices_inside_another_mesh():
    """A 4 cm cube sunk 2 cm into a 10 cm box overlaps it (about half of its vertices
    inside, >= 1 %); the same cube 1 cm clear of the box does not."""
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    cube = trimesh.creation.box((0.04, 0.04, 0.04)).subdivide().subdivide()
    sunk = cube.copy().apply_translation((0.05, 0.0, 0.0))  # spans x = 0.03..0.07
    clear = cube.copy().apply_translation((0.08, 0.0, 0.0))  # spans x = 0.06..0.10
    assert overlaps(sunk, [Claimant(box, np.zeros((0, 3)))])
    assert not overlaps(clear, [Claimant(box, np.zeros((0, 3)))])
