"""Collision pieces trimmed against the neighbours (r2s/geometry/collision_trim.py), and
export using the pieces physopt checked (r2s/io/pieces_file.py).

Known answer: a U-shaped block (a 60 x 20 x 10 mm base and two 10 x 20 x 30 mm uprights,
volume 24 cm^3, hull 48 cm^3) with a 20 x 10 x 20 mm box in the notch, 2 mm above the base
and 10 mm from each upright. The U's convex hull (the worst single piece) holds the box
10 mm deep (analytic: the hull's y faces are 10 mm from the box's middle plane)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from r2s.geometry.collision_trim import (capped_hull, inside_depth_m, surface_points,
                                         trim_pieces, trim_scene_pieces)
from r2s.geometry.convex_params import ConvexParams
from r2s.io.mesh_io import save_mesh
from r2s.io.pieces_file import read_pieces, write_pieces
from r2s.physopt.piece_overlap import CUT_CLEARANCE_M
from r2s.sim.export_scene import BodyParams, ObjectItem, build_and_write

TRANSLATE = trimesh.transformations.translation_matrix


def u_block() -> trimesh.Trimesh:
    parts = [trimesh.creation.box((0.06, 0.02, 0.01), TRANSLATE((0, 0, 0.005)))]
    parts += [trimesh.creation.box((0.01, 0.02, 0.03), TRANSLATE((x, 0, 0.025)))
              for x in (-0.025, 0.025)]
    return trimesh.boolean.union(parts, engine="manifold")


def notch_box() -> trimesh.Trimesh:
    return trimesh.creation.box((0.02, 0.01, 0.02), TRANSLATE((0, 0, 0.022)))


def _deepest_mm(pieces: list[trimesh.Trimesh], points: np.ndarray) -> float:
    return 1000 * max(max(float(inside_depth_m(p, points).max()), 0.0) for p in pieces)


def test_hull_of_the_u_is_trimmed_out_of_the_notch_and_still_covers_the_u():
    u = u_block()
    assert u.volume == pytest.approx(24e-6, rel=1e-6)
    box_points = surface_points(notch_box(), 8000, seed=3)
    hull = u.convex_hull
    assert _deepest_mm([hull], box_points) == pytest.approx(10.0, abs=0.1)
    pieces, report = trim_pieces([hull], u, box_points)
    # no piece reaches into the box by more than 1 mm (the trimming tolerance)
    assert _deepest_mm(pieces, box_points) <= 1.0
    assert report.depth_before_m == pytest.approx(0.010, abs=1e-4)
    assert report.depth_after_m <= 1e-3 and report.pieces_after == len(pieces) >= 3
    # every surface sample of the U lies in a piece or within 0.2 mm of one
    check = surface_points(u, 20_000, seed=11)
    depth = np.max([inside_depth_m(p, check) for p in pieces], axis=0)
    assert depth.min() >= -0.2e-3
    # and the pieces stay inside the U's hull and well below it in volume
    assert all(p.is_convex and p.is_watertight for p in pieces)
    assert min(float(inside_depth_m(hull, p.vertices).min()) for p in pieces) >= -1e-9
    assert sum(p.volume for p in pieces) < 0.7 * hull.volume
    # deterministic
    again, _ = trim_pieces([hull], u, box_points)
    assert [np.array_equal(p.vertices, q.vertices) for p, q in zip(pieces, again)] == \
        [True] * len(pieces) and len(again) == len(pieces)


def test_capped_hull_keeps_a_sphere_within_3_mm():
    """A rebuilt piece has at most 64 vertices (as V-HACD's): of the hull of 5000 samples
    of a 5 cm sphere, the 64 kept leave no sample more than 3 mm outside (measured 2.8 mm;
    an evenly spread 64-vertex polytope leaves about 1.6 mm) and 0.9 of the volume."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    points = surface_points(sphere, 5000, seed=1)
    hull = capped_hull(points, 64)
    assert len(hull.vertices) == 64
    assert -float(inside_depth_m(hull, points, 0.01).min()) <= 3e-3
    assert hull.volume >= 0.9 * sphere.volume
    assert capped_hull(points[:3]) is None  # degenerate


def test_pieces_no_neighbour_reaches_into_are_kept_as_given():
    u = u_block()
    far = surface_points(notch_box().apply_translation((0, 0.1, 0)), 2000, seed=3)
    pieces = [u.convex_hull]
    out, report = trim_pieces(pieces, u, far)
    assert out[0] is pieces[0] and len(out) == 1
    assert report.depth_before_m == report.depth_after_m == 0.0


def test_points_inside_the_mesh_itself_are_not_trimmed_against():
    """A neighbour that interpenetrates the visual mesh (a box sunk 5 mm into the U's base)
    cannot be trimmed away without uncovering the U: its pieces are left alone."""
    u = u_block()
    sunk = trimesh.creation.box((0.02, 0.01, 0.01), TRANSLATE((0, 0, 0.005 + 0.005)))
    inside_only = surface_points(sunk, 4000, seed=5)
    inside_only = inside_only[inside_only[:, 2] < 0.0095]  # only what lies in the base
    pieces = [u.convex_hull]
    out, report = trim_pieces(pieces, u, inside_only)
    assert out[0] is pieces[0] and report.pieces_after == 1


def test_trim_scene_pieces_uses_each_objects_pose():
    """The same U and box placed in the world: the U (rotated 90 deg about z and moved)
    gets its hull trimmed, the box (its own hull, untouched by the U's surface) does not."""
    u, box = u_block(), trimesh.creation.box((0.02, 0.01, 0.02))
    turn = trimesh.transformations.rotation_matrix(np.pi / 2, (0, 0, 1))
    poses = {1: TRANSLATE((0.3, -0.1, 0.0)) @ turn,
             2: TRANSLATE((0.3, -0.1, 0.0)) @ turn @ TRANSLATE((0, 0, 0.022))}
    out, reports = trim_scene_pieces({1: [u.convex_hull], 2: [box.convex_hull]},
                                     {1: u, 2: box}, poses)
    assert reports[1].depth_before_m == pytest.approx(0.010, abs=2e-4)
    assert reports[1].depth_after_m <= 1e-3 and len(out[1]) >= 3
    assert reports[2].pieces_after == 1 and reports[2].depth_before_m == 0.0
    kept, only_box = trim_scene_pieces({1: [u.convex_hull], 2: [box.convex_hull]},
                                       {1: u, 2: box}, poses, only={2})
    assert 1 not in only_box and len(kept[1]) == 1 and kept[1][0].volume == u.convex_hull.volume


def test_physopt_writes_the_pieces_it_checked(tmp_path):
    """physopt/collision/<id>.npz holds each object's pieces under the export's parameters
    (two cubes, the upper resting on the lower: one piece each, the lower cube's volume, and
    the upper one's less the slab physopt cuts under it, r2s/physopt/piece_overlap.py: two
    touching hulls read 2 mm in Bullet, over its 1.5 mm tolerance)."""
    from r2s.io.manifest import StageRecord, load_manifest, save_manifest
    from r2s.io.state import ObjectState, SceneState, SupportPlane, write_state
    from r2s.runner.base import run_stage
    from r2s.stages.physopt import STAGE as PHYSOPT, Options

    root = tmp_path / "scene"
    (root / "init" / "meshes").mkdir(parents=True)
    objects = []
    for oid, edge, z in ((1, 0.1, 0.05), (2, 0.06, 0.13)):
        save_mesh(trimesh.creation.box([edge] * 3), root / "init" / "meshes" / f"{oid}.glb")
        objects.append(ObjectState(id=oid, label="box", mesh=f"meshes/{oid}.glb",
                                   world_from_object=TRANSLATE((0, 0, z)).tolist()))
    write_state(root / "init", SceneState(stage="init", support=SupportPlane(
        point=[0, 0, 0], normal=[0, 0, 1]), objects=objects))
    manifest = load_manifest(root / "manifest.json")
    manifest.stages["init"] = StageRecord(status="done")
    save_manifest(root / "manifest.json", manifest)
    run_stage(PHYSOPT, root, Options(use_diffsim=False))
    for oid, edge, height in ((1, 0.1, 0.1), (2, 0.06, 0.06 - CUT_CLEARANCE_M)):
        pieces = read_pieces(root / "physopt" / "collision" / f"{oid}.npz",
                             BodyParams().convex.as_kwargs())
        assert len(pieces) == 1
        assert pieces[0].volume == pytest.approx(edge * edge * height, rel=1e-6)


def _item(mesh_path: Path, pieces_path: Path | None, collision_mesh: Path | None = None):
    return ObjectItem(id=1, label="u", mesh_path=mesh_path, pose=np.eye(4), mass_kg=0.1,
                      com=None, friction=0.5, collision_mesh_path=collision_mesh,
                      collision_pieces_path=pieces_path)


def test_export_uses_the_pieces_physopt_wrote_only_for_the_same_parameters(tmp_path):
    u = u_block()
    mesh_path = tmp_path / "u.glb"
    save_mesh(u, mesh_path)
    written = [trimesh.creation.box((0.06, 0.02, 0.01), TRANSLATE((0, 0, 0.005))),
               trimesh.creation.box((0.01, 0.02, 0.04), TRANSLATE((0.025, 0, 0.02)))]
    params = BodyParams()
    pieces_path = tmp_path / "collision" / "1.npz"
    write_pieces(pieces_path, written, params.convex.as_kwargs())
    loaded = read_pieces(pieces_path, params.convex.as_kwargs())
    assert [np.allclose(a.vertices, b.vertices) for a, b in zip(loaded, written)] == [True, True]
    assert read_pieces(pieces_path, ConvexParams(max_pieces=8).as_kwargs()) is None
    assert read_pieces(tmp_path / "missing.npz", params.convex.as_kwargs()) is None

    bodies = build_and_write(tmp_path / "export", [0, 0, -9.81], {"point": [0, 0, 0],
                             "normal": [0, 0, 1]}, [_item(mesh_path, pieces_path)], params, None)
    assert len(bodies[0].collision_pieces) == 2
    assert sum(p.volume for p in bodies[0].collision_pieces) == pytest.approx(
        sum(p.volume for p in written), rel=1e-9)
    # other decomposition parameters: export decomposes the mesh itself
    other = BodyParams(max_convex_pieces=32)
    bodies = build_and_write(tmp_path / "export2", [0, 0, -9.81], {"point": [0, 0, 0],
                             "normal": [0, 0, 1]}, [_item(mesh_path, pieces_path)], other, None)
    assert sum(p.volume for p in bodies[0].collision_pieces) != pytest.approx(
        sum(p.volume for p in written), rel=1e-3)
    # a collision mesh with other triangles than the exported one: its pieces are not used
    changed = tmp_path / "changed.glb"
    save_mesh(notch_box(), changed)
    bodies = build_and_write(tmp_path / "export3", [0, 0, -9.81], {"point": [0, 0, 0],
                             "normal": [0, 0, 1]}, [_item(mesh_path, pieces_path, changed)],
                             params, None)
    assert sum(p.volume for p in bodies[0].collision_pieces) != pytest.approx(
        sum(p.volume for p in written), rel=1e-3)
