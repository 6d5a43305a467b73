"""Contact graph: support parents by H on hand-built stacks, proximity edges, the stage."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from r2s.graph.build import GraphParams, PosedObject, build_contact_graph
from r2s.graph.polygon import contains, convex_hull_2d, convex_overlap, distance_to_polygon
from r2s.runner.base import run_stage
from r2s.stages.graph import STAGE, read_contact_graph
from tests.helpers_state import box, rot_x, rot_y, write_init_state


def graph_of(objs, gravity=(0, 0, -9.81), plane_point=(0, 0, 0), plane_normal=(0, 0, 1),
             params=GraphParams()):
    posed = []
    for o in objs:
        mesh = o.mesh.copy().apply_transform(o.world_from_object)
        posed.append(PosedObject(o.id, o.label, mesh, np.asarray(mesh.center_mass)))
    return build_contact_graph(posed, np.asarray(gravity, float), np.asarray(plane_point, float),
                               np.asarray(plane_normal, float), params)


def tree_edge(graph, child):
    (edge,) = [e for e in graph.support_edges if e.child == child and e.in_tree]
    return edge


# ---- polygon helpers ---------------------------------------------------------------
def test_polygon_distance_and_overlap_on_unit_square():
    square = convex_hull_2d(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]]))
    assert len(square) == 4
    pts = np.array([[0.5, 0.5], [2.0, 0.5], [2.0, 2.0], [1.0, 1.0]])
    np.testing.assert_allclose(distance_to_polygon(square, pts), [0, 1, np.sqrt(2), 0], atol=1e-12)
    assert contains(square, pts).tolist() == [True, False, False, True]
    shifted = square + [1.5, 0]
    assert not convex_overlap(square, shifted)
    assert convex_overlap(square, shifted, tol=0.6)
    assert convex_overlap(square, square + [0.9, 0.9])


# ---- support relations -------------------------------------------------------------
def test_box_on_box_parent_is_lower_box():
    objs = [box(1, (0.10, 0.10, 0.05), (0, 0, 0.025)),
            box(2, (0.06, 0.06, 0.04), (0.01, 0, 0.07))]
    g = graph_of(objs)
    assert g.parent_of(1) == 0 and g.parent_of(2) == 1
    e = tree_edge(g, 2)
    assert e.gap_m == pytest.approx(0.0, abs=1e-6)
    assert e.plane_height_m == pytest.approx(0.05, abs=1e-6)
    assert e.likelihood == pytest.approx(1.0, abs=1e-6)
    assert tree_edge(g, 1).likelihood == pytest.approx(1.0, abs=1e-6)
    # the upper box is shadowed by the lower one: the table cannot touch it
    assert all(e.parent != 0 for e in g.support_edges if e.child == 2)
    assert g.order == [0, 1, 2]
    assert g.node(2).depth == 2


def test_plate_on_two_blocks_records_both_blocks():
    objs = [box(1, (0.04, 0.06, 0.05), (-0.08, 0, 0.025)),
            box(2, (0.04, 0.06, 0.05), (0.08, 0, 0.025)),
            box(3, (0.25, 0.08, 0.01), (0, 0, 0.055), label="plate")]
    g = graph_of(objs)
    supporters = {e.parent: e for e in g.supporters_of(3)}
    assert set(supporters) == {1, 2}
    assert g.parent_of(3) in (1, 2)
    # symmetric scene: both blocks are equally likely; the COM lies between them
    h1, h2 = supporters[1].likelihood, supporters[2].likelihood
    assert h1 == pytest.approx(h2, abs=1e-6)
    # COM at x=0, block edge at x=0.06; plate footprint radius = |(0.125, 0.04)|
    expected_d_com = 0.06 / np.hypot(0.125, 0.04)
    assert supporters[1].d_com == pytest.approx(expected_d_com, rel=1e-3)
    assert h1 == pytest.approx(1.0 - expected_d_com, rel=1e-3)
    assert g.order.index(3) > max(g.order.index(1), g.order.index(2))


def leaning_scene(theta_deg: float = 20.0):
    """Board 2 stands on the table, its left face resting on block 1's top-right edge."""
    th = np.radians(theta_deg)
    cz = 0.01 * np.sin(th) + 0.06 * np.cos(th)          # lowest corner on the table
    z = (0.10 - cz + 0.01 * np.sin(th)) / np.cos(th)     # face coordinate of the contact
    cx = 0.03 + 0.01 * np.cos(th) + z * np.sin(th)
    return [box(1, (0.06, 0.06, 0.10), (0, 0, 0.05)),
            box(2, (0.02, 0.06, 0.12), (cx, 0, cz), rotation=rot_y(-th), label="board")]


