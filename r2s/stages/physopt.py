"""The ``physopt`` stage: make the reconstructed scene stay at rest in simulation.

Objects are optimised root to leaves along the contact graph through the differentiable
simulator (pose, COM inside the shape, friction within bounds), then the whole scene is
checked in PyBullet with the export's collision geometry and what still moves is repaired,
first within the observation tolerance of where each object was seen (docs/physopt.md).
Every change is recorded per object with its reason in ``physopt/log.json``; objects left
beyond the tolerance are flagged.

The algorithm lives in :mod:`r2s.physopt`; this module reads, calls it and writes."""

from __future__ import annotations

import copy
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional

import numpy as np
from pydantic import Field

from r2s.errors import StageError
from r2s.geometry.collision_trim import MAX_SPLIT_DEPTH, TrimReport, trim_scene_pieces
from r2s.geometry.convex_cache import cached_convex_decomposition
from r2s.geometry.convex_params import DEFAULT_CONVEX, ConvexMethod, ConvexParams
from r2s.io.atomic import atomic_write_json
from r2s.io.latest_state import latest_state_stage
from r2s.io.manifest import Manifest
from r2s.io.input_scene import InputScene, load_input
from r2s.io.mesh_io import load_mesh, welded
from r2s.io.paths import (INIT_ALTERNATES_DIR, PHYSOPT_COLLISION_DIR, PHYSOPT_LOG_FILE,
                          STATE_FILE, ScenePaths)
from r2s.io.pieces_file import write_pieces
from r2s.io.state import ObjectState, SceneState, read_state, write_state
from r2s.physopt.hierarchy import (descendants, lowest_points_m, order_root_to_leaves,
                                   parents_from_graph)
from r2s.physopt.observation_bound import OBSERVATION_FLAG_KEY, SEEN_POSE_KEY, seen_poses
from r2s.physopt.params import initial_params, keep_previous
from r2s.physopt.piece_overlap import OverlapShave, shave_overlaps
from r2s.physopt.repair import world_factory
from r2s.physopt.solve import (Solved, finish_scene, give_props, physopt_provenance,
                               prepare_scene)
from r2s.physopt.swap_choice import (MOVED_DEG, MOVED_M, SolutionSummary, prefer_propped,
                                    prefer_swapped, swap_candidates)
from r2s.metrics.observation import observe_scene, render_objects, silhouette_iou
from r2s.physopt.settings import DiffsimSettings, RepairSettings
from r2s.physopt.support_prop import depth_hidden, fell
from r2s.physical.provenance import user_entries
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.scene_model import corrected_input, corrected_state
from r2s.stages.refit_poses import refit_poses


