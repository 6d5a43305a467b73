"""Signed distance volumes of meshes: a dense grid in the object frame, negative inside.

:func:`compute_sdf` samples a mesh's signed distance on a cubic grid that covers the mesh's
bounding box plus a padding. Distances are exact (closest point on the triangles, by
Open3D's ``RaycastingScene``) in a band of a few voxels around the surface. Further out a
voxel takes the distance to the closest surface point of the nearest band voxel (a
closest-point transform over a Euclidean distance transform), within half a voxel or so
of the truth and a fraction of the cost: far-field closest-point queries would otherwise
dominate the run time (measured here: 10 s instead of 2 s at 128^3).

Signs: the band separates the far voxels into connected components that the surface never
crosses, so each component has one sign, voted by seven of its voxels. Votes and band
voxels use ray parity (Open3D's occupancy, three rays) for a watertight mesh. A mesh that
is not watertight (a scan with a hole, a missing bottom) uses the generalised winding
number (inside above 1/2) for the votes and the closest triangle's normal in the band;
where a hole joins the inside to the outer component, a voxel there is inside when it is
behind its closest face and a coarse winding-number grid says so. This needs consistently
oriented faces: a mesh whose faces point every which way has no meaningful inside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage

SIGN_CONVENTION = "negative_inside"
REFINE_VOXELS = 12.0
"""Far voxels up to this many voxels from the surface get the neighbour refinement."""
FRAME = "object"


@dataclass(frozen=True)
class SdfGrid:
    """A signed distance function sampled on a cubic grid.

    Attributes
    ----------
    values_m : (R, R, R) float32, signed distance at voxel centres, indexed [i, j, k] =
        [x, y, z]; negative inside the mesh.
    origin_m : (3,) float64, object-frame position of voxel [0, 0, 0]'s centre.
    voxel_size_m : spacing between voxel centres.
    frame : the frame of the grid (always "object": the mesh's own frame).
    sign : sign convention (always "negative_inside").
    """

    values_m: np.ndarray
    origin_m: np.ndarray
    voxel_size_m: float
    frame: str = FRAME
    sign: str = SIGN_CONVENTION

    def __post_init__(self) -> None:
        values = np.ascontiguousarray(self.values_m, dtype=np.float32)
        if values.ndim != 3 or len(set(values.shape)) != 1:
            raise ValueError(f"values_m must be (R, R, R), got {values.shape}")
        origin = np.asarray(self.origin_m, dtype=np.float64).reshape(3)
        if not self.voxel_size_m > 0:
            raise ValueError("voxel_size_m must be positive")
        object.__setattr__(self, "values_m", values)
        object.__setattr__(self, "origin_m", origin)
        object.__setattr__(self, "voxel_size_m", float(self.voxel_size_m))

    @property
    def resolution(self) -> int:
        return int(self.values_m.shape[0])

    @property
    def max_corner_m(self) -> np.ndarray:
        """(3,) centre of the last voxel [R-1, R-1, R-1]."""
        return self.origin_m + (self.resolution - 1) * self.voxel_size_m

    def voxel_centres_m(self) -> np.ndarray:
        """(R, R, R, 3) object-frame voxel centres."""
        return grid_points(self.origin_m, self.voxel_size_m, self.resolution)

    def sample(self, points_m: np.ndarray) -> np.ndarray:
        """Trilinear signed distance at (N, 3) object-frame points; (N,) float64.

        Outside the grid: the value at the closest grid point plus the distance to it.
        """
        return trilinear_sample(self.values_m, self.origin_m, self.voxel_size_m, points_m)


def grid_points(origin_m: np.ndarray, voxel_size_m: float, resolution: int) -> np.ndarray:
    """(R, R, R, 3) voxel centres of a cubic grid."""
    axis = np.arange(resolution, dtype=np.float64) * voxel_size_m
    gx, gy, gz = np.meshgrid(axis + origin_m[0], axis + origin_m[1], axis + origin_m[2],
                             indexing="ij")
    return np.stack([gx, gy, gz], axis=-1)


def grid_layout(bounds_m: np.ndarray, resolution: int, padding_m: float) -> tuple[np.ndarray, float]:
    """Origin and voxel size of a cubic grid covering ``bounds_m`` (2, 3) plus ``padding_m``.

    The cube is centred on the box; its side is the largest extent plus twice the padding.
    """
    if resolution < 4:
        raise ValueError("resolution must be at least 4")
    bounds_m = np.asarray(bounds_m, dtype=np.float64)
    centre = bounds_m.mean(axis=0)
    side = float(np.max(bounds_m[1] - bounds_m[0])) + 2.0 * padding_m
    voxel = side / (resolution - 1)
    return centre - 0.5 * side, voxel


def trilinear_sample(values: np.ndarray, origin_m: np.ndarray, voxel_size_m: float,
                     points_m: np.ndarray) -> np.ndarray:
    """Numpy twin of :func:`r2s.geometry.sdf_torch.sdf_lookup` (no gradients)."""
    points_m = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    r = values.shape[0]
    u = (points_m - origin_m) / voxel_size_m
    uc = np.clip(u, 0.0, r - 1)
    i0 = np.clip(np.floor(uc).astype(np.int64), 0, r - 2)
    t = uc - i0
    out = np.zeros(len(points_m))
    for dx in (0, 1):
        wx = t[:, 0] if dx else 1.0 - t[:, 0]
        for dy in (0, 1):
            wy = t[:, 1] if dy else 1.0 - t[:, 1]
            for dz in (0, 1):
                wz = t[:, 2] if dz else 1.0 - t[:, 2]
                out += wx * wy * wz * values[i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
    outside = np.linalg.norm((u - uc) * voxel_size_m, axis=1)
    return out + outside


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    """An Open3D ``RaycastingScene`` of one triangle mesh ((V, 3) vertices, (F, 3) faces)."""
    import open3d as o3d  # heavy import, only where needed

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)))
    return scene


def closest_surface_points(scene, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For (M, 3) points: the closest point on the scene's triangles (M, 3) and that
    triangle's unit normal (M, 3), as float64."""
    found = scene.compute_closest_points(_o3d_points(points))
    closest = found["points"].numpy().astype(np.float64)
    normal = found["primitive_normals"].numpy().astype(np.float64)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return closest, normal


def first_hit_distance(scene, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(M,) distance along each unit direction (M, 3) from each origin (M, 3) to the first
    triangle of the scene it meets (m; inf for none)."""
    import open3d as o3d

    rays = np.hstack([np.asarray(origins, dtype=np.float32),
                      np.asarray(directions, dtype=np.float32)])
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


def vertical_heights(scene, xy: np.ndarray, start_z: float, from_above: bool = True
                     ) -> np.ndarray:
    """(M,) z of the first triangle of the scene met by vertical rays at ``xy`` (M, 2),
    started at height ``start_z`` and going down (``from_above``: a top) or up (a base);
    NaN where a ray meets none. The scene's frame has z up."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    origins = np.column_stack([xy, np.full(len(xy), float(start_z))])
    direction = np.array([0.0, 0.0, -1.0 if from_above else 1.0])
    t_hit = first_hit_distance(scene, origins, np.tile(direction, (len(xy), 1)))
    z = start_z - t_hit if from_above else start_z + t_hit
    return np.where(np.isfinite(t_hit), z, np.nan)


def signed_distances(scene, points: np.ndarray) -> np.ndarray:
    """(M,) signed distance (m) from (M, 3) points to the scene's triangles, negative
    inside (closed meshes), as float64."""
    return scene.compute_signed_distance(_o3d_points(points)).numpy().astype(np.float64)


def _o3d_points(points: np.ndarray):
    import open3d as o3d

    return o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))


