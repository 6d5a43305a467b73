"""Differentiable rigid-body simulator (torch) for the physics-constrained optimisation.

One free body (surface sample points, mass, COM, inertia) against a support plane and
fixed bodies given by SDF grids; velocity-level contact with Coulomb friction solved
exactly enough that a resting body does not creep; semi-implicit Euler. Brax's shape::

    system = system_from_mesh(mesh, mass_kg=0.3, friction=0.8, plane=make_plane(...))
    state = init(system, world_from_object, rotvec=delta)      # delta may require grad
    states = rollout(system, state, steps=40)
    loss = sim_velocity_loss(states, system.params.dt_s)

Modules: :mod:`.system` (the model), :mod:`.state` (state and ``init``), :mod:`.contacts`,
:mod:`.solver` (the impulse solve), :mod:`.dynamics` (``step``, ``rollout``), :mod:`.losses`,
:mod:`.obstacles` (SDF obstacles), :mod:`.rotation`, :mod:`.sdf`.
"""

from r2s.sim.diffsim.losses import sim_velocity_loss, static_wrench_residual
from r2s.sim.diffsim.obstacles import box_obstacle, mesh_obstacle, obstacle_from_grid
from r2s.sim.diffsim.state import State, init, points_in_world, world_from_object
from r2s.sim.diffsim.dynamics import rollout, step
from r2s.sim.diffsim.system import (SdfObstacle, SolverParams, SupportPlane, System, make_obstacle,
                                    make_plane, system_from_mesh)

__all__ = [
    "SdfObstacle", "SolverParams", "State", "SupportPlane", "System", "box_obstacle", "init",
    "make_obstacle", "make_plane", "mesh_obstacle", "obstacle_from_grid", "points_in_world",
    "rollout", "sim_velocity_loss", "static_wrench_residual", "step", "system_from_mesh",
    "world_from_object",
]
