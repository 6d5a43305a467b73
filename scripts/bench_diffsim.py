#!/usr/bin/env python
"""Speed of the torch simulator (r2s.sim.diffsim): steps/s and rollout gradients.

Scenarios, a 10 cm box with ``--samples`` surface points (default 1000):
  free       falling, no contact
  rest       resting on the plane (steady state: warm-started solves)
  slide      sliding down a 20 deg slope (mu 0.2)
  topple     toppling off the edge of a table given as an SDF grid (64^3)
For each: forward steps/s without autograd, and Newton steps per contact solve. Then the
optimiser's use: forward + backward of a ``--horizon``-step rollout (velocity loss w.r.t.
pose perturbation, COM, mass and friction), and the static wrench residual.

Usage:
  python scripts/bench_diffsim.py --samples 1000 --steps 120 --horizon 40 --threads 1
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from r2s.sim.diffsim import (box_obstacle, init, make_plane, rollout,  # noqa: E402
                             sim_velocity_loss, static_wrench_residual, step, system_from_mesh)
from r2s.sim.diffsim.solver import STATS  # noqa: E402


def pose(x: float, y: float, z: float, rot=None) -> np.ndarray:
    out = np.eye(4)
    if rot is not None:
        out[:3, :3] = rot
    out[:3, 3] = (x, y, z)
    return out


def scenario(name: str, samples: int, dtype: torch.dtype):
    """(system, world_from_object) of a named scenario."""
    mesh = trimesh.creation.box((0.1, 0.1, 0.1))
    if name == "slide":
        a = math.radians(20.0)
        normal = np.array([0.0, -math.sin(a), math.cos(a)])
        plane = make_plane([0, 0, 0], normal, 0.2, dtype=dtype)
        rot = trimesh.transformations.rotation_matrix(a, [1, 0, 0])[:3, :3]
        start = pose(*(0.05 * normal), rot=rot)
        obstacles = ()
    else:
        plane = make_plane([0, 0, 0], [0, 0, 1], 0.5, dtype=dtype)
        start = {"free": pose(0, 0, 2.0), "rest": pose(0, 0, 0.05),
                 "topple": pose(0.17, 0, 0.15)}[name]
        obstacles = ()
        if name == "topple":
            obstacles = (box_obstacle((0.15, 0.15, 0.05), pose(0, 0, 0.05), 1.0, dtype=dtype),)
    system = system_from_mesh(mesh, 1.0, friction=1.0, samples=samples, plane=plane,
                              obstacles=obstacles, dtype=dtype)
    return system, start


def forward_rate(name: str, samples: int, steps: int, dtype: torch.dtype) -> tuple[float, float]:
    """(steps per second, Newton steps per solve) of a no-grad run."""
    system, start = scenario(name, samples, dtype)
    state = init(system, start)
    with torch.no_grad():
        state = step(system, state)                       # warm up
        STATS.newton_steps = STATS.solves = 0
        t0 = time.perf_counter()
        for _ in range(steps):
            state = step(system, state)
        elapsed = time.perf_counter() - t0
    per_solve = STATS.newton_steps / STATS.solves if STATS.solves else 0.0
    return steps / elapsed, per_solve


def rollout_gradient(name: str, samples: int, horizon: int,
                     dtype: torch.dtype) -> tuple[float, float]:
    """Seconds for the forward and the backward pass of a velocity-loss rollout."""
    system, start = scenario(name, samples, dtype)
    com = system.com_in_object.clone().requires_grad_()
    mass = system.mass_kg.clone().requires_grad_()
    friction = system.friction.clone().requires_grad_()
    system = system.replace(com_in_object=com, mass_kg=mass, friction=friction)
    translation = torch.zeros(3, dtype=dtype, requires_grad=True)
    rotvec = torch.zeros(3, dtype=dtype, requires_grad=True)
    t0 = time.perf_counter()
    states = rollout(system, init(system, start, translation=translation, rotvec=rotvec), horizon)
    loss = sim_velocity_loss(states, system.params.dt_s)
    t1 = time.perf_counter()
    loss.backward()
    t2 = time.perf_counter()
    for t in (com, mass, friction, translation, rotvec):
        assert t.grad is None or torch.isfinite(t.grad).all()      # None: no path (free fall)
    return t1 - t0, t2 - t1


def wrench_residual_time(samples: int, dtype: torch.dtype) -> tuple[float, float]:
    system, start = scenario("topple", samples, dtype)
    com = system.com_in_object.clone().requires_grad_()
    system = system.replace(com_in_object=com)
    t0 = time.perf_counter()
    residual, _ = static_wrench_residual(system, init(system, start))
    t1 = time.perf_counter()
    residual.backward()
    return t1 - t0, time.perf_counter() - t1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=120)
    parser.add_argument("--horizon", type=int, default=40)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} thread(s), {args.samples} sample points")
    print("| scenario | dtype | steps/s (no grad) | Newton steps/solve | "
          f"{args.horizon}-step rollout fwd s | bwd s |")
    print("|---|---|---|---|---|---|")
    for dtype in (torch.float64, torch.float32):
        for name in ("free", "rest", "slide", "topple"):
            rate, newton = forward_rate(name, args.samples, args.steps, dtype)
            fwd, bwd = rollout_gradient(name, args.samples, args.horizon, dtype)
            print(f"| {name} | {str(dtype).replace('torch.', '')} | {rate:.0f} | {newton:.1f} | "
                  f"{fwd:.2f} | {bwd:.2f} |")
    fwd, bwd = wrench_residual_time(args.samples, torch.float64)
    print(f"static_wrench_residual (table edge, float64): {fwd * 1e3:.0f} ms forward, "
          f"{bwd * 1e3:.0f} ms backward")


if __name__ == "__main__":
    main()