class Options(StageOptions, RepairSettings, DiffsimSettings):
    """Where to start and the priors; the rounds' and the diffsim step's settings are
    inherited (:mod:`r2s.physopt.settings`)."""

    source: Literal["auto", "init", "geomopt"] = Field(
        "auto", description="State to start from (auto: geomopt if it ran, else init).")
    density_kg_m3: Optional[float] = Field(
        None, gt=0, description="Nominal density for the mass prior (unset: by label, "
                                "r2s/physical/density_table.py; input/objects.json's "
                                "mass_kg or density_kg_m3 win).")
    mass_bounds: tuple[float, float] = Field(
        (0.5, 2.0), description="Mass bounds as factors of volume x density.")
    friction_init: float = Field(0.6, description="Starting per-body friction.")
    only: Optional[int] = Field(None, description="Rerun only this object and the objects it "
                                                   "supports; the rest keep their last physopt "
                                                   "result and stay fixed.")
    use_diffsim: bool = Field(True, description="Optimise each object through the torch "
                                                "simulator before the PyBullet check.")
    diffsim_guard: bool = Field(True, description="Put a completed object the torch step "
                                                  "leaves moving in PyBullet's check back to "
                                                  "its pose and COM before the step, where it "
                                                  "moves much less there "
                                                  "(physopt/diffsim_guard.py).")
    convex_method: ConvexMethod = Field(DEFAULT_CONVEX.method,
                                        description="Convex decomposition: vhacd or coacd "
                                                    "(same as export).")
    convex_threshold: float = Field(DEFAULT_CONVEX.threshold, gt=0,
                                    description="CoACD threshold, convex_method=coacd only "
                                                "(same as export).")
    max_convex_pieces: int = Field(DEFAULT_CONVEX.max_pieces, ge=1,
                                   description="Most convex pieces (same as export).")
    trim_collision: Literal["completed", "all", "off"] = Field(
        "completed", description="Rebuild the convex pieces a neighbour's visual mesh reaches "
                                 "into from the object's own surface "
                                 "(r2s/geometry/collision_trim.py): of completed objects (and "
                                 "of priors whose surface init moved out of another's), of "
                                 "all, or of none; export uses the pieces physopt checked.")
    shave_overlaps: bool = Field(
        True, description="Cut the convex pieces of an object where they overlap the pieces of "
                          "an object it rests on or beside (the later one in the support order) "
                          "or reach below the table, so the depenetration does not push it off "
                          "where it was seen (r2s/physopt/piece_overlap.py).")
    trim_split_levels: int = Field(
        MAX_SPLIT_DEPTH, ge=0, le=8, description="Most levels a trimmed piece is split at its "
                                                 "intruders (up to 2**levels pieces; "
                                                 "docs/realistic.md measured 5 on the seed "
                                                 "demo).")
    swap_to_completion: bool = Field(
        True, description="Where a prior object, or a completed one with a second "
                          "completion lying across others, can be made to rest only beyond "
                          "the observation tolerance, solve the scene again with init's "
                          "alternative shape of it in its place (init/alternates/) and keep "
                          "that solution if it leaves no more objects flagged or still moving "
                          "and its silhouette IoU is higher by >= 0.01 "
                          "(physopt/swap_choice.py). A prior that the first solve moved or "
                          "turned beyond swap_moved_m / swap_moved_deg is tried the same way.")
    swap_moved_m: float = Field(
        MOVED_M, gt=0, description="A prior the first solve left farther than this from "
                                   "where it was seen is solved again with its completion, m.")
    swap_moved_deg: float = Field(
        MOVED_DEG, gt=0, description="... or turned more than this, degrees.")


def _source(paths: ScenePaths, options: Options, manifest: Manifest) -> str:
    return latest_state_stage(paths, manifest, None if options.source == "auto" else options.source,
                              candidates=("init", "geomopt"))


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    try:
        src = _source(paths, options, manifest)
    except Exception:
        return []
    # objects.json: a user's mass_kg / density_kg_m3 / friction fixes those parameters
    return [paths.stage_dir(src), paths.contact_graph, paths.stage_dir("init"), paths.objects]


