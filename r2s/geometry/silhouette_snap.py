"""Move a completed shape's outline, in the table's plane, onto its mask's outline.

A shape completed on a grid (2 mm cells, about 2 px at 0.6 m) has a silhouette that is
right to about a cell: a completion renders a band of 1-2 px beyond its mask along much
of its outline and falls short of it elsewhere (docs/completion.md, "The outline"). Along
an outline of a few hundred pixels that band costs 5-10 % of an object's silhouette IoU.

Here the vertices that form the outer silhouette (on a contour generator: their faces
turn both towards and away from the camera; and projected within ``CONTOUR_PX`` of the
rendered silhouette's edge) are moved so that their projections land on the mask's
sub-pixel outline (the zero of a signed distance built from the mask's pixel centres).
The move is horizontal, in the support plane, so heights (read from depth) and the
contact with the table are kept; it is spread over nearby vertices (Gaussian, ``sigma_m``)
so the surface stays smooth. It is refused where the outline is not the object's own:

- where the mask's edge meets another instance (an occluder in front, or a neighbour that
  the mask bleeds onto): the object may go on behind it;
- within ``border_px`` of the image's border: the object may go on outside the image;
- outwards onto a pixel whose depth reading lies more than ``seen_past_m`` behind the
  vertex: the camera saw past it there (the carving rule, geometry/carving.py);
- into another object (``others``), or to within ``KEEP_OUT_M`` of it from farther out,
  whether a vertex of this mesh would enter it or a face would pass one of its vertices:
  overlaps would make geomopt and physopt push the objects apart, away from where they
  were seen;
- where the shape rests on another object (within ``CONTACT_M`` above it at the start):
  its base there carries it, which the snap must not change.

Each move is at most ``max_shift_px`` per iteration.

Frames: world points in metres; pixels ``(u = column, v = row)`` as geometry/camera.py;
``up`` is the support plane's unit normal in the world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

from r2s.geometry.camera import camera_center, project
from r2s.geometry.plane import world_from_plane
from r2s.geometry.raycast import raycast_view
from r2s.geometry.sdf import raycasting_scene, signed_distances

CONTOUR_PX = 1.0
"""A contour-generator vertex projected within this distance (pixels) of the rendered
silhouette's edge forms the outer silhouette."""

RING_PX = 3
"""How far outside the mask its neighbourhood is looked at to tell background from
another instance (pixels)."""

KEEP_OUT_M = 5e-4
"""A vertex may not move to within this distance of another object's surface (metres),
unless it was already closer: the snap never makes objects overlap, which geomopt and
physopt would then push apart, moving them away from where they were seen."""

CONTACT_M = 3e-3
"""A vertex with another object within this distance below it (metres, along ``up``) at
the start does not move: that is where the object rests on the other, and moving it would
change what carries it (a shape lying across two others loses part of its base)."""


@dataclass(frozen=True)
class SnapReport:
    """What :func:`snap_outline` did.

    vertices_moved : vertices given a move (contour vertices that passed every test).
    mean_shift_px : mean |image shift| asked of them, pixels.
    refused_other : contour vertices left where the mask meets another instance.
    refused_seen_past : outward moves refused because the camera saw past the vertex.
    refused_overlap : vertex moves undone because they went into another object (or within
        ``KEEP_OUT_M`` of it) from farther out.
    pinned : vertices held where the shape rests on another object (``CONTACT_M``).
    """

    vertices_moved: int
    mean_shift_px: float
    refused_other: int
    refused_seen_past: int
    refused_overlap: int = 0
    pinned: int = 0