def test_leaning_box_parent_is_table_block_is_extra_supporter():
    g = graph_of(leaning_scene())
    # The table carries the board's weight at its bottom edge (gap 0, d_com 0, H = 1); the
    # block only pushes sideways, so it is recorded as an extra supporter, not the parent.
    assert g.parent_of(2) == 0
    assert tree_edge(g, 2).likelihood == pytest.approx(1.0, abs=1e-3)
    extra = [e for e in g.supporters_of(2) if not e.in_tree]
    assert [e.parent for e in extra] == [1]
    assert abs(extra[0].gap_m) < 2e-3
    assert 0.25 <= extra[0].likelihood < 1.0
    assert (1, 2) in {(p.a, p.b) for p in g.proximity_edges}
    assert g.order.index(1) < g.order.index(2)


def test_box_floating_2cm_above_box_keeps_that_box_as_parent():
    objs = [box(1, (0.10, 0.10, 0.05), (0, 0, 0.025)),
            box(2, (0.05, 0.05, 0.04), (0, 0, 0.05 + 0.02 + 0.02))]
    g = graph_of(objs)
    e = tree_edge(g, 2)
    assert e.parent == 1
    assert e.gap_m == pytest.approx(0.02, abs=1e-6)
    assert e.likelihood == pytest.approx(1 - 0.02 / 0.05, abs=1e-6)
    # too far to be a touching support: no other supporter recorded
    assert len(g.supporters_of(2)) == 1


def test_proximity_edges_for_touching_side_by_side_boxes():
    objs = [box(1, (0.05, 0.05, 0.05), (0, 0, 0.025)),
            box(2, (0.05, 0.05, 0.05), (0.05, 0, 0.025)),       # touching 1
            box(3, (0.05, 0.05, 0.05), (0.05 + 0.05 + 0.003, 0, 0.025)),  # 3 mm from 2
            box(4, (0.05, 0.05, 0.05), (0.30, 0, 0.025))]       # far away
    g = graph_of(objs)
    pairs = {(p.a, p.b) for p in g.proximity_edges}
    assert pairs == {(1, 2), (2, 3)}
    assert all(g.parent_of(i) == 0 for i in (1, 2, 3, 4))
    assert not any(p.support for p in g.proximity_edges)
    g_tight = graph_of(objs, params=GraphParams(proximity_margin_m=0.001))
    assert {(p.a, p.b) for p in g_tight.proximity_edges} == {(1, 2)}


def test_graph_is_invariant_to_a_rigid_motion_of_the_whole_scene():
    objs = [box(1, (0.04, 0.06, 0.05), (-0.08, 0, 0.025)),
            box(2, (0.04, 0.06, 0.05), (0.08, 0, 0.025)),
            box(3, (0.25, 0.08, 0.01), (0, 0, 0.055), label="plate"),
            box(4, (0.05, 0.05, 0.05), (0.0, 0.2, 0.025))]
    g0 = graph_of(objs)
    rot = rot_x(0.4) @ rot_y(-0.3)
    shift = np.array([0.3, -0.1, 0.7])
    moved = []
    for o in objs:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = rot, shift
        moved.append(type(o)(o.id, o.mesh, T @ o.world_from_object, o.label))
    g1 = graph_of(moved, gravity=rot @ [0, 0, -9.81], plane_point=shift,
                  plane_normal=rot @ [0, 0, 1])
    key = lambda g: sorted((e.child, e.parent, e.in_tree, round(e.likelihood, 4)) for e in g.support_edges)
    assert key(g0) == key(g1)
    # (proximity edges use world-axis-aligned boxes, so they are not rotation invariant)
    assert g0.order == g1.order