def run(ctx: StageContext) -> dict:
    paths, opt = ctx.paths, ctx.options
    src = _source(paths, opt, ctx.manifest)
    # with the effects kept in the scene's model (COM, friction, table: r2s.scene_model)
    state = corrected_state(read_state(paths.stage_dir(src)), ctx.manifest.model)
    meshes = {o.id: welded(load_mesh(paths.stage_dir(src) / o.mesh)) for o in state.objects}
    convex = ConvexParams(opt.convex_threshold, opt.max_convex_pieces, opt.convex_method)
    parents = parents_from_graph(paths.contact_graph)
    order = order_root_to_leaves([o.id for o in state.objects], parents,
                                 lowest_points_m(state.objects, meshes))
    pieces = _collision_pieces(ctx, state, meshes, convex, order)
    params = initial_params(state, meshes, pieces.pieces, opt.density_kg_m3, opt.mass_bounds,
                            opt.friction_init, user_entries(paths.root))
    log = _new_log(src, order, parents, pieces)
    if opt.only is not None:
        if opt.only not in params:
            raise StageError(f"physopt only={opt.only}: no object {opt.only} "
                             f"(objects: {sorted(params)})")
        rerun = descendants(opt.only, parents or {})
        previous = read_state(paths.stage_dir("physopt"))
        swapped = [o.id for o in previous.objects if getattr(o, SEEN_POSE_KEY, None)]
        if swapped:
            raise StageError(f"physopt only={opt.only}: objects {swapped} were swapped for "
                             f"their completions in the last run; rerun physopt for the "
                             f"whole scene")
        params = keep_previous(params, previous, rerun)
        log["only"] = {"object": opt.only, "rerun": sorted(rerun)}

    seen = seen_poses(paths, state, ctx.manifest.model)
    view = _view(ctx)
    hidden = (depth_hidden(view.depth_m, view.camera.K, view.camera.world_from_camera)
              if view is not None else None)
    solved, log = _solve_props_checked(ctx, params, pieces.pieces, meshes, state, order, seen,
                                       log, parents, hidden, view)
    mesh_files = {o.id: paths.stage_dir(src) / o.mesh for o in state.objects}
    if opt.swap_to_completion and opt.only is None:
        swapped = _solve_with_completions(ctx, src, state, meshes, parents, seen,
                                          convex, solved, log, view, hidden)
        if swapped is not None:
            state, pieces, solved, log, mesh_files = swapped
    params, final, flags = solved.params, solved.drift, solved.flags
    _write(ctx, mesh_files, state, params, final, log, flags)
    for i, object_pieces in pieces.pieces.items():
        write_pieces(ctx.out_dir / PHYSOPT_COLLISION_DIR / f"{i}.npz", object_pieces,
                     convex.as_kwargs())
    ctx.progress("done", 1.0)
    return {"source": src, "objects": len(state.objects),
            "still_moving": len(opt.moving(final)), "rounds": len(log["rounds"]) - 1,
            "flagged_objects": len(flags),
            "warnings": ([f"object {i}: {reason}" for i, reason in sorted(flags.items())]
                         + _not_at_rest(final, opt))}


def _view(ctx: StageContext) -> Optional[InputScene]:
    """The scene's input (with the effects in the scene's model); None without ``input/``."""
    if not ctx.paths.input.is_dir():
        return None
    return corrected_input(load_input(ctx.paths.root), ctx.manifest.model)


def _solve_props_checked(ctx: StageContext, params: dict, pieces: dict, meshes: dict,
                         state: SceneState, order: list[int], seen: dict, log: dict,
                         parents: dict, hidden, view: Optional[InputScene]
                         ) -> tuple[Solved, dict]:
    """The physopt pass (:func:`prepare_scene`, :func:`finish_scene`) without the hidden
    support props; where that leaves an object that fell off another in the first check
    flagged or still moving (:func:`_fallen_and_left`), the repairs run again from the same
    prepared scene with the props (:func:`give_props`), and of the two the solution
    :func:`prefer_propped` prefers is returned with its log; its collision pieces are left
    in ``pieces`` (in place). The log records the choice (``support_props_choice``)."""
    opt = ctx.options
    make_world = world_factory(pieces, state, order, opt)
    prepared = prepare_scene(make_world, pieces, params, meshes, state, order, opt, log,
                             ctx.progress)
    propped_pieces, propped_log = dict(pieces), copy.deepcopy(log)
    solved = finish_scene(make_world, prepared, meshes, state, order, seen, opt, log,
                          ctx.progress)
    if not opt.support_props or not _fallen_and_left(log, parents or {}, solved, opt):
        return solved, log
    ctx.progress("solving again with hidden props under what fell", 0.6)
    propped_world = world_factory(propped_pieces, state, order, opt)
    propped_world.checked.update(make_world.checked)  # the same pieces until props are added
    give_props(propped_world, propped_pieces, prepared.params, [o.id for o in state.objects],
               parents, state, opt, propped_log, hidden)
    if not propped_log.get("support_props"):
        return solved, log
    propped = finish_scene(propped_world, prepared, meshes, state, order, seen, opt,
                           propped_log, ctx.progress)
    summaries = [_observed_summary(view, meshes, s, opt) for s in (solved, propped)]
    keep = prefer_propped(*summaries)
    record = {"props": propped_log["support_props"], "kept": keep,
              **{f"{k}_{name}": getattr(summary, k)
                 for name, summary in zip(("without", "with"), summaries)
                 for k in ("flagged", "moving", "pooled_iou", "ucd_mm")}}
    if not keep:
        log["support_props_choice"] = record
        return solved, log
    propped_log["support_props_choice"] = record
    pieces.clear()
    pieces.update(propped_pieces)
    return propped, propped_log


