"""Stage ``geomopt``: geometry-aware pose optimisation (paper stage c, first half).

Reads ``init/`` (poses, meshes) and ``graph/contact_graph.json``; writes

* ``geomopt/sdf/<id>.npy`` + ``<id>.json``: each object's SDF in its own frame
  (:mod:`r2s.io.sdf_io`); reused from the previous run when mesh and settings match;
* ``geomopt/state.json`` + ``meshes/<id>.glb``: init's state with optimised poses;
* ``geomopt/loss.json``: the loss terms per iteration, the contact state before/after and
  the share of each object's samples in space the camera saw empty (``free_space``);
* ``geomopt/loss.png``: a plot of the loss.
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path
from typing import Optional

import numpy as np
from pydantic import Field, field_validator

from r2s.scene_model import corrected_camera, corrected_input
from r2s.errors import InputError, StageError
from r2s.geometry.sdf import SdfGrid, compute_sdf
from r2s.geomopt.free_space import ObservedView, observed_view
from r2s.geomopt.optimise import GeomParams, optimise_poses
from r2s.geomopt.plot import loss_plot
from r2s.geomopt.problem import build_problem
from r2s.io.atomic import atomic_write_bytes, atomic_write_json
from r2s.io.input_scene import load_camera, load_input
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import GEOMOPT_LOSS_FILE, ScenePaths
from r2s.io.sdf_io import load_sdf, read_sdf_meta, save_sdf
from r2s.io.state import SceneState, read_state, write_state
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.stages.graph import read_contact_graph
from r2s.io.manifest import Manifest
from r2s.io.latest_state import latest_state_stage

SOURCE_STAGES = ("init",)
SDF_PADDING_FRACTION = 0.1


class Options(StageOptions):
    iterations: int = Field(300, ge=1, description="most Adam iterations")
    learning_rate_m: float = Field(1e-3, gt=0, description="initial step (m); decays to 1 %")
    lambda_penetration: float = Field(1000.0, ge=0, description="weight of the non-penetration terms")
    lambda_contact: float = Field(1.0, ge=0, description="weight of the TopK-min support contact term")
    lambda_anchor: float = Field(1.0, ge=0, description="weight of the pose anchor to the init pose")
    sigma_translation_m: float = Field(0.02, gt=0, description="translation that costs 1 in the anchor (m)")
    sigma_rotation_m: float = Field(0.01, gt=0, description="rotation, as displacement of the farthest point, that costs 1 (m)")
    anchor_sideways_ratio: float = Field(4.0, ge=1, description="image-space anchor: a move across the camera's viewing ray costs this many times more per metre than one along it (1: isotropic; docs/observation.md)")
    top_k: int = Field(10, ge=1, description="K of the TopK-min contact term")
    samples: int = Field(2000, ge=50, description="surface samples per object")
    sdf_resolution: int = Field(128, ge=8, le=512, description="SDF voxels per axis (the most per axis when sdf_voxel_size_m is set)")
    sdf_voxel_size_m: Optional[float] = Field(0.0015, gt=0, description="SDF voxels of about this size, at most sdf_resolution and at least 16 per axis (small objects get small grids); None: always sdf_resolution")
    all_supporters: bool = Field(True, description="contact term for extra supporters too (not only the tree parent)")
    min_support_likelihood: float = Field(0.25, ge=0.0, le=1.0, description="a support edge whose likelihood H is under this gets no contact term: the graph found nothing under that child (the table far below a wedged ball; 0.25 is the graph's own bar for a supporter); 0: every edge")
    contact_rotates: bool = Field(False, description="let the contact term rotate objects and move them sideways (default: only along gravity)")
    support_vertical: bool = Field(True, description="penetration between a child and its supporter moves them along gravity only")
    seed: int = Field(0, description="seed of the surface samples")
    lambda_free_space: float = Field(0.0, ge=0, description="weight of the free-space term: samples in space the camera saw empty are pulled towards their mask, in a pass after the optimisation (0: off, the default: docs/observation.md; 30 was tried)")
    free_space_band_px: float = Field(2.0, ge=0, description="pixels around an object's mask where its samples never violate free space")
    free_space_margin_m: float = Field(0.015, ge=0, description="a sample violates free space when the observed depth is at least this far behind it (m)")

    @field_validator("sdf_voxel_size_m", mode="before")
    @classmethod
    def _none_text(cls, value):
        """``--set sdf_voxel_size_m=none`` on the command line means None."""
        if isinstance(value, str) and value.strip().lower() in ("none", "null", ""):
            return None
        return value

    def params(self) -> GeomParams:
        return GeomParams(iterations=self.iterations, lr_translation_m=self.learning_rate_m,
                          lambda_penetration=self.lambda_penetration,
                          lambda_contact=self.lambda_contact, lambda_anchor=self.lambda_anchor,
                          sigma_translation_m=self.sigma_translation_m,
                          sigma_rotation_m=self.sigma_rotation_m, top_k=self.top_k,
                          anchor_sideways_ratio=self.anchor_sideways_ratio,
                          contact_rotates=self.contact_rotates,
                          support_vertical=self.support_vertical,
                          lambda_free_space=self.lambda_free_space,
                          free_space_band_px=self.free_space_band_px,
                          free_space_margin_m=self.free_space_margin_m)


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    found = [paths.stage_dir("init"), paths.stage_dir("graph")]
    if options.lambda_free_space > 0:
        found += [paths.camera, paths.depth_png, paths.depth_npy, paths.masks]
    elif options.anchor_sideways_ratio != 1.0:
        found += [paths.camera]
    return found


def solve_poses(paths: ScenePaths, model: dict, state: SceneState, meshes: list, grids: list,
                graph, opts: Options, progress) -> tuple:
    """geomopt's optimisation of ``state``'s poses (meshes and SDF grids per object, in the
    state's order, object frame) with ``graph``; (problem, result) of
    :func:`r2s.geomopt.optimise.optimise_poses`. ``paths`` / ``model``: where the view and
    the camera are read from, as the scene's model corrects them (physopt's solve with
    init's completions runs it too)."""
    ids = [o.id for o in state.objects]
    problem = build_problem(ids, meshes, np.stack([o.pose for o in state.objects]), grids, graph,
                            np.asarray(state.support.point), np.asarray(state.support.normal),
                            samples=opts.samples, seed=opts.seed,
                            all_supporters=opts.all_supporters, gravity=np.asarray(state.gravity),
                            min_support_likelihood=opts.min_support_likelihood)
    if opts.lambda_free_space > 0:
        problem.view = _view(paths, ids, model)
    if opts.anchor_sideways_ratio != 1.0 and paths.camera.is_file():
        camera = corrected_camera(load_camera(paths.camera)[0], model)
        problem.camera_position_m = np.asarray(camera.world_from_camera, dtype=float)[:3, 3]
    return problem, optimise_poses(problem, opts.params(), progress)


def pose_moves(problem, result) -> tuple[np.ndarray, np.ndarray]:
    """(M,) how far each object's origin moved (mm) and (M,) how far it turned (deg) from
    ``problem``'s start poses to ``result``'s (:func:`solve_poses`)."""
    shift_mm = 1000.0 * np.linalg.norm(result.world_from_object[:, :3, 3]
                                       - problem.init_world_from_object[:, :3, 3], axis=1)
    return shift_mm, np.degrees(np.linalg.norm(result.omega, axis=1))


def _view(paths: ScenePaths, ids: list[int], model: dict) -> Optional[ObservedView]:
    """The input view (as the scene's model corrects it) for the free-space term; None for
    a scene without input/ (a state built by hand)."""
    if not paths.input.is_dir():
        return None
    scene = corrected_input(load_input(paths.root), model)
    return observed_view(scene.camera.K, scene.camera.world_from_camera, scene.depth_m,
                         scene.masks, ids)


def _sdf_settings(resolution: int, voxel_size_m: Optional[float]) -> dict:
    return {"resolution": resolution, "voxel_size_m": voxel_size_m,
            "padding_fraction": SDF_PADDING_FRACTION, "method": "band3+cpt"}


def sdf_of_file(folder: Path, obj_id: int, mesh, mesh_bytes: bytes, opts: Options
                ) -> tuple[SdfGrid, str, bool]:
    """The SDF of object ``obj_id``'s mesh (loaded from ``mesh_bytes``, object frame) with
    ``opts``'s grid settings: the one saved in ``folder`` (a geomopt run's ``sdf/``) when it
    was made from the same bytes with the same settings, else computed. Returns the grid,
    the bytes' sha256 and whether it was reused."""
    sha = hashlib.sha256(mesh_bytes).hexdigest()
    settings = _sdf_settings(opts.sdf_resolution, opts.sdf_voxel_size_m)
    grid = _cached_sdf(folder, obj_id, sha, settings)
    if grid is not None:
        return grid, sha, True
    return object_sdf(mesh, opts.sdf_resolution, opts.sdf_voxel_size_m), sha, False


def _cached_sdf(folder: Path, obj_id: int, mesh_sha: str, settings: dict) -> SdfGrid | None:
    """The previous run's SDF of this mesh with these settings, if any."""
    try:
        meta = read_sdf_meta(folder, obj_id)
        if meta.get("mesh_sha256") != mesh_sha or meta.get("settings") != settings:
            return None
        return load_sdf(folder, obj_id)
    except InputError:
        return None


def sdf_resolution_for(extent_m: float, max_resolution: int, voxel_size_m: Optional[float]) -> int:
    """Voxels per axis: ``max_resolution``, or fewer so voxels are about ``voxel_size_m``."""
    if voxel_size_m is None:
        return max_resolution
    side = extent_m * (1.0 + 2.0 * SDF_PADDING_FRACTION)
    wanted = int(np.ceil(side / voxel_size_m)) + 5  # + the two-voxel margins each side
    return int(np.clip(wanted, 16, max_resolution))


def object_sdf(mesh, max_resolution: int, voxel_size_m: Optional[float] = None) -> SdfGrid:
    """SDF of an object-frame mesh, padded by 10 % of its extent plus two voxels."""
    extent = float(np.max(mesh.extents))
    resolution = sdf_resolution_for(extent, max_resolution, voxel_size_m)
    padding = SDF_PADDING_FRACTION * extent + 2.0 * 1.2 * extent / (resolution - 1)
    return compute_sdf(mesh, resolution=resolution, padding_m=padding)


def _mm(d: dict) -> dict:
    return {(k[:-2] + "_mm" if k.endswith("_m") else k): round(1000.0 * v, 4) for k, v in d.items()}


def run(ctx: StageContext) -> dict:
    paths, opts = ctx.paths, ctx.options
    source = latest_state_stage(paths, ctx.manifest, candidates=SOURCE_STAGES)
    src_dir = paths.stage_dir(source)
    state = read_state(src_dir)
    graph = read_contact_graph(paths.contact_graph)
    ids = [o.id for o in state.objects]
    graph_ids = {n.id for n in graph.nodes if not n.is_root}
    if graph_ids != set(ids):
        raise StageError(f"{paths.contact_graph}: objects {sorted(graph_ids)} differ from "
                         f"{paths.state(source)} {sorted(ids)}; rerun 'r2s graph'")
    if not ids:
        raise StageError(f"{paths.state(source)}: no objects to optimise")

    (ctx.out_dir / "meshes").mkdir()
    sdf_dir = ctx.out_dir / "sdf"
    old_sdf_dir = paths.stage_dir("geomopt") / "sdf"
    meshes, grids, reused = [], [], 0
    t_sdf = time.perf_counter()
    for k, o in enumerate(state.objects):
        ctx.progress(f"SDF of object {o.id}", 0.5 * k / len(ids))
        mesh_path = src_dir / o.mesh
        mesh = load_mesh(mesh_path)
        mesh_bytes = mesh_path.read_bytes()
        atomic_write_bytes(ctx.out_dir / "meshes" / f"{o.id}.glb", mesh_bytes)
        grid, sha, was_cached = sdf_of_file(old_sdf_dir, o.id, mesh, mesh_bytes, opts)
        reused += was_cached
        save_sdf(grid, sdf_dir, o.id, extra={
            "mesh_sha256": sha, "mesh": f"meshes/{o.id}.glb",
            "settings": _sdf_settings(opts.sdf_resolution, opts.sdf_voxel_size_m)})
        meshes.append(mesh)
        grids.append(grid)
    t_sdf = time.perf_counter() - t_sdf

    def progress(message: str, fraction: float) -> None:
        ctx.progress(message, 0.5 + 0.5 * fraction)

    problem, result = solve_poses(paths, ctx.manifest.model, state, meshes, grids, graph, opts,
                                  progress)

    objects = [o.model_copy(update={"world_from_object": result.world_from_object[k].tolist(),
                                    "mesh": f"meshes/{o.id}.glb"})
               for k, o in enumerate(state.objects)]
    write_state(ctx.out_dir, SceneState.model_validate(
        {**state.model_dump(), "stage": "geomopt", "objects": [o.model_dump() for o in objects]}))

    shift_mm, rot_deg = pose_moves(problem, result)
    per_object = [{"id": i, "translation_mm": round(float(s), 3), "rotation_deg": round(float(r), 3)}
                  for i, s, r in zip(ids, shift_mm, rot_deg)]
    atomic_write_json(ctx.out_dir / GEOMOPT_LOSS_FILE, {
        "iterations": result.iterations, "converged": result.converged,
        "best_iteration": result.best_iteration,  # timing lives in the manifest only
        "kept_initial": result.kept_initial,
        "terms": result.history, "before": _mm(result.before), "after": _mm(result.after),
        "objects": per_object, "source_stage": source,
        "free_space": None if result.free_space_before is None else {
            "before": dict(zip(ids, result.free_space_before)),
            "after": dict(zip(ids, result.free_space_after))},
        "support_edges": [[ids[c], None if p < 0 else ids[p]] for c, p in problem.support_edges],
        "penetration_pairs": [[ids[a], ids[b]] for a, b in problem.penetration_pairs],
    })
    atomic_write_bytes(ctx.out_dir / "loss.png", loss_plot(result.history))
    after, before = _mm(result.after), _mm(result.before)
    summary = {
        "objects": len(ids),
        "max_penetration_mm": after["max_penetration_pairs_mm"],
        "max_support_gap_mm": after["max_support_gap_mm"],
        "max_translation_mm": round(float(shift_mm.max()), 3),
        "max_rotation_deg": round(float(rot_deg.max()), 3),
        "iterations": result.iterations, "converged": result.converged,
        "kept_initial": result.kept_initial,
        "sdf_seconds": round(t_sdf, 2), "sdf_reused": reused,
        "optimise_seconds": round(result.seconds, 2),
    }
    summary.update({f"before_{k}": v for k, v in before.items()})
    summary.update({f"after_{k}": v for k, v in after.items()})
    if result.free_space_before is not None:
        summary["before_free_space_share"] = round(float(np.mean(result.free_space_before)), 5)
        summary["after_free_space_share"] = round(float(np.mean(result.free_space_after)), 5)
    return summary


STAGE = StageSpec("geomopt", Options, inputs, run, uses_model=frozenset({"input"}))
