"""Convex decomposition of a mesh for simulation, deterministic for a given mesh.

A bowl, a plate or a mug must stay concave in simulation: a convex piece that fills a
dish lifts whatever rests in it. Measured on YCB meshes (plate, bowl, mug, can), V-HACD
(PyBullet's built-in copy, voxel resolution 1e5) hugs a dish better and runs several
times faster than CoACD with comparable piece counts (docs/convex_decomposition.md), so it
is the default; CoACD remains selectable. A nearly convex shape is kept as its hull.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from typing import Literal

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

CONVEX_VOLUME_RATIO = 0.9
"""A closed mesh whose volume is at least this fraction of its hull's is treated as convex."""


def closed_convex_hull(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh``'s convex hull as a closed mesh (same frame and units). trimesh's hull of a
    fine marching-cubes mesh (many points on each flat face) can come back not watertight
    (seen on a 2 mm completion of a long box); then the hull is rebuilt from qhull's
    triangles as they are, which close. Flat or degenerate vertices, which enclose no
    volume either way, get trimesh's hull as it is."""
    hull = mesh.convex_hull
    if hull.is_volume:
        return hull
    try:
        qhull = ConvexHull(np.asarray(mesh.vertices, dtype=float))
    except QhullError:
        return hull
    rebuilt = trimesh.Trimesh(qhull.points, qhull.simplices)
    rebuilt.remove_unreferenced_vertices()
    rebuilt.fix_normals()
    return rebuilt


def _clean(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=np.float64),
                           np.asarray(mesh.faces, dtype=np.int64), process=False)
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


@contextlib.contextmanager
def _quiet_c_stdout():
    """Silence output that C code writes straight to file descriptors 1 and 2."""
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        import sys

        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [devnull]:
            os.close(fd)


def _vhacd(mesh: trimesh.Trimesh, resolution: int, max_vertices: int) -> list[trimesh.Trimesh]:
    import pybullet as pb

    with tempfile.TemporaryDirectory(prefix="r2s-vhacd-") as tmp, _quiet_c_stdout():
        src, dst = os.path.join(tmp, "in.obj"), os.path.join(tmp, "out.obj")
        mesh.export(src)
        client = pb.connect(pb.DIRECT)
        try:
            pb.vhacd(src, dst, os.path.join(tmp, "log.txt"), resolution=resolution,
                     concavity=0.0025, maxNumVerticesPerCH=max_vertices,
                     minVolumePerCH=0.0001, physicsClientId=client)
        finally:
            pb.disconnect(client)
        if not os.path.isfile(dst):
            return []
        loaded = trimesh.load(dst, split_object=True, group_material=False, process=False)
    geoms = (list(loaded.geometry.values()) if isinstance(loaded, trimesh.Scene)
             else loaded.split(only_watertight=False))
    return [g.convex_hull for g in geoms if len(g.vertices) >= 4]


def _coacd(mesh: trimesh.Trimesh, threshold: float, max_pieces: int, seed: int,
           max_faces: int = 3000) -> list[trimesh.Trimesh]:
    import coacd

    work = mesh
    if len(mesh.faces) > max_faces:
        import open3d as o3d

        om = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                       o3d.utility.Vector3iVector(mesh.faces))
        om = om.simplify_quadric_decimation(max_faces)
        work = trimesh.Trimesh(np.asarray(om.vertices), np.asarray(om.triangles), process=True)
    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(work.vertices, np.float64), np.asarray(work.faces, np.int64)),
        threshold=threshold, max_convex_hull=max_pieces, seed=seed, preprocess_mode="auto",
        resolution=2000, mcts_nodes=20, mcts_iterations=100, mcts_max_depth=2)
    return [trimesh.Trimesh(np.asarray(v), np.asarray(f), process=True).convex_hull
            for v, f in parts]


def convex_decomposition(mesh: trimesh.Trimesh, threshold: float = 0.05, max_pieces: int = 64,
                         seed: int = 0, method: Literal["vhacd", "coacd"] = "vhacd",
                         resolution: int = 100_000) -> list[trimesh.Trimesh]:
    """Convex pieces (object frame) whose union approximates ``mesh``.

    Parameters
    ----------
    mesh : triangle mesh, metres, object frame.
    threshold : CoACD concavity threshold (method="coacd").
    max_pieces : upper bound on the number of pieces (the smallest extra pieces are merged
        away by keeping the largest ones; V-HACD rarely exceeds it).
    seed : CoACD's random seed.
    method : "vhacd" (default) or "coacd".
    resolution : V-HACD voxel resolution.

    Returns
    -------
    list of convex, watertight ``trimesh.Trimesh``.
    """
    mesh = _clean(mesh)
    hull = closed_convex_hull(mesh)
    if mesh.is_watertight and abs(mesh.volume) >= CONVEX_VOLUME_RATIO * hull.volume:
        return [hull]
    try:
        if method == "coacd":
            pieces = _coacd(mesh, threshold, max_pieces, seed)
        else:
            pieces = _vhacd(mesh, resolution, 64)
    except Exception:
        pieces = []
    pieces = [p for p in pieces if p.volume > 1e-10]
    if len(pieces) > max_pieces:
        pieces = sorted(pieces, key=lambda p: -p.volume)[:max_pieces]
    return pieces or [hull]
