"""The speed-ups that must not change results: physopt's check memo, the OBJ text memos
of the PyBullet worlds, and export's reuse of physopt's convex pieces (same triangles)."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from r2s.forked_map import THREADS_VARIABLE
from r2s.io.mesh_io import same_triangles, save_mesh, welded
from r2s.io.state import SceneState, SupportPlane
from r2s.physopt import pybullet_world
from r2s.physopt.params import ObjectParams, inner_box
from r2s.physopt.repair import check, world_factory
from r2s.physopt.settings import RepairSettings
from r2s.sim import pybullet_bodies
from r2s.sim.export_scene import ObjectItem, _collision_geometry


def _shuffled(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    """The same triangles with vertices and faces permuted and each face's corners rotated."""
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(mesh.vertices))
    new_index = np.empty_like(perm)
    new_index[perm] = np.arange(len(perm))
    faces = new_index[np.asarray(mesh.faces)][rng.permutation(len(mesh.faces))]
    faces = np.stack([np.roll(f, int(rng.integers(3))) for f in faces])
    return trimesh.Trimesh(np.asarray(mesh.vertices)[perm], faces, process=False)


def test_same_triangles_ignores_order_but_not_geometry_or_winding():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    other = _shuffled(mesh, 0)
    assert not np.array_equal(other.vertices, mesh.vertices)
    assert same_triangles(mesh, other) and same_triangles(other, mesh)
    flipped = trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)
    assert not same_triangles(mesh, flipped)
    moved = mesh.copy()
    moved.vertices[5] += [1e-9, 0.0, 0.0]
    assert not same_triangles(mesh, moved)
    assert not same_triangles(mesh, trimesh.creation.icosphere(subdivisions=1))


def test_export_decomposes_the_collision_mesh_only_when_its_triangles_are_the_same():
    sphere = trimesh.creation.icosphere(subdivisions=2)  # float32-exact, as GLB stores it
    mesh = trimesh.Trimesh(np.float32(sphere.vertices).astype(np.float64), sphere.faces,
                           process=False)
    with tempfile.TemporaryDirectory() as tmp:
        same, changed = Path(tmp) / "same.glb", Path(tmp) / "changed.glb"
        save_mesh(_shuffled(mesh, 1), same)
        save_mesh(trimesh.creation.icosphere(subdivisions=2, radius=1.01), changed)
        geom = welded(mesh)

        def item(path):
            return ObjectItem(id=1, label="x", mesh_path=Path(tmp) / "unused.glb",
                              pose=np.eye(4), mass_kg=None, com=None, friction=None,
                              collision_mesh_path=path)

        used = _collision_geometry(item(same), geom)
        assert used is not geom and same_triangles(used, geom)
        assert not np.array_equal(used.vertices, geom.vertices)  # its own vertex order
        assert _collision_geometry(item(changed), geom) is geom
        assert _collision_geometry(item(None), geom) is geom
        assert _collision_geometry(item(Path(tmp) / "missing.glb"), geom) is geom


def _pieces() -> list[trimesh.Trimesh]:
    """Three convex pieces of a 12 cm x 4 cm x 4 cm bar (fewer than 16: one shape array)."""
    return [trimesh.creation.box([0.04] * 3, transform=trimesh.transformations.
                                 translation_matrix([x, 0, 0])) for x in (-0.04, 0.0, 0.04)]