def _fallen_and_left(log: dict, parents: dict, solved: Solved, opt: Options) -> list[int]:
    """The objects resting on another object that fell in the solve's first check
    (:func:`r2s.physopt.support_prop.fell`; ``log["rounds"][0]``) and end it flagged or
    still moving: what a hidden prop under them may hold where seen."""
    first = log["rounds"][0]["drift"] if log.get("rounds") else {}
    left = set(solved.flags) | set(opt.moving(solved.drift))
    return sorted(i for i in left if parents.get(i, 0) != 0 and str(i) in first
                  and fell(first[str(i)], opt.judge_translation_m))


def _not_at_rest(final: dict[int, tuple[float, float]], opt: Options) -> list[str]:
    """One line per object that still fails the judge's criterion in physopt's last check
    (``final``: id -> (COM translation m, rotation deg) over the check): the scene does not
    rest, and the user is told so rather than finding out in evaluate."""
    return [f"object {i}: does not rest in physopt's last check (moved {1000 * t:.0f} mm, "
            f"turned {r:.0f} deg over {opt.verify_duration_s:g} s)"
            for i, (t, r) in sorted(final.items())
            if t >= opt.judge_translation_m or r >= opt.judge_rotation_deg]


def _new_log(src: str, order: list[int], parents: dict, pieces: "_Pieces") -> dict:
    """physopt/log.json's record before the solve."""
    return {"source": src, "order": order, "parents": parents,
            "objects": {i: [] for i in order}, "rounds": [],
            "collision_trim": _trim_log(pieces.reports),
            "collision_shave": _shave_log(pieces.shaved)}


