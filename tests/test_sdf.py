"""SDF grids against analytic distances, the torch lookup's gradients, the file round trip."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from r2s.errors import InputError
from r2s.geometry.sdf import SdfGrid, compute_sdf, winding_number
from r2s.geometry.sdf_torch import (pack_grids, plane_sdf, sdf_lookup, sdf_lookup_batched,
                                    sdf_lookup_packed)
from r2s.io.sdf_io import load_sdf, read_sdf_meta, save_sdf

torch.set_num_threads(1)

RADIUS = 0.05
HALF = np.array([0.05, 0.03, 0.015])


def box_sdf(points: np.ndarray, half: np.ndarray = HALF) -> np.ndarray:
    q = np.abs(points) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


@pytest.fixture(scope="module")
def sphere_grid() -> SdfGrid:
    return compute_sdf(trimesh.creation.icosphere(subdivisions=4, radius=RADIUS), resolution=64)


def test_sphere_sdf_matches_analytic_within_a_voxel(sphere_grid):
    g = sphere_grid
    pts = g.voxel_centres_m().reshape(-1, 3)
    analytic = np.linalg.norm(pts, axis=1) - RADIUS
    err = np.abs(g.values_m.reshape(-1) - analytic)
    assert err.max() < g.voxel_size_m
    # near the surface (where contacts happen) the closest-point band is exact; the only
    # error left is the facetting of the icosphere (sagitta ~ 0.03 mm here)
    near = np.abs(analytic) < 2 * g.voxel_size_m
    assert err[near].max() < 0.1e-3
    assert np.all(np.sign(g.values_m.reshape(-1)[np.abs(analytic) > 1e-3])
                  == np.sign(analytic[np.abs(analytic) > 1e-3]))
    assert g.frame == "object" and g.sign == "negative_inside"
    # the grid covers the sphere with padding
    assert np.all(g.origin_m < -RADIUS) and np.all(g.max_corner_m > RADIUS)


def test_box_sdf_matches_analytic_within_a_voxel():
    g = compute_sdf(trimesh.creation.box(extents=2 * HALF), resolution=56)
    pts = g.voxel_centres_m().reshape(-1, 3)
    err = np.abs(g.values_m.reshape(-1) - box_sdf(pts))
    assert err.max() < g.voxel_size_m
    assert err[np.abs(box_sdf(pts)) < 2 * g.voxel_size_m].max() < 1e-6
    # trilinear sampling between voxels stays within a voxel too
    rng = np.random.default_rng(1)
    q = rng.uniform(g.origin_m, g.max_corner_m, size=(3000, 3))
    assert np.abs(g.sample(q) - box_sdf(q)).max() < g.voxel_size_m


def test_translated_mesh_gives_the_same_values_shifted():
    mesh = trimesh.creation.box(extents=2 * HALF)
    g0 = compute_sdf(mesh, resolution=32)
    g1 = compute_sdf(mesh.copy().apply_translation([0.3, -0.2, 0.1]), resolution=32)
    np.testing.assert_allclose(g1.origin_m - g0.origin_m, [0.3, -0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose(g1.values_m, g0.values_m, atol=1e-6)


def test_open_mesh_gets_a_winding_number_sign():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)
    keep = sphere.triangles_center[:, 2] > -0.045  # cut a cap off the bottom: a hole
    open_mesh = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
    assert not open_mesh.is_watertight
    g = compute_sdf(open_mesh, resolution=40)
    pts = g.voxel_centres_m().reshape(-1, 3)
    analytic = np.linalg.norm(pts, axis=1) - RADIUS
    # away from the hole (z > -0.03) the sign is the sphere's
    sure = (np.abs(analytic) > 1.5 * g.voxel_size_m) & (pts[:, 2] > -0.03)
    assert np.all(np.sign(g.values_m.reshape(-1)[sure]) == np.sign(analytic[sure]))
    # winding number itself: 1 inside, 0 far outside, for the closed sphere
    w = winding_number(sphere.vertices, sphere.faces, np.array([[0, 0, 0], [0.2, 0, 0.0]]))
    np.testing.assert_allclose(w, [1.0, 0.0], atol=1e-9)


def test_sdf_round_trip(tmp_path, sphere_grid):
    save_sdf(sphere_grid, tmp_path, 7, extra={"mesh_sha256": "abc"})
    back = load_sdf(tmp_path, 7)
    np.testing.assert_array_equal(back.values_m, sphere_grid.values_m)
    np.testing.assert_array_equal(back.origin_m, sphere_grid.origin_m)
    assert back.voxel_size_m == sphere_grid.voxel_size_m
    meta = read_sdf_meta(tmp_path, 7)
    assert meta["mesh_sha256"] == "abc" and meta["resolution"] == 64
    assert meta["sign"] == "negative_inside" and meta["frame"] == "object"
    (tmp_path / "7.npy").write_bytes(b"junk")
    with pytest.raises(InputError):
        load_sdf(tmp_path, 7)
    with pytest.raises(InputError):
        load_sdf(tmp_path, 8)


# ---- torch lookup ------------------------------------------------------------------
def test_torch_lookup_matches_numpy_and_analytic_box():
    g = compute_sdf(trimesh.creation.box(extents=2 * HALF), resolution=40)
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.12, 0.12, size=(2000, 3))  # partly outside the grid
    values = torch.as_tensor(g.values_m)
    d = sdf_lookup(values, torch.as_tensor(g.origin_m), g.voxel_size_m,
                   torch.as_tensor(q)).numpy()
    np.testing.assert_allclose(d, g.sample(q), atol=1e-7)
    inside = np.all((q >= g.origin_m) & (q <= g.max_corner_m), axis=1)
    assert 0 < inside.sum() < len(q)
    assert np.abs(d - box_sdf(q))[inside].max() < g.voxel_size_m
    # outside the grid: clamped value + distance to the grid, an upper bound of the true
    # distance (triangle inequality), so no false penetration far away
    assert np.all(d[~inside] >= box_sdf(q[~inside]) - g.voxel_size_m)
    assert np.all(d[~inside] > 0)
    # gradient of the lookup points outward, unit length away from edges, outside too
    p = torch.tensor([[0.0, 0.0, 0.10], [0.001, 0.0, -0.008], [0.3, 0.0, 0.0]], dtype=torch.float64,
                     requires_grad=True)
    sdf_lookup(values, torch.as_tensor(g.origin_m), g.voxel_size_m, p).sum().backward()
    np.testing.assert_allclose(p.grad[0].numpy(), [0, 0, 1], atol=0.05)
    np.testing.assert_allclose(p.grad[1].numpy(), [0, 0, -1], atol=0.05)  # inside: to -z face
    np.testing.assert_allclose(p.grad[2].numpy(), [1, 0, 0], atol=0.05)


def test_lookup_gradcheck_float64():
    rng = np.random.default_rng(3)
    values = torch.as_tensor(rng.normal(size=(5, 5, 5)))
    origin = torch.tensor([0.1, -0.2, 0.0], dtype=torch.float64)
    voxel = 0.05
    # points inside and outside the grid, off voxel faces (trilinear is not C1 across them)
    pts = torch.tensor([[0.213, -0.117, 0.061], [0.29, -0.03, 0.18], [0.5, -0.11, 0.07],
                        [0.05, -0.31, -0.04]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p: sdf_lookup(values, origin, voxel, p), (pts,))
    n = torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)
    c = torch.tensor([0.0, 0.1, 0.2], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: plane_sdf(p, c, n), (pts,))


def test_batched_lookup_uses_each_points_grid():
    a = torch.zeros((4, 4, 4))
    b = torch.ones((4, 4, 4))
    vals = torch.stack([a, b])
    origins = torch.zeros((2, 3), dtype=torch.float64)
    voxels = torch.tensor([1.0, 2.0], dtype=torch.float64)
    pts = torch.tensor([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [10.0, 2.0, 2.0]], dtype=torch.float64)
    d = sdf_lookup_batched(vals, origins, voxels, torch.tensor([0, 1, 1]), pts)
    # grid 1 spans [0, 6]; the third point is 4 past its x face: 1 + 4
    np.testing.assert_allclose(d.numpy(), [0.0, 1.0, 5.0])


def test_plane_sdf_is_signed_distance():
    pts = torch.tensor([[0.0, 0.0, 0.3], [1.0, 2.0, -0.1]], dtype=torch.float64)
    d = plane_sdf(pts, torch.tensor([0.0, 0.0, 0.1]), torch.tensor([0.0, 0.0, 2.0]))
    np.testing.assert_allclose(d.numpy(), [0.2, -0.2])


def test_packed_grids_of_different_resolutions_match_single_lookups():
    rng = np.random.default_rng(5)
    grids = [torch.as_tensor(rng.normal(size=(r, r, r)).astype(np.float32)) for r in (4, 7, 5)]
    origins = torch.as_tensor(rng.normal(size=(3, 3)))
    voxels = torch.tensor([0.1, 0.05, 0.2], dtype=torch.float64)
    packed = pack_grids(grids, origins, voxels)
    pts = torch.as_tensor(rng.normal(size=(60, 3)) * 0.3)
    which = torch.as_tensor(rng.integers(0, 3, size=60))
    d = sdf_lookup_packed(packed, which, pts + origins[which] + 0.15)
    for k in range(3):
        sel = which == k
        ref = sdf_lookup(grids[k], origins[k], voxels[k], pts[sel] + origins[k] + 0.15)
        np.testing.assert_allclose(d[sel].numpy(), ref.numpy(), atol=1e-12)
