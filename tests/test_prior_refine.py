"""Per-axis scale refinement of a registered prior (r2s/geometry/prior_refine.py)."""

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from helpers_init import SynthObject, default_camera, render_view
from r2s.geometry.camera import backproject
from r2s.geometry.free_space import view_constraint
from r2s.geometry.prior_refine import RefineOptions, refine_axis_scale
from r2s.geometry.registration import IcpOptions, register_prior

TRUE_EXTENTS_M = np.array([0.16, 0.10, 0.06])
CAMERA_M = np.array([0.45, -0.35, 0.40])
FREE_SCALE = RefineOptions(scale_ridge=0.0, schedule_m=(0.02, 0.01, 0.005), seed=0)
"""No pull of the axis scales towards the registration's: the box's three axes are all in
view here (init keeps a ridge, as unseen axes of real partial views drift to the bounds)."""


def _visible_box_points(count: int = 6000, seed: int = 0) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The true box resting on z = 0 at the origin, and its camera-facing surface samples
    (a convex box: facing the camera = visible)."""
    box = trimesh.creation.box(extents=TRUE_EXTENTS_M)
    box.apply_translation([0.0, 0.0, TRUE_EXTENTS_M[2] / 2])
    pts, faces = trimesh.sample.sample_surface(box, count, seed=seed)
    normals = box.face_normals[faces]
    facing = np.einsum("nj,nj->n", normals, CAMERA_M - pts) > 0
    return box, np.asarray(pts)[facing]


def _pose(rotvec_deg: np.ndarray, translation_m: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    out[:3, 3] = translation_m
    return out


def test_box_prior_with_wrong_proportions_recovers_extents_and_pose():
    # a ray-cast 320 x 240 view of the true box on the table, 35 deg above it
    K, world_from_camera = default_camera(320, 240, eye=(0.3, -0.25, 0.3))
    box = trimesh.creation.box(extents=TRUE_EXTENTS_M)
    _, depth, masks = render_view([SynthObject(1, box, _pose([0, 0, 0], [0, 0, 0.03]))], K,
                                  world_from_camera, 320, 240)
    observed = backproject(depth, K, world_from_camera, masks == 1)
    view = view_constraint(K, world_from_camera, depth, masks == 1)
    camera = world_from_camera[:3, 3]
    # the prior: the true box with proportions off by 1.15 x 0.9 x 1.0, its own frame
    prior = trimesh.creation.box(extents=TRUE_EXTENTS_M * np.array([1.15, 0.9, 1.0]))
    truth = _pose([0, 0, 0], [0, 0, TRUE_EXTENTS_M[2] / 2])
    start = _pose([0, 0, 20], [0.01, -0.008, TRUE_EXTENTS_M[2] / 2 + 0.005])
    reg = register_prior(prior, observed, start, view=view,
                         options=IcpOptions(local_yaw_steps=1, seed=0))
    refined = refine_axis_scale(prior, observed, reg.world_from_object, reg.scale, camera,
                                view=view,
                                support=(np.zeros(3), np.array([0.0, 0.0, 1.0])),
                                options=FREE_SCALE)
    mesh, pose = refined.object_mesh(prior)
    # extents within 3 % of the truth, per axis
    np.testing.assert_allclose(mesh.extents, TRUE_EXTENTS_M, rtol=0.03)
    # centre within 5 mm, rotation within 3 deg (a box: up to its 180-deg symmetries)
    assert np.linalg.norm(pose[:3, 3] - truth[:3, 3]) < 0.005
    rel = pose[:3, :3].T @ truth[:3, :3]
    angles = [np.degrees(np.linalg.norm(Rotation.from_matrix(rel @ np.diag(f)).as_rotvec()))
              for f in ([1, 1, 1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1])]
    assert min(angles) < 3.0


def test_prior_sunk_into_the_support_is_lifted_out_of_it():
    box, observed = _visible_box_points()
    prior = trimesh.creation.box(extents=TRUE_EXTENTS_M)
    sunk = _pose([0, 0, 0], [0, 0, TRUE_EXTENTS_M[2] / 2 - 0.006])
    plane = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    # only the top face seen: the data term does not fix the height on its own
    top = observed[observed[:, 2] > TRUE_EXTENTS_M[2] - 1e-6] - np.array([0, 0, 0.006])
    free = refine_axis_scale(prior, top, sunk, 1.0, CAMERA_M, support=None)
    held = refine_axis_scale(prior, top, sunk, 1.0, CAMERA_M, support=plane)
    bottom = lambda r: (r.object_mesh(prior)[0].copy()  # noqa: E731
                        .apply_transform(r.object_mesh(prior)[1]).bounds[0, 2])
    assert bottom(free) < -0.004  # without the plane it stays sunk
    assert bottom(held) > -0.001  # with it, out of the plane within 1 mm
    assert held.on_support
