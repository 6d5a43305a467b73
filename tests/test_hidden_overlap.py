"""Hidden overlap between whole shapes, given to one of them
(r2s/geometry/hidden_overlap.py): the shapes stop overlapping, the owner and every part of
the yielding shape the camera saw stay where they were, and a shape sunk through a thin
support comes back up onto its top."""

from __future__ import annotations

import numpy as np
import trimesh

from r2s.geometry.hidden_overlap import (CLEARANCE_M, MIN_DEPTH_M, SHAPE_ERROR_M,
                                         lift_onto_plane, yield_hidden_overlaps)
from r2s.geometry.sdf import occupancy, raycasting_scene


def _sphere(centre, radius: float) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=4, radius=radius).apply_translation(centre)


def _cap(mesh: trimesh.Trimesh, towards: np.ndarray, min_cos: float) -> np.ndarray:
    """The vertices of ``mesh`` on the side facing ``towards`` (a unit direction): what a
    camera there sees of it."""
    c = np.asarray(mesh.vertices).mean(axis=0)
    d = np.asarray(mesh.vertices) - c
    cos = d @ towards / np.linalg.norm(d, axis=1)
    return np.asarray(mesh.vertices)[cos > min_cos]


def _depth_inside(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """(N,) how far each point is inside ``mesh`` (0 outside), by ray parity and the
    distance to its surface."""
    inside = occupancy(raycasting_scene(mesh.vertices, mesh.faces), points)
    dist = np.abs(trimesh.proximity.signed_distance(mesh, points))
    return np.where(inside, dist, 0.0)


def test_two_overlapping_balls_stop_overlapping_and_keep_what_was_seen():
    """Two 40 mm balls 70 mm apart overlap by 10 mm behind what a camera above sees (their
    upper caps). The overlap goes to one; afterwards no vertex of either lies more than
    the clearance inside the other, the owner is unchanged, and the yielding ball's seen
    cap is unchanged."""
    a = _sphere([0.0, 0.0, 0.04], 0.04)
    b = _sphere([0.07, 0.0, 0.04], 0.04)
    up = np.array([0.0, 0.0, 1.0])
    # ball a was seen over more of its surface, so its points reach nearer the overlap
    pts = {1: _cap(a, up, -0.2), 2: _cap(b, up, 0.5)}
    assert _depth_inside(b, a.vertices).max() > 0.009  # the overlap is there
    new, report, _ = yield_hidden_overlaps({1: a, 2: b}, pts)
    assert set(new) == {2} and report[2].yielded_to == (1,)
    assert abs(report[2].deepest_m - 0.01) < 1e-3
    b2 = trimesh.Trimesh(new[2], b.faces, process=False)
    assert _depth_inside(b2, a.vertices).max() < MIN_DEPTH_M
    assert _depth_inside(a, new[2]).max() < MIN_DEPTH_M
    # nor do the yielded faces cut across the owner between their vertices
    samples, _ = trimesh.sample.sample_surface(b2, 20000, seed=0)
    assert _depth_inside(a, samples).max() < MIN_DEPTH_M
    moved = np.linalg.norm(new[2] - b.vertices, axis=1) > 1e-9
    seen = np.isin(np.arange(len(b.vertices)),
                   np.flatnonzero(np.asarray(b.vertices) @ up > 0.04 + 0.02))
    assert not np.any(moved & seen)
    # the moved surface lies on the owner's, just outside it
    gap = trimesh.proximity.signed_distance(a, new[2][moved])
    assert np.all(np.abs(gap + CLEARANCE_M) < 1e-3)


def test_the_decision_does_not_depend_on_the_ids():
    """The same two balls with their ids swapped: the same ball yields the same way."""
    a = _sphere([0.0, 0.0, 0.04], 0.04)
    b = _sphere([0.07, 0.0, 0.04], 0.04)
    up = np.array([0.0, 0.0, 1.0])
    one, _, _ = yield_hidden_overlaps({1: a, 2: b}, {1: _cap(a, up, -0.2), 2: _cap(b, up, 0.5)})
    two, _, _ = yield_hidden_overlaps({5: b, 3: a}, {5: _cap(b, up, 0.5), 3: _cap(a, up, -0.2)})
    assert set(two) == {5}
    np.testing.assert_allclose(two[5], one[2], atol=1e-9)


def test_a_ball_sunk_into_a_thin_plate_comes_back_onto_its_top():
    """A 30 mm ball whose bottom reaches 2.5 mm into a plate 3 mm thick: for its lowest
    vertices the closest surface is the plate's underside, but the ball yields along the
    way to its own centre, onto the plate's top. The camera above sees the plate's top
    around the ball (beyond its 30 mm silhouette), nearer the overlap than the ball's own
    upper half, so the plate owns it."""
    plate = trimesh.creation.box([0.2, 0.2, 0.003]).apply_translation([0, 0, 0.0015])
    ball = _sphere([0.0, 0.0, 0.0005 + 0.03], 0.03)
    g = np.linspace(-0.09, 0.09, 37)
    top = np.array([[x, y, 0.003] for x in g for y in g if np.hypot(x, y) > 0.03])
    up = np.array([0.0, 0.0, 1.0])
    new, report, _ = yield_hidden_overlaps({1: plate, 2: ball}, {1: top, 2: _cap(ball, up, 0.0)},
                                           min_overlap_m=0.0)  # 2.5 mm: under the gate
    assert set(new) == {2} and report[2].yielded_to == (1,)
    low = new[2][:, 2].min()
    assert 0.003 - MIN_DEPTH_M <= low <= 0.003 + CLEARANCE_M + 1e-6  # the top, not the underside
    assert _depth_inside(plate, new[2]).max() < MIN_DEPTH_M
    # the closest-point rule would have put them on the underside (z = 0)
    assert ball.vertices[:, 2].min() < 0.0015


def test_shapes_that_agree_within_the_gate_keep_their_shape():
    """The two balls 3 mm into each other (less than ``SHAPE_ERROR_M``): taken as exact
    shapes with a pose error, nothing yields; the deepest overlap is reported."""
    a = _sphere([0.0, 0.0, 0.04], 0.04)
    b = _sphere([0.077, 0.0, 0.04], 0.04)
    up = np.array([0.0, 0.0, 1.0])
    new, report, overlap_m = yield_hidden_overlaps({1: a, 2: b},
                                                   {1: _cap(a, up, -0.2), 2: _cap(b, up, 0.5)})
    assert new == {} and report == {}
    assert abs(overlap_m - 0.003) < 5e-4 and overlap_m < SHAPE_ERROR_M


def test_what_reaches_below_the_table_is_lifted_onto_it():
    """A 40 mm cube on a table tilted 5.7 deg, its centre 17 mm above it: its four lowest
    vertices (0.9-4.9 mm below) come up onto the plane (plus the clearance) along its
    normal; the others do not move."""
    n = np.array([0.0, np.sin(0.1), np.cos(0.1)])
    cube = trimesh.creation.box([0.04] * 3)
    v = np.asarray(cube.vertices) + 0.017 * n
    lifted, count = lift_onto_plane(v, np.zeros(3), n)
    h_before, h_after = v @ n, lifted @ n
    assert count == 4
    np.testing.assert_allclose(h_after[h_before < 0], CLEARANCE_M, atol=1e-12)
    np.testing.assert_allclose(lifted[h_before > 0], v[h_before > 0])
    # moved straight along the normal
    d = lifted - v
    np.testing.assert_allclose(np.cross(d[h_before < 0], n), 0.0, atol=1e-12)


def test_a_prior_far_into_the_table_is_left_for_geomopt():
    """A 40 mm cube 8 mm into the table was registered too low (a pose error, beyond
    ``MAX_LIFT_M``): nothing is moved."""
    cube = trimesh.creation.box([0.04] * 3)
    v = np.asarray(cube.vertices) + [0.0, 0.0, 0.012]
    lifted, count = lift_onto_plane(v, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert count == 0
    np.testing.assert_array_equal(lifted, v)


def _two_ball_scene(root):
    """Two 30 mm balls 2 mm apart on the table, side by side across the camera's view, each
    given a prior 15 % too long towards the other: registered to what the camera sees (no scale
    estimate), the priors overlap behind the balls."""
    from helpers_init import SynthObject, pose, write_input_scene

    ball = _sphere([0.0, 0.0, 0.0], 0.03)
    big = _sphere([0.0, 0.0, 0.0], 0.03).apply_scale([1.15, 1.0, 1.0])
    objs = [SynthObject(i, ball, pose([x, 0.0, 0.03]), c, f"ball{i}", prior=big,
                        world_from_prior=pose([x, 0.0, 0.03]))
            for i, x, c in ((1, -0.031, (200, 60, 60)), (2, 0.031, (60, 60, 200)))]
    return write_input_scene(root, objs, width=200, height=150)


def _init_overlap_m(scene, **options) -> tuple[float, dict]:
    """Run init; the deepest vertex of either ball inside the other (m) and the state's
    hidden_overlap records."""
    from r2s.io.mesh_io import load_mesh
    from r2s.io.paths import ScenePaths
    from r2s.io.state import read_state
    from r2s.runner.base import run_stage
    from r2s.stages.init import STAGE, Options

    run_stage(STAGE, scene, Options(estimate_scale=False, prior_choice="prior", **options),
              force=True)
    out = ScenePaths(scene).stage_dir("init")
    state = read_state(out)
    posed = {o.id: load_mesh(out / o.mesh).apply_transform(o.pose) for o in state.objects}
    deepest = max(_depth_inside(posed[b], np.asarray(posed[a].vertices)).max()
                  for a, b in ((1, 2), (2, 1)))
    records = {o.id: getattr(o, "hidden_overlap", None) for o in state.objects}
    return deepest, records


def test_init_gives_the_hidden_overlap_of_two_priors_to_one(tmp_path):
    """Through the init stage: without the option the registered priors overlap by
    millimetres behind the balls; with it (the default) one ball's prior yields, its
    state says so, and nothing overlaps by more than ``MIN_DEPTH_M``."""
    scene = _two_ball_scene(tmp_path / "scene")
    before, records = _init_overlap_m(scene, prior_yield_hidden_overlap=False,
                                      prior_lift_below_table=False)
    assert before > 0.002 and records == {1: None, 2: None}
    after, records = _init_overlap_m(scene)
    assert after < MIN_DEPTH_M
    # a record may also count vertices lifted from below the table (the default
    # prior_lift_below_table; one vertex of a ball's prior, depending on the numerics of
    # its registration): only the prior that yields has "yielded_to"
    yielded = [i for i, r in records.items() if r is not None and "yielded_to" in r]
    assert len(yielded) == 1
    r = records[yielded[0]]
    assert r["yielded_to"] == [3 - yielded[0]] and r["moved_vertices"] > 0
    assert abs(r["deepest_mm"] / 1000 - before) < 1e-3
