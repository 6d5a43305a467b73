"""The least continuation of a carrier under what it carries
(r2s/geometry/hidden_support.py), on boxes whose answer is known by construction."""

from __future__ import annotations

import numpy as np
import trimesh

from r2s.geometry.hidden_support import CELL_M, PAST_M, support_extension

UP = np.array([0.0, 0.0, 1.0])
ORIGIN = np.zeros(3)


def _box(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> trimesh.Trimesh:
    box = trimesh.creation.box((x1 - x0, y1 - y0, z1 - z0))
    box.apply_translation(((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2))
    return box


# a slab 80 mm long lying on a 50 mm tall carrier; its centre of mass at x = 10 mm
SLAB = _box(-0.03, 0.05, -0.02, 0.02, 0.05, 0.07)


def test_a_carrier_cut_where_the_slab_hides_it_is_continued_to_just_past_its_centre():
    """The completed carrier ends at x = 0 (where the slab's mask begins): the slab's
    centre of mass (x = 10 mm) is past its contact. The continuation is at the carrier's
    top (50 mm, within 1 mm), from x = 0 to 10 mm + PAST_M (within a cell), and across no
    wider than the contact (the slab's 40 mm, within a cell)."""
    cut = _box(-0.06, 0.0, -0.03, 0.03, 0.0, 0.05)
    top = support_extension(SLAB, {1: cut}, {}, ORIGIN, UP, carried_id=2)
    assert top is not None and top.carrier_id == 1 and top.carried_id == 2
    assert abs(top.height_m - 0.05) < 0.001
    x, y = top.points_world[:, 0], top.points_world[:, 1]
    assert x.min() >= 0.0 and x.min() < 2 * CELL_M
    assert abs(x.max() - (0.01 + PAST_M)) <= CELL_M
    assert y.min() >= -0.02 - CELL_M and y.max() <= 0.02 + CELL_M
    assert np.allclose(top.points_world[:, 2], top.height_m)


def test_nothing_is_added_where_the_slab_already_rests():
    """On the whole carrier, or across two carriers on either side of its centre of mass,
    the slab rests as it is: no continuation."""
    whole = _box(-0.06, 0.06, -0.03, 0.03, 0.0, 0.05)
    assert support_extension(SLAB, {1: whole}, {}, ORIGIN, UP) is None
    left = _box(-0.04, -0.01, -0.03, 0.03, 0.0, 0.05)
    right = _box(0.03, 0.06, -0.03, 0.03, 0.0, 0.05)
    assert support_extension(SLAB, {1: left, 3: right}, {}, ORIGIN, UP) is None


def test_a_slab_above_the_carrier_with_a_gap_gets_nothing():
    """10 mm above the cut carrier the slab touches nothing: there is no contact to
    continue (what carries it is not that carrier's top)."""
    cut = _box(-0.06, 0.0, -0.03, 0.03, 0.0, 0.04)
    assert support_extension(SLAB, {1: cut}, {}, ORIGIN, UP) is None


def test_a_registered_prior_is_never_continued_but_counts_as_support():
    """A prior under the slab's far end carries it with the cut carrier: nothing is
    added. The same prior alone as the only thing touching: it is not a carrier that
    may be continued, so nothing is added either."""
    cut = _box(-0.06, 0.0, -0.03, 0.03, 0.0, 0.05)
    prior = _box(0.03, 0.06, -0.03, 0.03, 0.0, 0.05)
    assert support_extension(SLAB, {1: cut}, {7: prior}, ORIGIN, UP) is None
    assert support_extension(SLAB, {}, {7: cut}, ORIGIN, UP) is None
