"""Unit tests of the torch simulator: geometry helpers, the contact solve, gradients, losses.

Every number is checked against an analytic value (rotations, box SDF and inertia,
Coulomb's law, discrete free fall and sliding) or against finite differences
(``torch.autograd.gradcheck`` in float64).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from r2s.sim.diffsim import (box_obstacle, init, make_plane, rollout, sim_velocity_loss,
                             static_wrench_residual, step, system_from_mesh, world_from_object)
from r2s.sim.diffsim.contacts import find_contacts
from r2s.sim.diffsim.obstacles import box_sdf
from r2s.sim.diffsim.rotation import (integrate_quat, matrix_from_quat, quat_from_matrix,
                                      quat_from_rotvec)
from r2s.sim.diffsim.sdf import sdf_lookup, trilinear_sdf
from r2s.sim.diffsim.solver import solve_impulses
from r2s.sim.diffsim.state import points_in_world
from r2s.sim.diffsim.system import SolverParams, System

torch.set_num_threads(1)
F64 = torch.float64
G = 9.81
DT = 1.0 / 240.0


def box_system(size=(0.1, 0.1, 0.1), mass_kg=1.0, com=(0.0, 0.0, 0.0), friction=1.0,
               plane_friction=0.5, normal=(0.0, 0.0, 1.0), samples=150, obstacles=(),
               params=None, dtype=F64) -> System:
    return system_from_mesh(trimesh.creation.box(size), mass_kg, com_in_object=com,
                            friction=friction, samples=samples,
                            plane=make_plane([0, 0, 0], normal, plane_friction, dtype=dtype),
                            obstacles=obstacles, params=params, dtype=dtype)


def pose_at(x, y, z, rot=None) -> np.ndarray:
    pose = np.eye(4)
    if rot is not None:
        pose[:3, :3] = rot
    pose[:3, 3] = (x, y, z)
    return pose


# --- geometry helpers -------------------------------------------------------------------

def test_rotations_match_scipy():
    rng = np.random.default_rng(0)
    rotvecs = rng.normal(size=(20, 3))
    rotvecs[0] = 0.0
    rotvecs[1] = 1e-9
    q = quat_from_rotvec(torch.tensor(rotvecs))
    ours = matrix_from_quat(q).numpy()
    ref = Rotation.from_rotvec(rotvecs).as_matrix()
    assert np.abs(ours - ref).max() < 1e-12
    for rot in ref[:5]:
        back = matrix_from_quat(quat_from_matrix(torch.tensor(rot))).numpy()
        assert np.abs(back - rot).max() < 1e-12
    # Integrating a constant angular velocity is exact.
    w = torch.tensor([0.3, -1.2, 2.0], dtype=F64)
    quat = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64)
    for _ in range(100):
        quat = integrate_quat(quat, w, 0.01)
    exact = Rotation.from_rotvec(w.numpy()).as_matrix()
    assert np.abs(matrix_from_quat(quat).numpy() - exact).max() < 1e-12


def test_zero_rotation_has_finite_gradient():
    rotvec = torch.zeros(3, dtype=F64, requires_grad=True)
    matrix_from_quat(quat_from_rotvec(rotvec)).sum().backward()
    assert torch.isfinite(rotvec.grad).all()


def test_sdf_lookup_matches_the_exact_box_distance():
    half = np.array([0.15, 0.1, 0.05])
    obstacle = box_obstacle(half, np.eye(4), 0.5, resolution=64, padding_m=0.02)
    rng = np.random.default_rng(1)
    points = rng.uniform(-half - 0.015, half + 0.015, size=(2000, 3))
    ours = sdf_lookup(obstacle.values, obstacle.origin, obstacle.voxel_size_m, torch.tensor(points))
    assert np.abs(ours.numpy() - box_sdf(half, points)).max() < obstacle.voxel_size_m
    # The package's own trilinear look-up and the shared one agree.
    own = trilinear_sdf(obstacle.values, obstacle.origin, obstacle.voxel_size_m,
                        torch.tensor(points))
    assert torch.allclose(own, ours, atol=1e-12)
    # Far outside the grid the distance keeps growing like the true distance.
    far = torch.tensor([[1.0, 0.0, 0.0]], dtype=F64)
    d = sdf_lookup(obstacle.values, obstacle.origin, obstacle.voxel_size_m, far)
    assert abs(float(d) - 0.85) < obstacle.voxel_size_m


def test_box_mass_properties_and_samples():
    size = (0.2, 0.1, 0.06)
    system = box_system(size=size, mass_kg=2.0, com=None, samples=200)
    a, b, c = size
    expected = np.diag([b**2 + c**2, a**2 + c**2, a**2 + b**2]) / 12.0
    assert np.abs(system.inertia_per_kg.numpy() - expected).max() < 1e-12
    assert np.abs(system.com_in_object.numpy()).max() < 1e-12
    points = system.points_in_object.numpy()
    assert points.shape == (200, 3)
    corners = trimesh.creation.box(size).vertices
    assert all(np.min(np.linalg.norm(points - v, axis=1)) < 1e-12 for v in corners)
    assert np.abs(box_sdf(np.asarray(size) / 2, points)).max() < 1e-12     # on the surface


def test_friction_combines_by_product():
    system = box_system(friction=0.8, plane_friction=0.5)
    state = init(system, pose_at(0, 0, 0.05))
    contacts = find_contacts(system, points_in_world(system, state)[0])
    assert contacts.count > 0
    assert torch.allclose(contacts.friction, torch.full_like(contacts.friction, 0.4))


# --- the contact solve ------------------------------------------------------------------

def _solve_on_plane(velocity, mu, samples=100):
    system = box_system(friction=1.0, plane_friction=mu, samples=samples)
    state = init(system, pose_at(0, 0, 0.05), linear_velocity=velocity)
    points, lever = points_in_world(system, state)
    contacts = find_contacts(system, points)
    inertia = system.mass_kg * system.inertia_per_kg
    v_free = state.linear_velocity + system.gravity * DT
    impulse, v, w = solve_impulses(v_free, torch.zeros(3, dtype=F64), system.mass_kg, inertia,
                                   torch.linalg.inv(inertia), lever[contacts.point],
                                   contacts.normal, torch.zeros(contacts.count, dtype=F64),
                                   contacts.friction, torch.zeros(contacts.count, 3, dtype=F64),
                                   tolerance_mps=1e-10)
    return impulse, v, w


def test_resting_contacts_stop_the_body_within_their_cones():
    impulse, v, w = _solve_on_plane([0.0, 0.0, 0.0], mu=0.5)
    assert float(v.abs().max()) < 1e-9 and float(w.abs().max()) < 1e-8
    normal = impulse[:, 2]
    tangential = impulse[:, :2].norm(dim=1)
    assert float(normal.min()) >= -1e-12
    assert bool((tangential <= 0.5 * normal + 1e-12).all())
    assert abs(float(normal.sum()) - G * DT) < 1e-9                    # carries the weight


def test_sliding_contacts_obey_coulomb_without_lift_off():
    mu, speed = 0.3, 1.0
    impulse, v, w = _solve_on_plane([speed, 0.0, 0.0], mu=mu)
    # Friction takes mu g dt off the speed, the box neither lifts nor sinks nor spins.
    assert abs(float(v[0]) - (speed - mu * G * DT)) < 1e-6
    assert abs(float(v[2])) < 1e-6 and float(w.abs().max()) < 1e-4
    total = impulse.sum(0)
    assert abs(float(total[0]) + mu * float(total[2])) < 1e-8            # |F_t| = mu F_n, opposing


# --- gradients --------------------------------------------------------------------------

CORNERS = torch.tensor([[x, y, z] for x in (-.05, .05) for y in (-.05, .05) for z in (-.05, .05)],
                       dtype=F64)
GRADCHECK_PARAMS = SolverParams(tolerance_mps=1e-12, refine_iterations=4)


def _one_step(translation, rotvec, velocity, com, mass, friction, obstacles=(), plane_z=0.0):
    system = System(points_in_object=CORNERS, mass_kg=mass, com_in_object=com,
                    inertia_per_kg=torch.eye(3, dtype=F64) * (0.1**2 / 6.0), friction=friction,
                    gravity=torch.tensor([0.0, 0.0, -G], dtype=F64),
                    plane=make_plane([0, 0, plane_z], [0, 0, 1], 0.8), obstacles=obstacles,
                    params=GRADCHECK_PARAMS)
    state = init(system, pose_at(0, 0, 0.048), linear_velocity=velocity, translation=translation,
                 rotvec=rotvec)
    nxt = step(system, state)
    return nxt.position, nxt.orientation, nxt.linear_velocity, nxt.angular_velocity


@pytest.mark.parametrize("velocity, rotvec", [
    ((0.3, 0.1, -0.2), (0.02, -0.01, 0.0)),     # tilted box sliding and rocking
    ((0.01, 0.0, 0.0), (0.0, 0.0, 0.0)),        # flat box held by static friction
])
def test_gradcheck_one_step(velocity, rotvec):
    args = tuple(torch.tensor(a, dtype=F64, requires_grad=True) for a in
                 [(0.0, 0.0, 0.0), rotvec, velocity, (0.01, 0.0, 0.0), 1.0, 0.6])
    assert torch.autograd.gradcheck(_one_step, args, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_gradcheck_one_step_against_an_sdf_obstacle():
    # The body's bottom corners sink 2 mm into a fixed box (turned 30 deg about z) whose top
    # face is at z = 0; the plane is out of reach.
    table_pose = pose_at(0.02, -0.01, -0.05, Rotation.from_rotvec([0, 0, 0.5]).as_matrix())
    table = box_obstacle((0.2, 0.2, 0.05), table_pose, 0.7, resolution=32)

    def fn(translation, com, friction):
        return _one_step(translation, torch.zeros(3, dtype=F64),
                         torch.tensor([0.2, 0.05, 0.0], dtype=F64), com,
                         torch.tensor(1.0, dtype=F64), friction, obstacles=(table,), plane_z=-0.2)

    args = tuple(torch.tensor(a, dtype=F64, requires_grad=True) for a in
                 [(0.0, 0.0, 0.0), (0.01, 0.0, 0.0), 0.6])
    assert torch.autograd.gradcheck(fn, args, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_slide_distance_gradient_matches_the_analytic_derivative():
    # Default solver settings: d(distance)/d(mu) = -g cos(a) dt^2 n (n + 1) / 2.
    a, steps = math.radians(20.0), 60
    normal = (0.0, -math.sin(a), math.cos(a))
    friction = torch.tensor(0.2, dtype=F64, requires_grad=True)
    system = box_system(friction=friction, plane_friction=1.0, normal=normal, samples=60)
    rot = Rotation.from_rotvec([a, 0, 0]).as_matrix()
    start = init(system, pose_at(*(0.05 * np.asarray(normal)), rot=rot))
    end = rollout(system, start, steps)[-1]
    distance = (end.position - start.position.detach()).norm()
    (grad,) = torch.autograd.grad(distance, friction)
    factor = G * DT**2 * steps * (steps + 1) / 2.0
    assert abs(float(distance.detach()) - (math.sin(a) - 0.2 * math.cos(a)) * factor) < 1e-6
    assert abs(float(grad) + math.cos(a) * factor) < 1e-3 * math.cos(a) * factor


def test_two_second_drop_is_finite_and_comes_to_rest():
    size = np.array([0.1, 0.08, 0.06])
    system = box_system(size=tuple(size), mass_kg=0.5, friction=0.7, plane_friction=1.0, samples=80)
    rot = Rotation.random(random_state=3).as_matrix()
    state = init(system, pose_at(0.0, 0.0, 0.2, rot), angular_velocity=[1.0, -2.0, 0.5])
    with torch.no_grad():
        for _ in range(480):
            state = step(system, state)
            assert torch.isfinite(state.position).all() and torch.isfinite(state.orientation).all()
    assert float(state.linear_velocity.norm()) < 1e-3
    assert np.min(np.abs(float(state.position[2]) - size / 2.0)) < 1e-3     # lies on a face


def _table_edge_system(com_x: float, samples: int = 120) -> System:
    """A 10 cm box on a table whose +x edge is at x = 0.15 (box centred at x = 0.13)."""
    table = box_obstacle((0.15, 0.15, 0.05), pose_at(0, 0, 0.05), 0.5, resolution=48)
    com = torch.tensor([com_x, 0.0, 0.0], dtype=F64, requires_grad=True)
    system = box_system(com=(0.0, 0.0, 0.0), samples=samples, obstacles=(table,))
    return system.replace(com_in_object=com)


def test_velocity_loss_gradient_wrt_com_of_a_tipping_box():
    system = _table_edge_system(com_x=0.04)                 # COM 2 cm past the edge
    states = rollout(system, init(system, pose_at(0.13, 0, 0.15)), 30)
    loss = sim_velocity_loss(states, DT)
    (grad,) = torch.autograd.grad(loss, system.com_in_object)
    assert torch.isfinite(grad).all()
    assert float(loss.detach()) > 1e-5
    assert float(grad[0]) > 0.0                              # further out tips faster


def test_velocity_loss_is_zero_at_rest_and_analytic_in_free_fall():
    system = box_system()
    states = rollout(system, init(system, pose_at(0, 0, 0.05)), 20)
    assert float(sim_velocity_loss(states, DT)) < 1e-12
    states = rollout(system, init(system, pose_at(0, 0, 1.0)), 20)
    expected = 0.5 * DT * sum((G * DT * n) ** 2 for n in range(1, 21))
    assert abs(float(sim_velocity_loss(states, DT)) - expected) < 1e-12


def test_static_wrench_residual_detects_the_support_polygon():
    residuals = []
    for com_x in (0.0, 0.01, 0.03, 0.04):                   # edge at com_x = 0.02
        system = _table_edge_system(com_x)
        residual, forces = static_wrench_residual(system, init(system, pose_at(0.13, 0, 0.15)))
        residuals.append(float(residual.detach()))
        if com_x == 0.04:
            (grad,) = torch.autograd.grad(residual, system.com_in_object)
            assert float(grad[0]) > 0.0                      # moving the COM back helps
        if com_x == 0.0:
            assert abs(float(forces.detach().sum(0)[2]) - G) < 1e-3  # the contacts carry the weight
    assert residuals[0] < 1e-6 and residuals[1] < 1e-4
    assert residuals[2] > 1e-3 and residuals[3] > residuals[2]
    floating = box_system()
    residual, _ = static_wrench_residual(floating, init(floating, pose_at(0, 0, 0.5)))
    assert float(residual) == 1.0


def test_float32_rollout_rests():
    system = box_system(dtype=torch.float32)
    start = init(system, pose_at(0.0, 0.0, 0.05))
    with torch.no_grad():
        end = rollout(system, start, 60)[-1]
    assert end.position.dtype == torch.float32
    moved = world_from_object(system, end) - world_from_object(system, start)
    assert float(moved.abs().max()) < 1e-4
