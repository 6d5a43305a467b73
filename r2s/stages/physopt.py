"""The ``physopt`` stage: make the reconstructed scene stay at rest in simulation.

Objects are processed root to leaves along the contact graph (parents fixed while a child
is optimised). Each object's pose, COM (kept inside the shape), mass (bounded around
volume x density) and friction (bounded to a plausible range) are optimised through the
differentiable simulator where it is available; then a verification pass re-simulates the
whole scene in PyBullet with the export's collision geometry, and objects that still move
are revisited with their neighbours (more friction within bounds, then letting the engine
settle them into the nearest rest state) until the scene is stable or the budget runs out.
Every change is recorded per object with its reason in ``physopt/log.json``.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Literal, Optional

import numpy as np
from pydantic import Field

from r2s.diagnose.model import corrected_state
from r2s.geometry.convex_cache import cached_convex_decomposition
from r2s.geometry.mass_properties import mass_properties
from r2s.io.atomic import atomic_write_json
from r2s.io.mesh_io import load_mesh, welded
from r2s.io.paths import ScenePaths
from r2s.io.state import SceneState, read_state, write_state
from r2s.errors import StageError
from r2s.physopt.hierarchy import descendants, order_root_to_leaves, parents_from_graph
from r2s.physopt.pybullet_world import (SimBody, build_world, depenetrate, drift, settle,
                                        support_centroid, world_gravity)
from r2s.stages.base import StageContext, StageOptions, StageSpec
from r2s.stages.manifest import Manifest
from r2s.stages.select import latest_state_stage


class Options(StageOptions):
    source: Literal["auto", "init", "geomopt"] = Field(
        "auto", description="State to start from (auto: geomopt if it ran, else init).")
    density_kg_m3: float = Field(600.0, gt=0, description="Nominal density for the mass prior.")
    mass_bounds: tuple[float, float] = Field(
        (0.5, 2.0), description="Mass bounds as factors of volume x density.")
    friction_bounds: tuple[float, float] = Field(
        (0.2, 1.0), description="Per-body friction bounds (PyBullet multiplies two bodies').")
    friction_init: float = Field(0.6, description="Starting per-body friction.")
    support_friction: float = Field(0.9, gt=0, description="Friction of the support plane.")
    verify_duration_s: float = Field(3.0, gt=0, description="Rollout length of the check.")
    tolerance_m: float = Field(0.005, gt=0, description="Largest COM motion counted as at rest.")
    tolerance_deg: float = Field(2.0, gt=0, description="Largest rotation counted as at rest.")
    max_rounds: int = Field(4, ge=0, description="Verification rounds (friction, then settling).")
    settle_duration_s: float = Field(2.0, gt=0, description="Quasi-static settling time per round.")
    settle_reset_steps: int = Field(8, ge=1, description="Velocities are zeroed every this many "
                                                         "steps while settling.")
    max_com_step_m: float = Field(0.01, gt=0, description="Largest COM move per round.")
    com_repair: bool = Field(False, description="In verification rounds, move a mover's COM "
                                                "towards the centroid of its contacts.")
    max_settle_shift_m: float = Field(
        0.03, gt=0, description="In early rounds, a settled object that moved further is kept "
                                "at its pose (its neighbours may still settle).")
    final_settle_shift_m: float = Field(
        0.15, gt=0, description="In the last round, the largest settling move accepted; an "
                                "object that must move further is reported unresolved.")
    only: Optional[int] = Field(None, description="Rerun only this object and the objects it "
                                                   "supports; the rest keep their last physopt "
                                                   "result and stay fixed.")
    use_diffsim: bool = Field(True, description="Optimise each object through the torch "
                                                "simulator before the PyBullet check.")
    diffsim_iterations: int = Field(30, ge=0, description="Adam steps per object.")
    diffsim_samples: int = Field(300, ge=10, description="Surface samples of the free body.")
    diffsim_sdf_resolution: int = Field(48, ge=16, description="SDF grid of fixed neighbours.")
    contact_margin_m: float = Field(0.0015, gt=0, description="Distance that may carry load in "
                                                           "the wrench residual.")
    wrench_tolerance: float = Field(0.01, ge=0, description="Residual counted as balanced.")
    sim_steps: int = Field(20, ge=0, description="Rollout steps of L_sim (0: wrench only).")
    sim_every: int = Field(5, ge=1, description="Evaluate L_sim every this many iterations.")
    lambda_wrench: float = Field(1.0, ge=0, description="Weight of the wrench residual.")
    lambda_sim: float = Field(10.0, ge=0, description="Weight of L_sim.")
    lambda_anchor: float = Field(0.01, ge=0, description="Weight of the pose anchor.")
    lambda_com: float = Field(0.01, ge=0, description="Weight of the COM shift (per cm^2).")
    anchor_translation_m: float = Field(0.005, gt=0, description="Anchor scale, translation.")
    anchor_rotation_deg: float = Field(3.0, gt=0, description="Anchor scale, rotation.")
    convex_threshold: float = Field(0.05, gt=0, description="CoACD threshold (same as export).")
    max_convex_pieces: int = Field(64, ge=1, description="Most convex pieces (same as export).")


def _source(paths: ScenePaths, options: Options, manifest: Manifest) -> str:
    return latest_state_stage(paths, manifest, None if options.source == "auto" else options.source,
                              candidates=("init", "geomopt"))


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    try:
        src = _source(paths, options, manifest)
    except Exception:
        return []
    return [paths.stage_dir(src), paths.contact_graph]


def _inner_box(mesh) -> tuple[np.ndarray, np.ndarray]:
    """COM bounds: the central 40% of the bounding box along each axis (object frame)."""
    lo, hi = np.asarray(mesh.bounds[0]), np.asarray(mesh.bounds[1])
    return lo + 0.3 * (hi - lo), hi - 0.3 * (hi - lo)


def _restrict_to_subtree(paths: ScenePaths, only: int, parents: Optional[dict[int, int]],
                         params: dict, log: dict) -> None:
    """``--only ID``: ID and its descendants start afresh; the rest keep their last physopt
    result and are fixed."""
    if only not in params:
        raise StageError(f"physopt only={only}: no object {only} (objects: {sorted(params)})")
    previous = read_state(paths.stage_dir("physopt"))
    chosen = descendants(only, parents or {})
    for obj in previous.objects:
        if obj.id in params and obj.id not in chosen:
            p = params[obj.id]
            p["world_from_object"] = obj.pose.copy()
            p["mass_kg"] = obj.mass_kg if obj.mass_kg is not None else p["mass_kg"]
            if obj.com_in_object is not None:
                p["com_in_object"] = np.asarray(obj.com_in_object, dtype=float)
            p["friction"] = obj.friction if obj.friction is not None else p["friction"]
    for i, p in params.items():
        p["movable"] = i in chosen
    log["only"] = {"object": only, "rerun": sorted(chosen)}


def _initial_params(state: SceneState, meshes: dict, pieces: dict, opt: Options) -> dict:
    params = {}
    for obj in state.objects:
        nominal = mass_properties(meshes[obj.id], pieces[obj.id], density_kg_m3=opt.density_kg_m3)
        mass = obj.mass_kg if obj.mass_kg is not None else nominal.mass_kg
        lo, hi = opt.mass_bounds
        params[obj.id] = {
            "world_from_object": obj.pose.copy(),
            "mass_kg": float(np.clip(mass, lo * nominal.mass_kg, hi * nominal.mass_kg)),
            "nominal_mass_kg": nominal.mass_kg,
            "com_in_object": (np.asarray(obj.com_in_object) if obj.com_in_object is not None
                              else nominal.com_in_object.copy()),
            "friction": float(obj.friction if obj.friction is not None else opt.friction_init),
            "com_bounds": _inner_box(meshes[obj.id]),
        }
    return params


def _world_factory(params: dict, pieces: dict, state: SceneState, order: list[int], opt: Options):
    def make_world():
        # objects outside the optimised set are static (mass 0): they must not move
        bodies = [SimBody(i, pieces[i], params[i]["world_from_object"],
                          params[i]["mass_kg"] if params[i].get("movable", True) else 0.0,
                          params[i]["com_in_object"], params[i]["friction"]) for i in order]
        return build_world(bodies, state.support.point, state.support.normal,
                           opt.support_friction, state.gravity)
    return make_world


def _depenetrate(params: dict, pieces: dict, state: SceneState, order: list[int], opt: Options,
                 log: dict) -> None:
    """Separate the collision geometry (children move, parents stay) before anything else."""
    world = _world_factory(params, pieces, state, order, opt)()
    try:
        before = {i: params[i]["world_from_object"] for i in order}
        fixed = depenetrate(world, order, movable={i for i in order if params[i].get("movable", True)})
    finally:
        world.close()
    for i in order:
        shift = float(np.linalg.norm(fixed[i][:3, 3] - before[i][:3, 3]))
        if shift > 1e-4:
            log["objects"][i].append(f"depenetrated by {shift * 1000:.1f} mm")
        params[i]["world_from_object"] = fixed[i]


def _com_over_support(world, oid: int, p: dict, notes: list, rnd: int, opt: Options) -> None:
    """Move a toppling object's COM horizontally towards the centroid of its contacts,
    within the inner half of its bounding box (non-uniform density, bounded)."""
    target = support_centroid(world, oid)
    if target is None:
        return
    pose = p["world_from_object"]
    com_world = pose[:3, :3] @ p["com_in_object"] + pose[:3, 3]
    up = -np.asarray(world_gravity(world), dtype=float)
    up /= np.linalg.norm(up)
    delta = target - com_world
    delta -= up * float(delta @ up)  # horizontal only
    step = pose[:3, :3].T @ delta
    step *= min(1.0, opt.max_com_step_m / max(float(np.linalg.norm(step)), 1e-12))
    new_com = p["com_in_object"] + step
    lo, hi = p["com_bounds"]
    new_com = np.clip(new_com, lo, hi)
    moved = float(np.linalg.norm(new_com - p["com_in_object"]))
    if moved > 1e-4:
        notes.append(f"round {rnd}: COM moved {moved * 1000:.1f} mm towards its support")
        p["com_in_object"] = new_com  # takes effect when the next world is built


def _verify_and_repair(params: dict, pieces: dict, state: SceneState, order: list[int],
                       opt: Options, log: dict, progress) -> dict:
    """PyBullet rounds: check, raise friction of movers, settle; returns final drift."""
    make_world = _world_factory(params, pieces, state, order, opt)

    def moving(d: dict) -> list[int]:
        return [i for i, (t, r) in d.items() if t > opt.tolerance_m or r > opt.tolerance_deg]

    world = make_world()
    try:
        result = drift(world, {i: params[i]["world_from_object"] for i in order},
                       opt.verify_duration_s)
    finally:
        world.close()
    log["rounds"].append({"round": 0, "action": "check", "moving": moving(result),
                          "drift": {str(i): list(v) for i, v in result.items()}})
    for rnd in range(1, opt.max_rounds + 1):
        movers = moving(result)
        if not movers:
            break
        progress(f"verification round {rnd}: {len(movers)} moving", 0.5 + 0.5 * rnd / (opt.max_rounds + 1))
        hi = opt.friction_bounds[1]
        if opt.com_repair:
            world = make_world()
            try:
                for i in movers:
                    _com_over_support(world, i, params[i], log["objects"][i], rnd, opt)
            finally:
                world.close()
        for i in movers:
            if params[i]["friction"] < hi:
                log["objects"][i].append(f"round {rnd}: friction {params[i]['friction']:.2f} -> "
                                         f"{hi:.2f} (moved {result[i][0] * 1000:.1f} mm, "
                                         f"{result[i][1]:.1f} deg)")
                params[i]["friction"] = hi
        world = make_world()
        try:
            start = {i: params[i]["world_from_object"] for i in order}
            settled = settle(world, start, opt.settle_duration_s, opt.settle_reset_steps)
            limit = opt.final_settle_shift_m if rnd == opt.max_rounds else opt.max_settle_shift_m
            for i in order:
                shift = float(np.linalg.norm(settled[i][:3, 3] - start[i][:3, 3]))
                if shift <= limit:
                    if shift > 1e-4:
                        log["objects"][i].append(f"round {rnd}: settled by {shift * 1000:.1f} mm")
                    params[i]["world_from_object"] = settled[i]
                else:
                    log["objects"][i].append(f"round {rnd}: settling moved it "
                                             f"{shift * 1000:.0f} mm; kept in place")
            start = {i: params[i]["world_from_object"] for i in order}
            result = drift(world, start, opt.verify_duration_s)
        finally:
            world.close()
        log["rounds"].append({"round": rnd, "action": "friction+settle", "moving": moving(result),
                              "drift": {str(i): list(v) for i, v in result.items()}})
    return result


def run(ctx: StageContext) -> dict:
    paths, opt = ctx.paths, ctx.options
    src = _source(paths, opt, ctx.manifest)
    # with the effects kept in the scene's model (COM, friction, table: r2s.diagnose.model)
    state = corrected_state(read_state(paths.stage_dir(src)), ctx.manifest.model)
    meshes = {o.id: welded(load_mesh(paths.stage_dir(src) / o.mesh)) for o in state.objects}
    cache = paths.root / ".cache" / "convex"
    pieces = {}
    for k, o in enumerate(state.objects):
        ctx.progress(f"object {o.id}: collision pieces", 0.1 * k / max(len(state.objects), 1))
        pieces[o.id] = cached_convex_decomposition(meshes[o.id], cache, opt.convex_threshold,
                                                   opt.max_convex_pieces)
    params = _initial_params(state, meshes, pieces, opt)
    parents = parents_from_graph(paths.contact_graph)
    heights = {o.id: float(np.min((o.pose[:3, :3] @ meshes[o.id].vertices.T).T[:, 2]
                                  + o.pose[2, 3])) for o in state.objects}
    order = order_root_to_leaves([o.id for o in state.objects], parents, heights)
    log: dict = {"source": src, "order": order, "parents": parents, "objects": {i: [] for i in order},
                 "rounds": []}
    if opt.only is not None:
        _restrict_to_subtree(paths, opt.only, parents, params, log)
        order_free = [i for i in order if params[i]["movable"]]
    else:
        order_free = order

    ctx.progress("depenetration", 0.1)
    _depenetrate(params, pieces, state, order, opt, log)
    if opt.use_diffsim:
        try:
            from r2s.physopt.object_opt import optimise_objects
        except ModuleNotFoundError:
            optimise_objects = None
        if optimise_objects is not None:
            optimise_objects(params, meshes, state, order_free, parents, opt, log, ctx.progress)

    final = _verify_and_repair(params, pieces, state, order, opt, log, ctx.progress)
    moving = [i for i, (t, r) in final.items() if t > opt.tolerance_m or r > opt.tolerance_deg]

    (ctx.out_dir / "meshes").mkdir()
    objects = []
    for o in state.objects:
        p = params[o.id]
        shutil.copyfile(paths.stage_dir(src) / o.mesh, ctx.out_dir / "meshes" / f"{o.id}.glb")
        data = o.model_dump()
        data.update(mesh=f"meshes/{o.id}.glb", world_from_object=p["world_from_object"].tolist(),
                    mass_kg=p["mass_kg"], com_in_object=[float(x) for x in p["com_in_object"]],
                    friction=p["friction"], physopt_drift_m=final[o.id][0],
                    physopt_drift_deg=final[o.id][1])
        objects.append(data)
    out_state = SceneState(stage="physopt", gravity=state.gravity,
                           support=state.support.model_copy(update={"friction": opt.support_friction}),
                           objects=objects)
    write_state(ctx.out_dir, out_state)
    atomic_write_json(ctx.out_dir / "log.json", {**log, "objects": {str(k): v for k, v in log["objects"].items()}})
    ctx.progress("done", 1.0)
    return {"source": src, "objects": len(objects), "still_moving": len(moving),
            "rounds": len(log["rounds"]) - 1}


STAGE = StageSpec("physopt", Options, inputs, run, uses_model=frozenset({"state"}))
