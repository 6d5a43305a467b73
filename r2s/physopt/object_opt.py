"""Per-object optimisation through the differentiable simulator, root to leaves.

For object j (parents and every other object fixed as SDF obstacles, the table as a
plane) the parameters theta_j = {pose offset, COM, friction} minimise

    L = lambda_w * R_wrench + lambda_s * L_sim + lambda_a * anchor(pose) + lambda_c * |dCOM|^2

where R_wrench is the quasi-static wrench residual (0 when admissible contact forces in
the friction cones balance gravity), L_sim the paper's 1/2 sum |v|^2 h over a short
rollout, and the anchor keeps the pose near the observation. The COM is kept inside the
shape's central box (:attr:`r2s.physopt.params.ObjectParams.com_lo` / ``com_hi``) and the friction within its bounds; the mass is kept at its prior
(a single body on fixed supports has no mass gradient). An object whose residual is
already below tolerance is left unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from r2s.geometry.sdf import compute_sdf
from r2s.physopt.params import ObjectParams, Params
from r2s.sim.adam import Adam  # torch.optim.Adam's steps without importing torch._dynamo
from r2s.sim.diffsim import (init, make_plane, obstacle_from_grid, rollout, sim_velocity_loss,
                             static_wrench_residual, system_from_mesh, world_from_object)


def _near(bounds: dict, a: int, b: int, margin_m: float) -> bool:
    lo_a, hi_a = bounds[a]
    lo_b, hi_b = bounds[b]
    return bool(np.all(lo_a - margin_m <= hi_b) and np.all(lo_b - margin_m <= hi_a))


def _world_bounds(mesh, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pts = mesh.vertices @ pose[:3, :3].T + pose[:3, 3]
    return pts.min(0), pts.max(0)


def optimise_objects(params: Params, meshes: dict, state, order: list[int], opt, log: dict,
                     progress) -> Params:
    """New parameters (pose, COM, friction) of the objects in ``order``, one by one, each
    against the others' current values. ``opt``: the physopt options (diffsim_*, lambda_*,
    anchor_*, contact_margin_m, wrench_tolerance, sim_*, friction_bounds,
    support_friction)."""
    params = dict(params)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        grids: dict[int, object] = {}
        plane = make_plane(state.support.point, state.support.normal, opt.support_friction)
        for k, oid in enumerate(order):
            progress(f"object {oid}: differentiable simulation", 0.1 + 0.4 * k / len(order))
            bounds = {i: _world_bounds(meshes[i], params[i].world_from_object) for i in order}
            neighbours = [j for j in order if j != oid and _near(bounds, oid, j, 0.01)]
            obstacles = []
            for j in neighbours:
                if j not in grids:
                    grids[j] = compute_sdf(meshes[j], resolution=opt.diffsim_sdf_resolution)
                pose_j = np.array(params[j].world_from_object)
                obstacles.append(obstacle_from_grid(grids[j], pose_j, params[j].friction))
            note, params[oid] = _optimise_one(meshes[oid], params[oid], plane, tuple(obstacles),
                                              state.gravity, opt)
            log["objects"][oid].append(note)
    finally:
        torch.set_num_threads(threads)
    return params


def _optimise_one(mesh, p: ObjectParams, plane, obstacles: tuple, gravity, opt
                  ) -> tuple[str, ObjectParams]:
    """One object's optimisation; returns a log line and its new parameters."""
    dtype = torch.float64
    system = system_from_mesh(mesh, p.mass_kg, np.array(p.com_in_object), p.friction,
                              samples=opt.diffsim_samples, plane=plane, obstacles=obstacles,
                              gravity=gravity, dtype=dtype)
    pose0 = torch.as_tensor(np.array(p.world_from_object), dtype=dtype)
    with torch.no_grad():
        r0, _ = static_wrench_residual(system, init(system, pose0), margin_m=opt.contact_margin_m)
    r0 = float(r0)
    if r0 <= opt.wrench_tolerance:
        return f"diffsim: statically balanced (wrench residual {r0:.3f}); unchanged", p

    lo_f, hi_f = opt.friction_bounds
    c0 = torch.as_tensor(np.array(p.com_in_object), dtype=dtype)
    inner_lo, inner_hi = (torch.tensor(np.array(b), dtype=dtype) for b in (p.com_lo, p.com_hi))
    t = torch.zeros(3, dtype=dtype, requires_grad=True)
    rv = torch.zeros(3, dtype=dtype, requires_grad=True)
    dc = torch.zeros(3, dtype=dtype, requires_grad=True)
    f0 = float(np.clip((p.friction - lo_f) / (hi_f - lo_f), 0.02, 0.98))
    fl = torch.tensor(np.log(f0 / (1 - f0)), dtype=dtype, requires_grad=True)
    optim = Adam([{"params": [t], "lr": 1e-3}, {"params": [rv], "lr": 5e-3},
                              {"params": [dc], "lr": 2e-3}, {"params": [fl], "lr": 0.2}])
    best = (float("inf"), None)
    sigma_t, sigma_r = opt.anchor_translation_m, np.radians(opt.anchor_rotation_deg)
    for it in range(opt.diffsim_iterations):
        com = torch.minimum(torch.maximum(c0 + dc, inner_lo), inner_hi)
        friction = lo_f + (hi_f - lo_f) * torch.sigmoid(fl)
        sys_v = system.replace(com_in_object=com, friction=friction)
        st = init(sys_v, pose0, translation=t, rotvec=rv)
        residual, _ = static_wrench_residual(sys_v, st, margin_m=opt.contact_margin_m)
        anchor = (t @ t) / sigma_t**2 + (rv @ rv) / sigma_r**2
        loss = opt.lambda_wrench * residual + opt.lambda_anchor * anchor \
            + opt.lambda_com * (dc @ dc) / (0.01**2)
        if opt.sim_steps > 0 and it % opt.sim_every == 0:
            states = rollout(sys_v, st, opt.sim_steps)
            loss = loss + opt.lambda_sim * sim_velocity_loss(states, sys_v.params.dt_s)
        value = float(residual.detach())
        if value < best[0]:
            with torch.no_grad():
                best = (value, (world_from_object(sys_v, st).numpy().copy(), com.numpy().copy(),
                                float(friction)))
        if value <= opt.wrench_tolerance:
            break
        optim.zero_grad()
        loss.backward()
        for g in (t, rv, dc, fl):
            if g.grad is not None:
                torch.nan_to_num_(g.grad, 0.0, 0.0, 0.0)
        optim.step()
    if best[1] is None or best[0] >= r0:
        return f"diffsim: wrench residual {r0:.3f} not improved; unchanged", p
    pose, com, friction = best[1]
    shift_mm = 1000 * float(np.linalg.norm(pose[:3, 3] - p.world_from_object[:3, 3]))
    com_mm = 1000 * float(np.linalg.norm(com - p.com_in_object))
    note = (f"diffsim: wrench residual {r0:.3f} -> {best[0]:.3f} (pose moved {shift_mm:.1f} mm, "
            f"COM moved {com_mm:.1f} mm, friction {friction:.2f})")
    return note, replace(p, world_from_object=pose, com_in_object=com, friction=friction)
