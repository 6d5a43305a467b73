"""physopt's library pieces: the parent map read from the contact graph, the frozen
per-object parameters, the one moving-object test."""

from __future__ import annotations

import json
from dataclasses import FrozenInstanceError
from pathlib import Path

import numpy as np
import pytest
import trimesh

from r2s.io.state import ObjectState, SceneState, SupportPlane
from r2s.physopt.hierarchy import order_root_to_leaves, parents_from_graph
from r2s.physopt.params import (INNER_BOX_MARGIN, drift_in_tolerances, initial_params,
                                inner_box, is_moving, keep_previous, moving_objects)


def _edge(child: int, parent: int, in_tree: bool, likelihood: float) -> dict:
    return {"child": child, "parent": parent, "likelihood": likelihood, "d_gap": 0.0,
            "d_com": 0.0, "gap_m": 0.0, "com_distance_m": 0.0, "plane_height_m": 0.0,
            "in_tree": in_tree}


def _graph(tmp_path: Path, nodes: list[dict], edges: list[dict]) -> Path:
    path = tmp_path / "contact_graph.json"
    path.write_text(json.dumps({"up": [0, 0, 1], "plane_basis": [[1, 0, 0], [0, 1, 0]],
                                "plane_point": [0, 0, 0], "nodes": nodes,
                                "support_edges": edges}))
    return path


def test_tree_edges_give_the_parents(tmp_path: Path):
    """Object 3 rests on 2 (the tree edge) and touches 1 (an extra support listed first);
    the nodes carry no parent, so only the edges' ``in_tree`` flag can tell. Reading a key
    the schema does not have (``is_tree_edge``) took the first edge: 3 -> 1."""
    nodes = [{"id": 0, "label": "table", "is_root": True}, {"id": 1, "label": "a"},
             {"id": 2, "label": "b"}, {"id": 3, "label": "c"}]
    edges = [_edge(1, 0, True, 0.99), _edge(2, 0, True, 0.98),
             _edge(3, 1, False, 0.9), _edge(3, 2, True, 0.7)]
    parents = parents_from_graph(_graph(tmp_path, nodes, edges))
    assert parents == {1: 0, 2: 0, 3: 2}
    assert order_root_to_leaves([3, 2, 1], parents, {1: 0.0, 2: 0.0, 3: 0.1})[-1] == 3


def test_node_parent_agrees_and_missing_graph_is_none(tmp_path: Path):
    nodes = [{"id": 0, "label": "table", "is_root": True}, {"id": 5, "label": "a", "parent": 0}]
    assert parents_from_graph(_graph(tmp_path, nodes, [])) == {5: 0}
    assert parents_from_graph(tmp_path / "absent.json") is None


def _state(com=None, mass=None, friction=None) -> tuple[SceneState, dict, dict]:
    box = trimesh.creation.box([0.1, 0.2, 0.4])
    pose = np.eye(4)
    pose[2, 3] = 0.2
    obj = ObjectState(id=1, label="box", mesh="meshes/1.glb", world_from_object=pose.tolist(),
                      com_in_object=com, mass_kg=mass, friction=friction)
    state = SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[obj])
    return state, {1: box}, {1: [box]}


def test_initial_params_are_the_uniform_body_within_bounds():
    state, meshes, pieces = _state(mass=100.0)
    p = initial_params(state, meshes, pieces, 500.0, (0.5, 2.0), 0.6)[1]
    volume_m3 = 0.1 * 0.2 * 0.4
    assert p.nominal_mass_kg == pytest.approx(500.0 * volume_m3, rel=1e-9)
    assert p.mass_kg == pytest.approx(2.0 * 500.0 * volume_m3, rel=1e-9)  # clipped at 2x
    np.testing.assert_allclose(p.com_in_object, 0.0, atol=1e-12)
    assert p.friction == 0.6 and p.movable
    # the COM box leaves INNER_BOX_MARGIN of each extent on either side: +-0.2 * extent
    np.testing.assert_allclose(p.com_hi, [0.02, 0.04, 0.08], atol=1e-12)
    np.testing.assert_allclose(p.com_lo, [-0.02, -0.04, -0.08], atol=1e-12)
    lo, hi = inner_box(np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 4.0]]))
    np.testing.assert_allclose(lo, INNER_BOX_MARGIN * np.array([1.0, 2.0, 4.0]))
    np.testing.assert_allclose(hi, (1 - INNER_BOX_MARGIN) * np.array([1.0, 2.0, 4.0]))


def test_params_are_frozen_and_keep_previous_holds_the_rest():
    state, meshes, pieces = _state()
    params = initial_params(state, meshes, pieces, 500.0, (0.5, 2.0), 0.6)
    with pytest.raises(FrozenInstanceError):
        params[1].friction = 0.9
    with pytest.raises(ValueError):
        params[1].com_in_object[0] = 1.0  # read-only array
    before, _, _ = _state(com=[0.01, 0.0, 0.0], mass=3.0, friction=0.9)
    kept = keep_previous(params, before, rerun=set())
    assert not kept[1].movable and kept[1].mass_kg == 3.0 and kept[1].friction == 0.9
    np.testing.assert_allclose(kept[1].com_in_object, [0.01, 0.0, 0.0])
    assert params[1].friction == 0.6  # the original is untouched
    fresh = keep_previous(params, before, rerun={1})
    assert fresh[1].movable and fresh[1].friction == 0.6


def test_one_moving_test():
    assert not is_moving((0.005, 2.0), 0.005, 2.0)  # at the tolerance: at rest
    assert is_moving((0.0051, 0.0, ), 0.005, 2.0)
    assert is_moving((0.0, 2.01), 0.005, 2.0)
    assert moving_objects({4: (0.0, 0.0), 2: (0.1, 0.0), 7: (0.0, 9.0)}, 0.005, 2.0) == [2, 7]


def test_drift_in_tolerances_is_the_larger_ratio_and_agrees_with_is_moving():
    assert drift_in_tolerances((0.010, 1.0), 0.005, 2.0) == pytest.approx(2.0, abs=1e-12)
    assert drift_in_tolerances((0.001, 6.0), 0.005, 2.0) == pytest.approx(3.0, abs=1e-12)
    for d in [(0.004, 1.9), (0.006, 0.0), (0.0, 2.5), (0.0049, 2.0)]:
        assert is_moving(d, 0.005, 2.0) == (drift_in_tolerances(d, 0.005, 2.0) > 1.0)
