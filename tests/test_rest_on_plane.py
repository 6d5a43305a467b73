"""A shape set down alone on a plane (r2s/sim/rest_on_plane.py) and the prior choice's rest
rule (r2s/geometry/prior_choice.py): known answers on boxes and a plate on a table at z = 0."""

import numpy as np
import trimesh

from r2s.geometry.prior_choice import Rest, RestRule, ViewScore, choose, stands_alone_on_table
from r2s.sim.rest_on_plane import SET_DOWN_GAP_M, rest_on_plane

TABLE = (np.zeros(3), np.array([0.0, 0.0, 1.0]))


def _pose(xyz, tilt_deg: float = 0.0) -> np.ndarray:
    out = trimesh.transformations.rotation_matrix(np.radians(tilt_deg), [1.0, 0.0, 0.0])
    out[:3, 3] = xyz
    return out


def test_a_box_lying_flat_rests_and_is_set_down_from_above():
    box = trimesh.creation.box((0.10, 0.06, 0.04))
    r = rest_on_plane(box, _pose([0.02, -0.01, 0.040]), *TABLE)  # bottom 20 mm up
    # set down by 20 mm less the gap; then it only drops the 0.5 mm gap
    assert abs(r.lift_m - (SET_DOWN_GAP_M - 0.020)) < 1e-9
    assert r.moved_m < 1.0e-3 and r.turned_deg < 0.5
    assert abs(r.com_drop_m) < 1.0e-4  # the gap and the contact margin do not count
    assert RestRule(moved_m=0.010, turned_deg=15.0).rests(Rest(r.moved_m, r.turned_deg))


def test_a_flat_box_tilted_on_its_edge_falls_back_onto_its_face():
    """A 10 x 10 x 2 cm slab tilted 30 deg about x stands on one bottom edge with its
    centre of mass 3.8 cm inside that edge: it falls flat, turning by the tilt, 30 deg, and
    its centre of mass goes down from 5 sin 30 + 1 cos 30 = 3.366 cm over the edge to 1 cm
    over the face."""
    slab = trimesh.creation.box((0.10, 0.10, 0.02))
    r = rest_on_plane(slab, _pose([0.0, 0.0, 0.05], tilt_deg=30.0), *TABLE)
    assert abs(r.turned_deg - 30.0) < 2.0
    drop = 0.05 * np.sin(np.radians(30.0)) + 0.01 * np.cos(np.radians(30.0)) - 0.01
    assert abs(r.com_drop_m - drop) < 5.0e-4
    assert not RestRule(moved_m=0.010, turned_deg=15.0).rests(Rest(r.moved_m, r.turned_deg))


def test_rest_rule_swaps_a_rolling_prior_only_for_a_resting_completion_as_good_in_view():
    prior_view = ViewScore(iou=0.86, ucd_mm=1.9, free_space=0.000)
    rolls, rests = Rest(moved_m=0.030, turned_deg=41.0), Rest(moved_m=0.0005, turned_deg=0.0)
    close = ViewScore(iou=0.845, ucd_mm=2.3, free_space=0.015)  # 0.015 worse IoU, +0.4 mm
    assert choose(prior_view, close, rest=(rolls, rests))[0] == "completion"
    assert "does not rest" in choose(prior_view, close, rest=(rolls, rests))[1]
    assert choose(prior_view, close)[0] == "prior"  # no rest test: the view margins only
    assert choose(prior_view, close, rest=(rests, rests))[0] == "prior"
    assert choose(prior_view, close, rest=(rolls, rolls))[0] == "prior"
    worse = [ViewScore(0.83, 2.3, 0.015), ViewScore(0.845, 2.5, 0.015),
             ViewScore(0.845, 2.3, 0.025)]  # IoU -0.03, UCD +0.6 mm, free space +0.025
    for completion in worse:
        assert choose(prior_view, completion, rest=(rolls, rests))[0] == "prior"
    turned_only = Rest(moved_m=0.004, turned_deg=26.0)
    assert not RestRule().rests(turned_only)
    assert choose(prior_view, close, rest=(turned_only, rests))[0] == "completion"


def test_a_prior_that_rolls_level_still_counts_as_not_resting():
    """A ball rolls on a level table without its centre of mass going down: a neutral rest
    on a real table, but the twin must stay put in the simulator, so the rule replaces it
    like a prior that tips into a lower rest (docs/realistic.md, "Rolling level"). The
    reason given says how far it went down."""
    prior_view = ViewScore(iou=0.86, ucd_mm=1.9, free_space=0.000)
    close = ViewScore(iou=0.845, ucd_mm=2.3, free_space=0.015)
    rests = Rest(moved_m=0.0005, turned_deg=0.0, com_drop_m=0.0)
    level = Rest(moved_m=0.060, turned_deg=90.0, com_drop_m=0.0003)
    chosen, reason = choose(prior_view, close, rest=(level, rests))
    assert chosen == "completion"
    assert "moved 60 mm, turned 90 deg and went down 0.3 mm" in reason
    assert Rest(0.06, 90.0, 0.0003).as_dict() == {"moved_mm": 60.0, "turned_deg": 90.0,
                                                 "com_drop_mm": 0.3}
    assert "com_drop_mm" not in Rest(0.06, 90.0).as_dict()  # not measured: left out
    for rest in (level, Rest(0.06, 90.0)):
        back = Rest.from_dict(rest.as_dict())
        assert back.as_dict() == rest.as_dict() and (back.com_drop_m is None) == (
            rest.com_drop_m is None)


def test_an_object_alone_on_the_table_and_one_on_a_plate():
    box = trimesh.creation.box((0.06, 0.06, 0.06))
    on_table = box.copy().apply_translation([0.0, 0.0, 0.030])
    neighbour = box.copy().apply_translation([0.10, 0.0, 0.030])  # beside it, not under
    assert stands_alone_on_table(on_table, [neighbour], *TABLE)
    sunk = box.copy().apply_translation([0.0, 0.0, 0.022])  # 8 mm into the table
    assert stands_alone_on_table(sunk, [], *TABLE)
    lifted = box.copy().apply_translation([0.0, 0.0, 0.045])  # 15 mm above it
    assert not stands_alone_on_table(lifted, [], *TABLE)
    plate = trimesh.creation.cylinder(radius=0.12, height=0.006)
    plate.apply_translation([0.02, 0.0, 0.003])  # 6 mm thick, under the box
    on_plate = box.copy().apply_translation([0.0, 0.0, 0.036])
    assert not stands_alone_on_table(on_plate, [plate], *TABLE)


def test_a_flat_shape_is_refused_with_a_value_error():
    flat = trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0]],
                           [[0, 1, 2], [1, 3, 2]], process=False)
    try:
        rest_on_plane(flat, np.eye(4), *TABLE)
    except ValueError as exc:
        assert "hull" in str(exc) or "volume" in str(exc)
    else:
        raise AssertionError("a flat shape was rolled out")