def _solve_with_completions(ctx: StageContext, src: str, state: SceneState, meshes: dict,
                            parents: dict, seen: dict[int, np.ndarray],
                            convex: ConvexParams, solved: Solved, log: dict,
                            view: Optional[InputScene] = None, hidden=None
                            ) -> Optional[tuple]:
    """Solve again with init's alternative shape (``init/alternates/``) in place of every
    object :func:`r2s.physopt.swap_choice.swap_candidates` names (flagged, or a prior moved
    or turned visibly) that has one: a prior's completion, or a completed object's second
    completion, lying across others or not, to the table, or deepened behind a face
    (``alternate``: its kind, r2s/stages/init.py ``_save_alternates``; ``seen``: id -> where each
    object was seen, for the first solve);
    (state, pieces, solved, log, mesh files) of that solution when
    :func:`r2s.physopt.swap_choice.prefer_swapped` prefers it, else None (``log`` then
    records the attempt). A swapped object is seen where its completion was (its state
    carries :data:`SEEN_POSE_KEY`, which export measures the displacement from). The
    support tree and (when ``src`` is geomopt) geomopt's poses are made again for the new
    shapes first (:mod:`r2s.stages.refit_poses`). ``view``: the scene's input (None:
    none), which scores both solutions; ``hidden``: for the second solve's props."""
    paths, opt = ctx.paths, ctx.options
    alt_dir = paths.stage_dir("init") / INIT_ALTERNATES_DIR
    if not (alt_dir / STATE_FILE).is_file():
        return None
    alternates = corrected_state(read_state(alt_dir), ctx.manifest.model)
    usable = {o.id: o for o in alternates.objects if o.id in meshes
              and (state.object(o.id).source == "prior" or _second_completion(o))}
    why = swap_candidates(solved.flags, solved.displacement, set(usable),
                          {i for i in usable if state.object(i).source == "prior"},
                          parents or {}, opt.swap_moved_m, opt.swap_moved_deg)
    swap = {i: usable[i] for i in why}
    if not swap:
        return None
    ctx.progress(f"objects {sorted(swap)}: solving again with their completions", 0.6)
    refit_geomopt = src == "geomopt"
    objects = [swap[o.id].model_copy(update={"label": o.label,
                                             SEEN_POSE_KEY: swap[o.id].world_from_object})
               if o.id in swap else _at_seen(o, seen) if refit_geomopt else o
               for o in state.objects]
    state2 = state.model_copy(update={"objects": objects})
    files = {o.id: (alt_dir / o.mesh if o.id in swap else paths.stage_dir(src) / o.mesh)
             for o in state2.objects}
    meshes2 = {**meshes, **{i: welded(load_mesh(files[i])) for i in swap}}
    state2, parents2, refit = refit_poses(ctx, state2, files, with_geomopt=refit_geomopt)
    order2 = order_root_to_leaves([o.id for o in state2.objects], parents2,
                                  lowest_points_m(state2.objects, meshes2))
    pieces2 = _collision_pieces(ctx, state2, meshes2, convex, order2)
    params2 = initial_params(state2, meshes2, pieces2.pieces, opt.density_kg_m3,
                             opt.mass_bounds, opt.friction_init, user_entries(paths.root))
    seen2 = {**seen, **{i: o.pose for i, o in swap.items()}}
    log2 = _new_log(src, order2, parents2, pieces2)
    solved2, log2 = _solve_props_checked(ctx, params2, pieces2.pieces, meshes2, state2, order2,
                                         seen2, log2, parents2, hidden, view)
    before = SolutionSummary(len(solved.flags), len(opt.moving(solved.drift)),
                             _pooled_iou(view, meshes, solved.params))
    after = SolutionSummary(len(solved2.flags), len(opt.moving(solved2.drift)),
                            _pooled_iou(view, meshes2, solved2.params))
    keep = prefer_swapped(before, after, priors_swapped=any(
        state.object(i).source == "prior" for i in swap))
    record = {"ids": sorted(swap), "why": {str(i): w for i, w in sorted(why.items())},
              "shapes": {str(i): (o.alternate if _second_completion(o) else "completion")
                         for i, o in sorted(swap.items())},
              "flagged_before": sorted(solved.flags),
              "flagged_after": sorted(solved2.flags),
              "moving_before": sorted(opt.moving(solved.drift)),
              "moving_after": sorted(opt.moving(solved2.drift)),
              "pooled_iou_before": before.pooled_iou,
              "pooled_iou_after": after.pooled_iou, "refit": refit, "kept": keep}
    if "support_props_choice" in log:  # the first solve's, which a kept swap's log drops
        record["first_solve_support_props_choice"] = log["support_props_choice"]
    if not keep:
        log["swap_to_completion"] = record
        return None
    log2["swap_to_completion"] = record
    return state2, pieces2, solved2, log2, files


def _at_seen(o: ObjectState, seen: dict[int, np.ndarray]) -> ObjectState:
    """``o`` back at the pose where init saw it (``seen``: id -> (4, 4)), from where geomopt
    runs again with the swapped shapes: the second solve then starts as ``r2s run`` would
    have, had init chosen them. On the seed demo it is then the very solve of
    ``init.prior_choice=completion`` (IoU 0.950); from geomopt's poses of the others and
    with welded meshes it ended elsewhere (0.926, the lemon 0.70 against 0.87)."""
    if o.id not in seen:
        return o
    return o.model_copy(update={"world_from_object": np.asarray(seen[o.id]).tolist()})


