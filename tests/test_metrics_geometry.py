"""Geometry metrics against analytic values: chamfer, F-score, IoU, pose errors, and the
two helpers they rest on (point-to-surface distance, inside test)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from helpers_export import pose, rot_x

from r2s.metrics.geometry import (centroid_error_mm, chamfer_distance_mm, fscore, posed,
                                  rotation_error_deg, surface_metrics, volumetric_iou)
from r2s.metrics.occupancy import contains
from r2s.metrics.proximity import (_pair_distances, closest_points_on_triangles,
                                   surface_distances_to)


def _shifted(mesh, offset):
    out = mesh.copy()
    out.apply_translation(offset)
    return out


def test_chamfer_of_mesh_with_itself_is_zero():
    mesh = trimesh.creation.capsule(height=0.08, radius=0.03)
    assert chamfer_distance_mm(mesh, mesh.copy(), n_samples=5000) == pytest.approx(0.0, abs=1e-6)


def test_chamfer_unit_sphere_shifted_3mm():
    """Expected: mean over the unit sphere of | |p - d e| - 1 |, with cos(theta) uniform on
    [-1, 1] (Archimedes), integrated numerically (about d / 2 = 1.5 mm). The faceting of a
    5120-face icosphere adds < 0.02 mm; tolerance 0.03 mm."""
    d = 0.003
    cos = np.linspace(-1.0, 1.0, 2_000_001)
    expected_mm = 1000.0 * np.mean(np.abs(np.sqrt(1.0 - 2.0 * d * cos + d * d) - 1.0))
    assert expected_mm == pytest.approx(1.5, abs=0.01)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    got = chamfer_distance_mm(sphere, _shifted(sphere, [0.0, 0.0, d]), n_samples=10000)
    assert got == pytest.approx(expected_mm, abs=0.03)


def test_fscore_identical_is_one_and_of_far_meshes_zero():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    assert fscore(mesh, mesh.copy(), threshold_mm=10.0, n_samples=4000) == 1.0
    assert fscore(mesh, _shifted(mesh, [0.3, 0, 0]), threshold_mm=10.0, n_samples=4000) == 0.0


def test_fscore_of_boxes_shifted_20mm():
    """10 cm cubes 20 mm apart along x, threshold 10 mm. Of the recon surface, the four side
    faces are within 10 mm where x <= 0.06 (0.9 of each), the -x face where max(|y|, |z|) >
    0.04 (1 - 0.8^2 = 0.36), the +x face nowhere: precision = (4 * 0.9 + 0.36) / 6 = 0.66,
    recall the same by symmetry. Sampling error ~0.005; tolerance 0.02."""
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    m = surface_metrics(_shifted(box, [0.02, 0, 0]), box, threshold_mm=10.0, n_samples=10000)
    assert m.precision == pytest.approx(0.66, abs=0.02)
    assert m.recall == pytest.approx(0.66, abs=0.02)
    assert m.fscore == pytest.approx(0.66, abs=0.02)
    assert m.threshold_mm == 10.0


def test_iou_of_boxes_overlapping_by_half():
    box = trimesh.creation.box([0.1, 0.08, 0.06])
    iou = volumetric_iou(box, _shifted(box, [0.05, 0, 0]), n_samples=10000, seed=0)
    assert iou == pytest.approx(1.0 / 3.0, abs=0.02)
    assert volumetric_iou(box, box.copy(), n_samples=2000) == 1.0
    assert volumetric_iou(box, _shifted(box, [0.2, 0, 0]), n_samples=2000) == 0.0


def test_iou_is_seeded():
    a = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    b = _shifted(a, [0.03, 0, 0])
    assert volumetric_iou(a, b, 3000, seed=1) == volumetric_iou(a, b, 3000, seed=1)


def test_pose_errors():
    mesh = trimesh.creation.box([0.1, 0.05, 0.02])
    gt_pose = pose([0.1, 0.2, 0.01], rot_x(0.2))
    recon_pose = pose([0.103, 0.204, 0.01], rot_x(0.2) @ rot_x(np.radians(30.0)))
    # rotation about the box centre leaves the centroid where the translation puts it
    err = centroid_error_mm(posed(mesh, recon_pose), posed(mesh, gt_pose))
    assert err == pytest.approx(5.0, abs=1e-6)
    assert rotation_error_deg(recon_pose, gt_pose) == pytest.approx(30.0, abs=1e-9)


def test_closest_point_on_triangle_against_dense_sampling():
    """Random triangles (some collinear, some with two equal vertices) against a barycentric
    grid of 201 x 201: the exact distance is never above the grid's minimum and below it
    by less than the grid spacing times the longest edge."""
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(120, 3, 3))
    tri[:20, 2] = 0.3 * tri[:20, 0] + 0.7 * tri[:20, 1]
    tri[20:30, 1] = tri[20:30, 0]
    points = rng.normal(size=(120, 3)) * 2.0
    got = np.linalg.norm(closest_points_on_triangles(tri, points) - points, axis=1)
    u, v = np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201))
    keep = (u + v) <= 1.0
    u, v = u[keep], v[keep]
    for k in range(len(tri)):
        a, b, c = tri[k]
        grid = a + np.outer(u, b - a) + np.outer(v, c - a)
        dense = np.linalg.norm(grid - points[k], axis=1).min()
        longest = max(np.linalg.norm(b - a), np.linalg.norm(c - a))
        assert dense - longest / 200 - 1e-12 <= got[k] <= dense + 1e-12


def test_surface_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    for mesh in (trimesh.creation.cylinder(radius=0.03, height=0.08, sections=24),
                 trimesh.creation.icosphere(subdivisions=2, radius=0.05)):
        near, _ = trimesh.sample.sample_surface(mesh, 300, seed=rng)
        points = np.r_[near + rng.normal(0, 0.005, near.shape),
                       rng.uniform(-0.15, 0.15, (300, 3))]
        got = surface_distances_to(mesh, points)
        tri = np.asarray(mesh.triangles)
        want = [_pair_distances(tri, np.repeat(q[None], len(tri), axis=0)).min() for q in points]
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_contains_against_analytic_sphere_and_box():
    rng = np.random.default_rng(0)
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    pts = rng.uniform(-1.2, 1.2, (20000, 3))
    r = np.linalg.norm(pts, axis=1)
    clear = np.abs(r - 1.0) > 0.01  # the 5120-face sphere deviates from r = 1 by < 0.01
    inside = contains(sphere, pts)
    assert np.array_equal(inside[clear], r[clear] < 1.0)
    box = trimesh.creation.box([0.1, 0.2, 0.3])
    pts = rng.uniform(-0.2, 0.2, (20000, 3))
    assert np.array_equal(contains(box, pts), np.all(np.abs(pts) < [0.05, 0.1, 0.15], axis=1))


def test_surface_distance_with_faces_of_every_radius_class_equals_brute_force():
    """Faces of each radius class (below 1, 1-2, 2-4 and over 4 median radii) are searched
    in separate trees; the distances are bit for bit the minimum over all faces."""
    rng = np.random.default_rng(7)
    parts = [trimesh.creation.icosphere(subdivisions=s, radius=r).apply_translation(c)
             for s, r, c in ((3, 0.05, (0, 0, 0)), (2, 0.05, (0.12, 0, 0)),
                             (1, 0.06, (0, 0.14, 0)), (0, 0.08, (0, 0, 0.2)))]
    mesh = trimesh.util.concatenate(parts)
    radii = np.linalg.norm(mesh.triangles - mesh.triangles_center[:, None], axis=2).max(axis=1)
    ratio = radii / np.median(radii)
    for lo, hi in ((0, 1), (1, 2), (2, 4), (4, np.inf)):
        assert np.any((ratio > lo) & (ratio <= hi)), (lo, hi)
    near, _ = trimesh.sample.sample_surface(mesh, 400, seed=rng)
    points = np.r_[near + rng.normal(0, 0.01, near.shape), rng.uniform(-0.2, 0.3, (400, 3))]
    got = surface_distances_to(mesh, points)
    tri = np.asarray(mesh.triangles)
    want = [_pair_distances(tri, np.repeat(q[None], len(tri), axis=0)).min() for q in points]
    np.testing.assert_array_equal(got, want)
