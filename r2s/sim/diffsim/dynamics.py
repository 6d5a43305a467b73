"""One time step and a rollout: ``step(system, state) -> State`` (semi-implicit Euler).

A step: gravity (and the gyroscopic torque) update the velocity; the contact impulse solve
(:mod:`r2s.sim.diffsim.solver`) makes the velocity admissible; the pose is then advanced
with the *new* velocity (position += v dt, orientation by the exponential map of w dt).
"""

from __future__ import annotations

import torch

from r2s.sim.diffsim.contacts import Contacts, find_contacts
from r2s.sim.diffsim.rotation import integrate_quat, matrix_from_quat
from r2s.sim.diffsim.solver import solve_impulses
from r2s.sim.diffsim.state import State, points_in_world
from r2s.sim.diffsim.system import System


def world_inertia(system: System, rot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(3, 3) world inertia about the COM and its inverse for the body rotation ``rot`` (3, 3)."""
    inertia_body = system.mass_kg * system.inertia_per_kg
    inertia = rot @ inertia_body @ rot.T
    inv_inertia = rot @ torch.linalg.inv(inertia_body) @ rot.T
    return inertia, 0.5 * (inv_inertia + inv_inertia.T)


def free_velocity(system: System, state: State, inertia: torch.Tensor,
                  inv_inertia: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(3,), (3,) velocity after gravity (and the explicit gyroscopic torque) for one step."""
    dt = system.params.dt_s
    v = state.linear_velocity + system.gravity * dt
    w = state.angular_velocity
    if system.params.gyroscopic:
        torque = -torch.linalg.cross(w, inertia @ w)
        w = w + dt * (inv_inertia @ torque)
    return v, w


def normal_target(system: System, distance: torch.Tensor) -> torch.Tensor:
    """Minimum normal velocity per contact from its signed ``distance`` (any shape).

    A gap ``d >= 0`` may close in one step (``-d / dt``, speculative contact); a penetration
    deeper than ``slop_m`` is pushed out at ``erp`` of its depth per step (Baumgarte).
    Continuous in ``d``.
    """
    p = system.params
    push_out = p.erp * torch.relu(-distance - p.slop_m) / p.dt_s
    return torch.where(distance >= 0, -distance / p.dt_s, push_out)


def contact_velocity(system: System, state: State, contacts: Contacts, lever: torch.Tensor,
                     v_free: torch.Tensor, w_free: torch.Tensor, inertia: torch.Tensor,
                     inv_inertia: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Run the impulse solve over the contact pairs.

    Returns the (E, N, 3) impulses (zero off contact; the next step's warm start) and the
    body velocity (3,), (3,) after contact.
    """
    impulse = torch.zeros_like(state.contact_impulse)
    if contacts.count == 0:
        return impulse, v_free, w_free
    warm = state.contact_impulse[contacts.body, contacts.point]
    p = system.params
    pair_impulse, v, w = solve_impulses(
        v_free, w_free, system.mass_kg, inertia, inv_inertia, lever[contacts.point],
        contacts.normal, normal_target(system, contacts.distance), contacts.friction, warm,
        p.outer_iterations, p.newton_iterations, p.tolerance_mps, p.rho_scale,
        p.refine_iterations)
    impulse = impulse.index_put((contacts.body, contacts.point), pair_impulse)
    return impulse, v, w


def step(system: System, state: State) -> State:
    """Advance ``state`` by ``system.params.dt_s`` (pure; differentiable)."""
    rot = matrix_from_quat(state.orientation)
    inertia, inv_inertia = world_inertia(system, rot)
    v_free, w_free = free_velocity(system, state, inertia, inv_inertia)
    points, lever = points_in_world(system, state, rot)
    contacts = find_contacts(system, points)
    impulse, v, w = contact_velocity(system, state, contacts, lever, v_free, w_free, inertia,
                                     inv_inertia)
    dt = system.params.dt_s
    return State(
        position=state.position + v * dt,
        orientation=integrate_quat(state.orientation, w, dt),
        linear_velocity=v,
        angular_velocity=w,
        time_s=state.time_s + dt,
        contact_impulse=impulse,
    )


def rollout(system: System, state: State, steps: int) -> list[State]:
    """``[state, step(state), ...]``: ``steps + 1`` states."""
    states = [state]
    for _ in range(steps):
        states.append(step(system, states[-1]))
    return states