def mask_signed_distance_px(mask: np.ndarray) -> np.ndarray:
    """(H, W) float signed distance (pixels) to the mask's outline, positive outside.

    The outline lies halfway between a mask pixel's centre and the nearest centre outside
    it, so a pixel is covered by a silhouette whose edge is at 0 exactly when it is in the
    mask."""
    mask = np.asarray(mask, dtype=bool)
    outside = ndimage.distance_transform_edt(~mask)
    inside = ndimage.distance_transform_edt(mask)
    return np.where(mask, -(inside - 0.5), outside - 0.5)


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of an (H, W) or (H, W, C) image at (N, 2) ``(u, v)``, clamped to
    the image."""
    at = [uv[:, 1], uv[:, 0]]
    if image.ndim == 2:
        return ndimage.map_coordinates(image, at, order=1, mode="nearest")
    return np.stack([ndimage.map_coordinates(image[..., c], at, order=1, mode="nearest")
                     for c in range(image.shape[2])], axis=1)


def contour_generator_vertices(mesh: trimesh.Trimesh, eye: np.ndarray) -> np.ndarray:
    """(V,) bool: vertices with faces turned both towards and away from ``eye`` (3,)."""
    faces = np.asarray(mesh.faces)
    centres = np.asarray(mesh.triangles_center)
    towards = np.einsum("ij,ij->i", np.asarray(mesh.face_normals), eye - centres) > 0
    n = len(mesh.vertices)
    seen_front = np.zeros(n, bool)
    seen_back = np.zeros(n, bool)
    for k in range(3):
        seen_front[faces[towards, k]] = True
        seen_back[faces[~towards, k]] = True
    return seen_front & seen_back


def _projection_jacobian(points: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray
                         ) -> np.ndarray:
    """(N, 2, 3) d(u, v) / d(world point) of the pinhole projection."""
    camera_from_world = np.linalg.inv(np.asarray(world_from_camera, dtype=np.float64))
    rot = camera_from_world[:3, :3]
    pc = points @ rot.T + camera_from_world[:3, 3]
    x, y, z = pc[:, 0], pc[:, 1], pc[:, 2]
    fx, fy = float(K[0, 0]), float(K[1, 1])
    jc = np.zeros((len(points), 2, 3))
    jc[:, 0, 0] = fx / z
    jc[:, 0, 2] = -fx * x / z ** 2
    jc[:, 1, 1] = fy / z
    jc[:, 1, 2] = -fy * y / z ** 2
    return jc @ rot


@dataclass(frozen=True)
class _Outline:
    """The image side of the snap, in a window of the image (its own K).

    phi : (h, w) signed distance to the mask's outline, px; grad : (h, w, 2) its gradient
    as (d/du, d/dv); own_edge : (h, w) bool, True where the nearest pixel of the ring
    around the mask is background; depth_m : (h, w); K : (3, 3) of the window;
    u_range, v_range : the pixels (window coordinates) away from the image's border.
    """

    phi: np.ndarray
    grad: np.ndarray
    own_edge: np.ndarray
    depth_m: np.ndarray
    K: np.ndarray
    u_range: tuple[float, float]
    v_range: tuple[float, float]


def _outline(mask: np.ndarray, labels: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
             window: tuple[int, int, int, int], border_px: int) -> _Outline:
    full_h, full_w = mask.shape
    r0, r1, c0, c1 = window
    mask = mask[r0:r1, c0:c1]
    h, w = mask.shape
    k = np.asarray(K, dtype=np.float64).copy()
    k[0, 2] -= c0
    k[1, 2] -= r0
    phi = mask_signed_distance_px(mask)
    ring = ndimage.binary_dilation(mask, iterations=RING_PX) & ~mask
    ring_is_background = ring & (np.asarray(labels)[r0:r1, c0:c1] == 0)
    _, (ring_r, ring_c) = ndimage.distance_transform_edt(~ring, return_indices=True)
    return _Outline(phi=phi, grad=np.stack(np.gradient(phi)[::-1], axis=-1),
                    own_edge=ring_is_background[ring_r, ring_c],
                    depth_m=np.asarray(depth_m, dtype=np.float64)[r0:r1, c0:c1], K=k,
                    u_range=(max(border_px - c0, 0), min(full_w - 1 - border_px - c0, w - 1)),
                    v_range=(max(border_px - r0, 0), min(full_h - 1 - border_px - r0, h - 1)))


def snap_outline(mesh_world: trimesh.Trimesh, mask: np.ndarray, labels: np.ndarray,
                 depth_m: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
                 up: np.ndarray, max_shift_px: float = 2.0, iterations: int = 3,
                 sigma_m: float = 0.0015, seen_past_m: float = 0.015, border_px: int = 2,
                 others: Sequence[trimesh.Trimesh] = ()
                 ) -> tuple[trimesh.Trimesh, SnapReport]:
    """The mesh with its outer silhouette moved onto the mask's outline.

    Parameters
    ----------
    mesh_world : the completed shape, world frame, metres.
    mask : (H, W) bool, the object's instance mask.
    labels : (H, W) int instance ids of the image, 0 = background.
    depth_m : (H, W) depth image, metres along the camera z axis; NaN / <= 0 = no reading.
    K : (3, 3) intrinsics; world_from_camera : (4, 4) OpenCV camera to world.
    up : (3,) the support plane's normal, world frame; every move is normal to it.
    max_shift_px, iterations, sigma_m, seen_past_m, border_px : see the module docstring.
    others : the other objects' closed meshes, world frame: no vertex moves into one, nor
        to within ``KEEP_OUT_M`` of it from farther out, and the vertices that start within
        ``CONTACT_M`` above one do not move.

    Returns
    -------
    The moved mesh (a new ``trimesh.Trimesh``, same faces) and a :class:`SnapReport`.
    """
    mask = np.asarray(mask, dtype=bool)
    verts = np.asarray(mesh_world.vertices, dtype=np.float64).copy()
    faces = np.asarray(mesh_world.faces)
    window = _window(mask, verts, K, world_from_camera, RING_PX + 2 * max_shift_px + 4)
    if window is None:
        return trimesh.Trimesh(verts, faces, process=False), SnapReport(0, 0.0, 0, 0)
    image = _outline(mask, labels, depth_m, K, window, border_px)
    basis = world_from_plane(np.zeros(3), up)[:3, :2]  # (3, 2) across ``up``
    blocker = _union_scene(others)
    other_points = (np.concatenate([np.asarray(m.vertices, dtype=np.float64) for m in others])
                    if len(others) else np.zeros((0, 3)))
    pinned = (signed_distances(blocker, verts - CONTACT_M * np.asarray(up, float)) < 0.0
              if blocker is not None else np.zeros(len(verts), dtype=bool))
    moved: set[int] = set()
    shifts: list[float] = []
    refused = np.zeros(3, dtype=np.int64)
    for _ in range(iterations):
        step = _one_pass(trimesh.Trimesh(verts, faces, process=False), image,
                         world_from_camera, max_shift_px, seen_past_m)
        if step is None:
            break
        cand, shift, g, step_refused = step
        refused[:2] += step_refused
        if len(cand) == 0:
            break
        move = _horizontal_moves(verts[cand], g * shift[:, None], image.K, world_from_camera,
                                 basis)
        delta = _spread(verts, verts[cand], move, sigma_m)
        delta[pinned] = 0.0
        if blocker is not None:
            delta, undone = _kept_out(blocker, verts, delta)
            refused[2] += undone
            delta, undone = _kept_clear(verts, faces, delta, other_points, 3.0 * sigma_m)
            refused[2] += undone
        verts += delta
        moved.update(int(i) for i in cand if not pinned[i])
        shifts.extend(np.abs(shift).tolist())
    report = SnapReport(vertices_moved=len(moved),
                        mean_shift_px=float(np.mean(shifts)) if shifts else 0.0,
                        refused_other=int(refused[0]), refused_seen_past=int(refused[1]),
                        refused_overlap=int(refused[2]), pinned=int(pinned.sum()))
    return trimesh.Trimesh(verts, faces, process=False), report


def _one_pass(mesh: trimesh.Trimesh, image: _Outline, world_from_camera: np.ndarray,
              max_shift_px: float, seen_past_m: float):
    """The outer silhouette's vertices and the shift each is given this pass: (ids (N,),
    shift px (N,) along the outline's outward normal, that normal (N, 2), refused counts
    (2,): [other instance, seen past]); None when nothing is rendered or on the outline."""
    h, w = image.phi.shape
    rendered, _, _ = raycast_view([mesh], image.K, world_from_camera, w, h)
    silhouette = np.isfinite(rendered)
    edge = silhouette & ~ndimage.binary_erosion(silhouette)
    if not edge.any():
        return None
    to_edge = ndimage.distance_transform_edt(~edge)
    uv, z = project(np.asarray(mesh.vertices), image.K, world_from_camera)
    (u_lo, u_hi), (v_lo, v_hi) = image.u_range, image.v_range
    ok = (np.all(np.isfinite(uv), axis=1) & (z > 0) & (uv[:, 0] >= u_lo) & (uv[:, 0] <= u_hi)
          & (uv[:, 1] >= v_lo) & (uv[:, 1] <= v_hi))
    ok &= contour_generator_vertices(mesh, camera_center(world_from_camera))
    cand = np.nonzero(ok)[0]
    cand = cand[_bilinear(to_edge, uv[cand]) <= CONTOUR_PX]
    if len(cand) == 0:
        return None
    p = uv[cand]
    d = _bilinear(image.phi, p)
    g = _bilinear(image.grad, p)
    g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
    shift = np.clip(-d, -max_shift_px, max_shift_px)  # outwards > 0
    # the outline there must be the object's own: the ring beyond it is background
    beyond = _pixel(p + g * (np.maximum(d + shift, 0.0) + 1.0)[:, None], h, w)
    own = image.own_edge[beyond]
    # outwards, the camera must not have seen past the new surface
    reading = image.depth_m[_pixel(p + g * shift[:, None], h, w)]
    past = (shift > 0) & np.isfinite(reading) & (reading > 0) & (reading > z[cand] + seen_past_m)
    keep = own & ~past & (np.abs(shift) > 0.05)
    refused = np.array([int((~own).sum()), int((own & past).sum())])
    return cand[keep], shift[keep], g[keep], refused


def _pixel(uv: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the pixels nearest (N, 2) ``(u, v)``, clipped to an h x w image."""
    return (np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, h - 1),
            np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, w - 1))