def winding_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                   chunk: int = 1024) -> np.ndarray:
    """Generalised winding number of a triangle soup at (N, 3) points; (N,) float64.

    About 1 inside and 0 outside a closed, outward-oriented mesh; in between near holes.
    Sum of signed solid angles (Van Oosterom & Strackee) over 4 pi. Cost N x F (torch).
    """
    import torch

    tri = torch.as_tensor(np.asarray(vertices, dtype=np.float64)[np.asarray(faces)])
    pts = torch.as_tensor(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    out = torch.empty(len(pts), dtype=torch.float64)
    with torch.no_grad():
        for s in range(0, len(pts), chunk):
            p = pts[s:s + chunk, None, :]
            a, b, c = tri[None, :, 0] - p, tri[None, :, 1] - p, tri[None, :, 2] - p
            la, lb, lc = a.norm(dim=-1), b.norm(dim=-1), c.norm(dim=-1)
            det = (a * torch.linalg.cross(b, c, dim=-1)).sum(-1)
            den = (la * lb * lc + (a * b).sum(-1) * lc + (b * c).sum(-1) * la
                   + (c * a).sum(-1) * lb)
            out[s:s + chunk] = torch.atan2(det, den).sum(dim=1) / (2.0 * np.pi)
    return out.numpy()


def decimated(mesh: trimesh.Trimesh, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of ``mesh`` simplified to at most ``max_faces`` faces (quadric
    decimation; the mesh itself when it has no more)."""
    if len(mesh.faces) <= max_faces:
        return np.asarray(mesh.vertices), np.asarray(mesh.faces)
    import open3d as o3d

    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices)),
                                       o3d.utility.Vector3iVector(np.asarray(mesh.faces)))
    small = legacy.simplify_quadric_decimation(target_number_of_triangles=max_faces)
    faces = np.asarray(small.triangles)
    if len(faces) == 0:
        return np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return np.asarray(small.vertices), faces


def _surface_seed_mask(mesh: trimesh.Trimesh, origin: np.ndarray, voxel: float,
                       resolution: int, seed: int) -> np.ndarray:
    """(R, R, R) bool: voxels whose cell holds a point of the surface (dense samples)."""
    spacing = 0.5 * voxel
    count = int(np.clip(mesh.area / spacing**2, 1000, 2_000_000))
    samples, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    pts = np.concatenate([samples, np.asarray(mesh.vertices)], axis=0)
    idx = np.rint((pts - origin) / voxel).astype(np.int64)
    idx = np.clip(idx, 0, resolution - 1)
    mask = np.zeros((resolution,) * 3, dtype=bool)
    mask[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    return mask


def _component_representatives(labels_far: np.ndarray, per_component: int
                                ) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``per_component`` positions (into ``labels_far``) spread over each label.

    Returns (positions (K,), their component labels (K,)).
    """
    order = np.argsort(labels_far, kind="stable")
    comps, starts, counts = np.unique(labels_far[order], return_index=True, return_counts=True)
    picks = (starts[:, None] + (counts[:, None] * np.arange(per_component)[None]) // per_component)
    return order[picks.reshape(-1)], np.repeat(comps, per_component)


def _component_sign(labels_far: np.ndarray, rep_comp: np.ndarray,
                    rep_inside_score: np.ndarray) -> np.ndarray:
    """Per far voxel: inside when most of its component's representatives are inside
    (score > 1/2: occupancy or winding number)."""
    n = int(labels_far.max()) + 1 if len(labels_far) else 1
    votes = np.bincount(rep_comp, weights=rep_inside_score > 0.5, minlength=n)
    total = np.bincount(rep_comp, minlength=n)
    return (votes / np.maximum(total, 1))[labels_far] > 0.5


def compute_sdf(mesh: trimesh.Trimesh, resolution: int = 128, padding_m: float | None = None,
                band_voxels: float = 3.0, refine_far: bool = True, winding_resolution: int = 16,
                winding_max_faces: int = 600, seed: int = 0) -> SdfGrid:
    """Signed distance grid of ``mesh`` in its own (object) frame.

    Parameters
    ----------
    mesh : triangle mesh, metres, object frame.
    resolution : voxels per axis R (the grid is cubic).
    padding_m : margin around the mesh's bounding box; default 10 % of its largest extent
        plus two voxels' worth, so that contacts a few mm off the surface stay inside.
    band_voxels : half-width, in voxels, of the band of exact closest-point queries.
    refine_far : also try the nearest seeds of the six neighbours of a far voxel up to
        REFINE_VOXELS from the surface (the far-field error drops from about 0.7 to 0.4
        voxel there; deeper voxels keep the single candidate).
    winding_resolution : coarse grid size for the winding number of leaky open meshes.
    winding_max_faces : the mesh is decimated to this many faces for winding numbers.
    seed : seed of the surface samples that locate the band.

    Returns
    -------
    SdfGrid with values_m (R, R, R) float32, negative inside.

    Notes
    -----
    Beyond the band the space splits into connected components that the surface does not
    cross, so each component has one sign: it is decided by a majority of seven voxels
    (ray parity for a watertight mesh, the winding number otherwise). For an open mesh, a
    hole may join the inside to the outer component (the one touching the grid's
    boundary); there each voxel is inside when it lies behind its closest face and the
    coarse winding number exceeds 1/2.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(faces) == 0:
        raise ValueError("mesh has no faces")
    bounds = np.stack([vertices.min(axis=0), vertices.max(axis=0)])
    extent = float(np.max(bounds[1] - bounds[0]))
    if padding_m is None:
        # two voxels of a grid whose side is 1.2 x extent, plus 10 % of the extent
        padding_m = 0.1 * extent + 2.0 * 1.2 * extent / (resolution - 1)
    origin, voxel = grid_layout(bounds, resolution, padding_m)
    shape = (resolution,) * 3

    scene = raycasting_scene(vertices, faces)
    seeds = _surface_seed_mask(mesh, origin, voxel, resolution, seed)
    dist_to_seed, nearest = ndimage.distance_transform_edt(~seeds, return_indices=True)
    band = dist_to_seed <= band_voxels
    nearest_flat = np.ravel_multi_index(tuple(nearest), shape).reshape(-1)
    seed_distance = dist_to_seed.reshape(-1)
    del nearest, dist_to_seed

    # band: exact closest points
    band_idx = np.flatnonzero(band)
    band_pts = origin + voxel * np.stack(np.unravel_index(band_idx, shape), axis=1)
    result = scene.compute_closest_points(_o3d_points(band_pts))
    cp_band = result["points"].numpy().astype(np.float64)
    d_band = np.linalg.norm(band_pts - cp_band, axis=1)
    row = np.full(resolution**3, -1, dtype=np.int64)
    row[band_idx] = np.arange(len(band_idx))

    # far field: distance to the closest point of the nearest seed (seeds lie in the band)
    far_idx = np.flatnonzero(~band)
    far_ijk = np.stack(np.unravel_index(far_idx, shape), axis=1)
    far_pts = (origin + voxel * far_ijk).astype(np.float32)
    cp32 = cp_band.astype(np.float32)
    best_row = row[nearest_flat[far_idx]]
    d_far = np.linalg.norm(far_pts - cp32[best_row], axis=1)
    if refine_far:
        sel = np.flatnonzero(seed_distance[far_idx] <= REFINE_VOXELS)
        pts_sel = far_pts[sel]
        for axis in range(3):
            for step in (-1, 1):
                nb = far_ijk[sel]
                nb[:, axis] = np.clip(nb[:, axis] + step, 0, resolution - 1)
                src = row[nearest_flat[np.ravel_multi_index(nb.T, shape)]]
                d = np.linalg.norm(pts_sel - cp32[src], axis=1)
                better = d < d_far[sel]
                d_far[sel[better]] = d[better]
                best_row[sel[better]] = src[better]
    del far_ijk

    # signs: one per far component (the surface lies inside the band)
    labels, _ = ndimage.label(~band)
    boundary = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                         labels[:, :, [0, -1]].ravel()]))
    labels_far = labels.reshape(-1)[far_idx]
    del labels
    rep_pos, rep_comp = _component_representatives(labels_far, 7)
    rep_pts = far_pts[rep_pos].astype(np.float64)
    if mesh.is_watertight:
        inside_band = occupancy(scene, band_pts)
        rep_score = occupancy(scene, rep_pts).astype(np.float64)
        inside_far = _component_sign(labels_far, rep_comp, rep_score)
    else:
        normals = result["primitive_normals"].numpy().astype(np.float64)
        inside_band = np.einsum("ni,ni->n", band_pts - cp_band, normals) < 0.0
        v, f = decimated(mesh, winding_max_faces)
        inside_far = _component_sign(labels_far, rep_comp, winding_number(v, f, rep_pts))
        # the outer component(s) may reach inside through a hole: there a voxel is inside
        # where it lies behind its closest face and the coarse winding number says so
        outer = np.isin(labels_far, boundary[boundary > 0])
        if np.any(outer):
            pts_o = far_pts[outer].astype(np.float64)
            behind = np.einsum("ni,ni->n", pts_o - cp_band[best_row[outer]],
                               normals[best_row[outer]]) < 0.0
            w = _coarse_winding(v, f, origin, voxel, resolution, winding_resolution, pts_o)
            inside_far[outer] = behind & (w > 0.5)

    values = np.empty(resolution**3, dtype=np.float32)
    values[band_idx] = np.where(inside_band, -d_band, d_band)
    values[far_idx] = np.where(inside_far, -d_far, d_far)
    return SdfGrid(values_m=values.reshape(shape), origin_m=origin, voxel_size_m=voxel)


def occupancy(scene, points: np.ndarray) -> np.ndarray:
    """Ray parity, majority of three rays (one ray may graze an edge and miscount)."""
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    return scene.compute_occupancy(_o3d_points(points), nsamples=3).numpy() > 0.5


def _coarse_winding(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, voxel: float,
                    resolution: int, winding_resolution: int, points: np.ndarray) -> np.ndarray:
    """Winding number on a coarse grid over the SDF's box, interpolated at ``points``."""
    wr = int(max(4, min(winding_resolution, resolution)))
    coarse_voxel = voxel * (resolution - 1) / (wr - 1)
    w = winding_number(vertices, faces, grid_points(origin, coarse_voxel, wr).reshape(-1, 3))
    return trilinear_sample(w.reshape((wr,) * 3), origin, coarse_voxel, points)