def _second_completion(o: ObjectState) -> bool:
    """Whether init's alternative ``o`` is a completed object's second completion: init
    names the kind of those alone in ``alternate`` (lying across others or not,
    r2s/stages/init.py ``_partition_hidden``; reaching the table where the first stands on
    others, ``_table_alternates``), a kept prior's completion carries none."""
    return getattr(o, "alternate", None) is not None


def _observed_summary(view: Optional[InputScene], meshes: dict, solved: Solved,
                      opt: Options) -> SolutionSummary:
    """What :func:`prefer_propped` compares of a solution: objects flagged and still moving,
    and against the view (:func:`r2s.metrics.observation.observe_scene`, as evaluate
    measures it) the pooled silhouette IoU (4 digits) and the mean over the objects of
    their UCD (mm, 2 digits); both None without a view."""
    flagged, moving = len(solved.flags), len(opt.moving(solved.drift))
    if view is None:
        return SolutionSummary(flagged, moving, None)
    ids = sorted(solved.params)
    cam = view.camera
    seen = observe_scene([meshes[i].copy().apply_transform(solved.params[i].world_from_object)
                          for i in ids], ids, cam.K, cam.world_from_camera, view.depth_m,
                         view.masks)
    ucds = [o.ucd_mm for o in seen.objects if o.ucd_mm is not None]
    return SolutionSummary(flagged, moving,
                           None if seen.pooled_iou is None else round(float(seen.pooled_iou), 4),
                           round(float(np.mean(ucds)), 2) if ucds else None)


def _pooled_iou(view: Optional[InputScene], meshes: dict, params: dict) -> Optional[float]:
    """Pooled silhouette IoU of a solution (meshes at their solved poses) against the
    view's masks, rounded to 4 digits; None without a view (a scene without input/)."""
    if view is None:
        return None
    ids = sorted(params)
    world = [meshes[i].copy().apply_transform(params[i].world_from_object) for i in ids]
    cam = view.camera
    rendered = render_objects(world, ids, cam.K, cam.world_from_camera, cam.width, cam.height)
    pooled = silhouette_iou(rendered.ids, view.masks, ids)[1]
    return None if pooled is None else round(float(pooled), 4)


@dataclass(frozen=True)
class _Pieces:
    """pieces: id -> convex pieces (object frame) the checks use and export reuses;
    reports: id -> what trimming against the neighbours did (empty when off)."""

    pieces: dict[int, list]
    reports: dict[int, TrimReport]
    shaved: dict[int, OverlapShave]


def _collision_pieces(ctx: StageContext, state: SceneState, meshes: dict,
                      convex: ConvexParams, order: list[int]) -> _Pieces:
    """Each object's convex decomposition (cached), trimmed where neighbours reach in, then
    cut where pieces of two objects still overlap (``order``: root to leaves)."""
    poses = {o.id: np.asarray(o.pose) for o in state.objects}
    trimmed = _trimmed_pieces(ctx, state, meshes, poses, convex)
    if not ctx.options.shave_overlaps:
        return trimmed
    ctx.progress("collision pieces cut where they overlap", 0.15)
    support = (np.asarray(state.support.point), np.asarray(state.support.normal))
    cut, shaved = shave_overlaps(trimmed.pieces, meshes, poses, order, support)
    return _Pieces(cut, trimmed.reports, shaved)