def _horizontal_moves(points: np.ndarray, want_px: np.ndarray, K: np.ndarray,
                      world_from_camera: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(N, 3) moves in the plane spanned by ``basis`` (3, 2) that shift the projections of
    (N, 3) ``points`` by ``want_px`` (N, 2), to first order; at most three times as long as
    a move across the ray would be (a ray seen grazing the plane asks for long moves)."""
    jac = _projection_jacobian(points, K, world_from_camera) @ basis  # (N, 2, 2)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    good = np.abs(det) > 1e-6 * np.max(np.abs(jac).reshape(len(jac), -1), axis=1) ** 2
    coef = np.zeros((len(points), 2))
    coef[good] = np.linalg.solve(jac[good], want_px[good][:, :, None])[:, :, 0]
    move = coef @ basis.T
    _, z = project(points, K, world_from_camera)
    across = np.linalg.norm(want_px, axis=1) * z / float(K[0, 0])
    size = np.linalg.norm(move, axis=1)
    return move * np.minimum(1.0, 3.0 * across / np.maximum(size, 1e-12))[:, None]


def _union_scene(meshes: Sequence[trimesh.Trimesh]):
    """An Open3D raycasting scene of all ``meshes`` (world frame), or None for none."""
    meshes = [m for m in meshes if len(m.faces)]
    if not meshes:
        return None
    union = trimesh.util.concatenate(meshes)
    return raycasting_scene(np.asarray(union.vertices), np.asarray(union.faces))


def _kept_out(blocker, verts: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, int]:
    """``delta`` (V, 3) with the moves undone that take a vertex into another object, or
    to within ``KEEP_OUT_M`` of its surface, from farther out; and how many were undone."""
    idx = np.nonzero(np.linalg.norm(delta, axis=1) > 1e-9)[0]
    if len(idx) == 0:
        return delta, 0
    before = signed_distances(blocker, verts[idx])
    after = signed_distances(blocker, verts[idx] + delta[idx])
    bad = idx[(after < KEEP_OUT_M) & (after < before)]
    delta = delta.copy()
    delta[bad] = 0.0
    return delta, len(bad)


def _kept_clear(verts: np.ndarray, faces: np.ndarray, delta: np.ndarray,
                other_points: np.ndarray, radius_m: float) -> tuple[np.ndarray, int]:
    """``delta`` (V, 3) with the moves undone, within ``radius_m`` of it, wherever a point
    of another object (M, 3) would come inside the moved mesh or within ``KEEP_OUT_M`` of
    its surface from farther out (a face moved past another object's vertices while this
    mesh's own vertices stay outside it); and how many moves were undone."""
    moving = np.nonzero(np.linalg.norm(delta, axis=1) > 1e-9)[0]
    if len(moving) == 0 or len(other_points) == 0:
        return delta, 0
    near = cKDTree(verts[moving]).query(other_points, distance_upper_bound=radius_m)[0]
    pts = other_points[np.isfinite(near)]
    if len(pts) == 0:
        return delta, 0
    before = signed_distances(raycasting_scene(verts, faces), pts)
    after = signed_distances(raycasting_scene(verts + delta, faces), pts)
    hit = pts[(after < KEEP_OUT_M) & (after < before)]
    if len(hit) == 0:
        return delta, 0
    undo = moving[np.isfinite(cKDTree(hit).query(verts[moving],
                                                 distance_upper_bound=radius_m)[0])]
    delta = delta.copy()
    delta[undo] = 0.0
    return delta, len(undo)


def _window(mask: np.ndarray, verts: np.ndarray, K: np.ndarray, world_from_camera: np.ndarray,
            margin_px: float) -> tuple[int, int, int, int] | None:
    """(row0, row1, col0, col1) of the image window holding the mask and the mesh's
    projection, ``margin_px`` wider, clipped to the image; None when neither is seen."""
    h, w = mask.shape
    rows, cols = np.nonzero(mask)
    uv, z = project(verts, K, world_from_camera)
    seen = np.all(np.isfinite(uv), axis=1) & (z > 0)
    us = np.concatenate([cols.astype(float), uv[seen, 0]])
    vs = np.concatenate([rows.astype(float), uv[seen, 1]])
    if len(us) == 0:
        return None
    r0 = int(np.clip(np.floor(vs.min() - margin_px), 0, h - 1))
    r1 = int(np.clip(np.ceil(vs.max() + margin_px) + 1, r0 + 1, h))
    c0 = int(np.clip(np.floor(us.min() - margin_px), 0, w - 1))
    c1 = int(np.clip(np.ceil(us.max() + margin_px) + 1, c0 + 1, w))
    if r1 - r0 < 3 or c1 - c0 < 3:
        return None
    return r0, r1, c0, c1


def _spread(verts: np.ndarray, sources: np.ndarray, moves: np.ndarray, sigma_m: float
            ) -> np.ndarray:
    """(V, 3) the sources' moves spread over every vertex: a Gaussian-weighted mean of the
    moves within 3 sigma, scaled down where the weights sum to less than 1 (far from
    every source)."""
    pairs = cKDTree(sources).sparse_distance_matrix(cKDTree(verts), 3.0 * sigma_m,
                                                    output_type="ndarray")
    src, dst, dist = pairs["i"], pairs["j"], pairs["v"]
    wgt = np.exp(-0.5 * (dist / sigma_m) ** 2)
    total = np.bincount(dst, weights=wgt, minlength=len(verts))
    out = np.stack([np.bincount(dst, weights=wgt * moves[src, k], minlength=len(verts))
                    for k in range(3)], axis=1)
    return out / np.maximum(total, 1.0)[:, None]