# ---- the stage -------------------------------------------------------------------
def test_graph_stage_writes_json_and_png_and_skips_when_current(tmp_path):
    scene = write_init_state(tmp_path / "scene", [
        box(1, (0.10, 0.10, 0.05), (0, 0, 0.025)),
        box(2, (0.06, 0.06, 0.04), (0, 0, 0.07), label="top"),
        box(3, (0.05, 0.05, 0.05), (0.2, 0, 0.025))])
    res = run_stage(STAGE, scene)
    assert res.ran and res.summary["stacked"] == 1 and res.summary["on_table"] == 2
    g = read_contact_graph(scene / "graph" / "contact_graph.json")
    assert g.parent_of(2) == 1 and g.node(2).label == "top"
    assert g.node(0).is_root and g.order[0] == 0
    png = (scene / "graph" / "contact_graph.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    again = run_stage(STAGE, scene, force=False)
    assert not again.ran


def test_graph_stage_without_init_is_a_stage_error(tmp_path):
    from r2s.errors import StageError

    (tmp_path / "scene").mkdir()
    with pytest.raises(StageError):
        run_stage(STAGE, tmp_path / "scene")


def test_open_mesh_and_com_declared_are_accepted():
    # a bowl-like open mesh (no top) on the table: still a node with a footprint
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    bowl = trimesh.Trimesh(sphere.vertices, sphere.faces[sphere.triangles_center[:, 2] < 0.0])
    bowl.apply_translation([0, 0, 0.04])
    g = build_contact_graph([PosedObject(5, "bowl", bowl, np.array([0, 0, 0.02]))],
                            np.array([0, 0, -9.81]), np.zeros(3), np.array([0, 0, 1.0]))
    assert g.parent_of(5) == 0
    assert tree_edge(g, 5).gap_m == pytest.approx(0.0, abs=1e-4)
    assert len(g.node(5).footprint_uv_m) >= 3


@pytest.mark.seed_demo
def test_ycb5_ground_truth_fruit_rests_on_the_plate(tmp_path):
    """The peer scene's true poses: five fruits in the plate, the strawberry beside it."""
    from r2s.io.mesh_io import load_mesh
    from r2s.io.scene_json import read_gt_scene
    from tests.conftest import SEED_DEMO
    from tests.helpers_state import StateObj

    if not (SEED_DEMO / "gt" / "scene.json").is_file():
        pytest.skip("../shared/seed_demo/ycb5 not present")
    gt = read_gt_scene(SEED_DEMO / "gt" / "scene.json")
    objs = [StateObj(o.id, load_mesh(SEED_DEMO / "gt" / o.mesh), np.asarray(o.world_from_object),
                     label=o.label) for o in gt.objects]
    g = graph_of(objs, gravity=gt.gravity, plane_point=gt.support.point,
                 plane_normal=gt.support.normal)
    labels = {o.id: o.label for o in objs}
    plate = next(i for i, lab in labels.items() if "plate" in lab)
    strawberry = next(i for i, lab in labels.items() if "strawberry" in lab)
    assert g.parent_of(plate) == 0 and g.parent_of(strawberry) == 0
    for i in labels:
        if i not in (plate, strawberry):
            assert g.parent_of(i) == plate, labels[i]
            assert abs(tree_edge(g, i).gap_m) < 5e-3
    assert g.order.index(plate) < min(g.order.index(i) for i in labels
                                      if i not in (plate, strawberry))