def _trimmed_pieces(ctx: StageContext, state: SceneState, meshes: dict, poses: dict,
                    convex: ConvexParams) -> _Pieces:
    """Each object's convex decomposition (cached), trimmed where neighbours reach in
    (poses: id -> (4, 4) world_from_object)."""
    pieces = {}
    for k, o in enumerate(state.objects):
        ctx.progress(f"object {o.id}: collision pieces", 0.1 * k / max(len(state.objects), 1))
        pieces[o.id] = cached_convex_decomposition(meshes[o.id], ctx.paths.convex_cache,
                                                   **convex.as_kwargs())
    mode = ctx.options.trim_collision
    if mode == "off":
        return _Pieces(pieces, {}, {})
    ctx.progress("collision pieces against the neighbours", 0.1)
    only = None if mode == "all" else trimmed_objects(state)
    trimmed, reports = trim_scene_pieces(pieces, meshes, poses, only=only,
                                         max_split_depth=ctx.options.trim_split_levels)
    return _Pieces(trimmed, reports, {})


def trimmed_objects(state: SceneState) -> set[int]:
    """Ids whose pieces ``trim_collision=completed`` (the default) trims: the completions,
    and the priors dented at init (:func:`_yielded_at_init`)."""
    return {o.id for o in state.objects
            if o.source in ("completed", "silhouette") or _yielded_at_init(o)}


def _yielded_at_init(o: ObjectState) -> bool:
    """Whether init moved part of this prior's surface onto another's (its
    ``hidden_overlap`` record): the prior is dented there, and its convex pieces, like a
    completion's, span the dent."""
    record = getattr(o, "hidden_overlap", None) or {}
    return int(record.get("moved_vertices", 0)) > 0


def _trim_log(reports: dict[int, TrimReport]) -> dict[str, dict]:
    """physopt/log.json's record of the objects whose pieces were trimmed (depths in mm)."""
    return {str(i): {"depth_before_mm": round(1000 * r.depth_before_m, 2),
                     "depth_after_mm": round(1000 * r.depth_after_m, 2),
                     "pieces_before": r.pieces_before, "pieces_after": r.pieces_after}
            for i, r in sorted(reports.items()) if r.pieces_before != r.pieces_after
            or r.depth_before_m != r.depth_after_m}


def _shave_log(shaved: dict[int, OverlapShave]) -> dict[str, dict]:
    """physopt/log.json's record of the objects whose pieces were cut (depths in mm, as
    Bullet reports them, its margins included)."""
    return {str(i): {"overlap_before_mm": round(1000 * r.depth_before_m, 2),
                     "overlap_after_mm": round(1000 * r.depth_after_m, 2),
                     "cuts": r.cuts} for i, r in sorted(shaved.items())}


def _write(ctx: StageContext, mesh_files: dict[int, Path], state: SceneState, params: dict,
           final: dict, log: dict, flags: dict[int, str]) -> None:
    """physopt/: the state with the tuned parameters, the meshes (copied from
    ``mesh_files``: id -> the mesh the solve used), log.json."""
    (ctx.out_dir / "meshes").mkdir()
    objects = []
    for o in state.objects:
        p = params[o.id]
        shutil.copyfile(mesh_files[o.id], ctx.out_dir / "meshes" / f"{o.id}.glb")
        data = o.model_dump()
        data.update(mesh=f"meshes/{o.id}.glb", world_from_object=p.world_from_object.tolist(),
                    mass_kg=p.mass_kg, com_in_object=[float(x) for x in p.com_in_object],
                    friction=p.friction,
                    provenance=physopt_provenance(p, log["objects"][o.id],
                                                  ctx.options.friction_init,
                                                  ctx.options.friction_bounds),
                    physopt_drift_m=final[o.id][0],
                    physopt_drift_deg=final[o.id][1])
        if o.id in flags:
            data[OBSERVATION_FLAG_KEY] = flags[o.id]
        objects.append(data)
    support = state.support.model_copy(update={"friction": ctx.options.support_friction})
    write_state(ctx.out_dir, SceneState(stage="physopt", gravity=state.gravity, support=support,
                                        objects=objects))
    atomic_write_json(ctx.out_dir / PHYSOPT_LOG_FILE,
                      {**log, "objects": {str(k): v for k, v in log["objects"].items()}})


STAGE = StageSpec("physopt", Options, inputs, run, uses_model=frozenset({"state"}))