def test_piece_obj_text_is_trimeshs_export():
    piece = trimesh.convex.convex_hull(np.random.default_rng(2).normal(size=(40, 3)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.obj"
        piece.export(path)
        assert pybullet_world.obj_file_bytes(piece) == path.read_bytes()
        assert pybullet_world.obj_file_bytes(piece) == path.read_bytes()  # remembered


def test_multi_part_text_remembered_is_the_text_computed():
    pieces = [trimesh.creation.box([0.01] * 3, transform=trimesh.transformations.
                                   translation_matrix([0.01 * k, 0, 0])) for k in range(20)]
    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for k, p in enumerate(pieces):
            files.append(str(Path(tmp) / f"{k}.obj"))
            p.export(files[-1])
        pybullet_bodies._MULTI_PART_TEXT.clear()
        first = pybullet_bodies._multi_part_text(files)
        assert len(pybullet_bodies._MULTI_PART_TEXT) == 1
        assert pybullet_bodies._multi_part_text(files) is first
        pybullet_bodies._MULTI_PART_TEXT.clear()
        assert pybullet_bodies._multi_part_text(files) == first
        assert first.count("\no piece_") + first.startswith("o piece_") == 20
        assert first.count("\nv ") == 20 * 8


@pytest.fixture
def bar_scene():
    """A bar resting on the table and one 2 cm above it (it falls: drift about 2 cm)."""
    bar = _pieces()
    lo, hi = inner_box(trimesh.util.concatenate(bar).bounds)
    params = {}
    for i, z in ((1, 0.02), (2, 0.02 + 0.02)):
        pose = np.eye(4)
        pose[:3, 3] = [0.3 * i, 0.0, z]
        params[i] = ObjectParams(world_from_object=pose, mass_kg=0.2, nominal_mass_kg=0.2,
                                 com_in_object=np.zeros(3), friction=0.6, com_lo=lo, com_hi=hi)
    state = SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[])
    return {1: bar, 2: bar}, state, params


def test_check_memo_returns_the_fresh_worlds_result(bar_scene, monkeypatch):
    monkeypatch.setenv(THREADS_VARIABLE, "1")  # every world built in this process, counted
    pieces, state, params = bar_scene
    settings, order = RepairSettings(), [1, 2]
    orders = [order, order[::-1]]
    built = []
    make_world = world_factory(pieces, state, order, settings)

    def counting(p, body_order=None):
        built.append(body_order)
        return make_world(p, body_order)

    counting.checked = make_world.checked
    first = check(counting, params, orders, 1.0)
    assert len(built) == 2
    assert first[2][0] == pytest.approx(0.02, abs=0.002)  # it fell 2 cm
    assert first[1][0] < 1e-3
    again = check(counting, params, orders, 1.0)
    assert again == first and len(built) == 2  # remembered: no world built
    # without the memo (a plain function), fresh worlds give exactly the same numbers
    assert check(lambda p, o=None: make_world(p, o), params, orders, 1.0) == first
    # any change of what a world is made of is a new check
    pose = np.array(params[2].world_from_object)
    pose[0, 3] += 1e-9
    for changed in ({**params, 2: params[2].with_pose(pose)},
                    {**params, 2: replace(params[2], friction=0.9)},
                    {**params, 2: replace(params[2], com_in_object=np.array([1e-9, 0, 0]))},
                    {**params, 2: replace(params[2], movable=False)}):
        before = len(built)
        check(counting, changed, orders, 1.0)
        assert len(built) == before + 2
    check(counting, params, orders, 2.0)
    assert len(built) == 2 + 4 * 2 + 2


def test_settle_memo_returns_the_fresh_worlds_result(bar_scene):
    from r2s.physopt.repair import settle_round

    pieces, state, params = bar_scene
    settings, order = RepairSettings(), [1, 2]
    built = []
    make_world = world_factory(pieces, state, order, settings)

    def counting(p, body_order=None):
        built.append(body_order)
        return make_world(p, body_order)

    counting.checked, counting.order = make_world.checked, make_world.order
    log = {"objects": {1: [], 2: []}, "rounds": []}
    first = settle_round(counting, params, order, 1, settings, log)
    assert len(built) == 1
    # the raised bar settled onto the table (2 cm down), the other stayed
    assert first[2].world_from_object[2, 3] == pytest.approx(0.02, abs=0.002)
    assert first[1].world_from_object[2, 3] == pytest.approx(0.02, abs=0.001)
    again = settle_round(counting, params, order, 1, settings, log)
    assert len(built) == 1
    fresh = settle_round(lambda p, o=None: make_world(p, o), params, order, 1, settings, log)
    for i in order:
        assert np.array_equal(again[i].world_from_object, first[i].world_from_object)
        assert np.array_equal(fresh[i].world_from_object, first[i].world_from_object)
