"""Stage ``graph``: the contact graph of the init reconstruction (paper stage b).

Reads ``init/state.json`` and its meshes, writes ``graph/contact_graph.json`` (see
:mod:`r2s.graph.schema`) and ``graph/contact_graph.png``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from pydantic import Field, ValidationError

from r2s.errors import StageError
from r2s.graph.build import GraphParams, PosedObject, build_contact_graph
from r2s.graph.draw import draw_contact_graph
from r2s.graph.schema import ContactGraph
from r2s.graph.support import SupportParams
from r2s.io.atomic import atomic_write_bytes, atomic_write_json
from r2s.io.input_scene import read_json_file
from r2s.io.mesh_io import load_mesh
from r2s.io.paths import CONTACT_GRAPH_FILE, ScenePaths
from r2s.io.state import SceneState, read_state
from r2s.runner.base import StageContext, StageOptions, StageSpec
from r2s.io.manifest import Manifest
from r2s.io.latest_state import latest_state_stage

SOURCE_STAGES = ("init",)


class Options(StageOptions):
    proximity_margin_m: float = Field(0.005, ge=0.0, description="AABB inflation for proximity edges (m)")
    gap_scale_m: float = Field(0.05, gt=0.0, description="support gap that gives d_gap = 1 (m)")
    min_support_likelihood: float = Field(0.25, ge=0.0, le=1.0, description="H needed to record an extra (non-tree) supporter")
    max_support_gap_m: float = Field(0.01, ge=0.0, description="largest gap of an extra (non-tree) supporter (m)")
    plane_max_tilt_deg: float = Field(20.0, ge=0.0, lt=90.0, description="faces within this angle of 'up' form support planes")
    plane_height_tolerance_m: float = Field(0.003, gt=0.0, description="faces closer in height than this join one plane (m)")
    min_plane_area_m2: float = Field(2e-5, ge=0.0, description="smallest support plane kept (m^2)")
    samples: int = Field(2000, ge=100, description="surface samples per object for gap measurements")
    seed: int = Field(0, description="seed of the surface samples")

    def params(self) -> GraphParams:
        return GraphParams(
            support=SupportParams(gap_scale_m=self.gap_scale_m,
                                  min_support_likelihood=self.min_support_likelihood,
                                  max_support_gap_m=self.max_support_gap_m),
            proximity_margin_m=self.proximity_margin_m,
            plane_max_tilt_deg=self.plane_max_tilt_deg,
            plane_height_tolerance_m=self.plane_height_tolerance_m,
            min_plane_area_m2=self.min_plane_area_m2,
            n_samples=self.samples, seed=self.seed)


def com_in_object_frame(mesh: trimesh.Trimesh, declared: list[float] | None) -> np.ndarray:
    """(3,) the declared COM, else the solid's centroid (watertight), else the area centroid."""
    if declared is not None:
        return np.asarray(declared, dtype=np.float64)
    if mesh.is_watertight and mesh.volume > 0:
        return np.asarray(mesh.center_mass, dtype=np.float64)
    return np.asarray(mesh.centroid, dtype=np.float64)


def load_object_meshes(stage_dir: Path, state: SceneState) -> dict[int, trimesh.Trimesh]:
    """Object-frame meshes of a state, by id."""
    return {o.id: load_mesh(Path(stage_dir) / o.mesh) for o in state.objects}


def posed_objects(state: SceneState, meshes: dict[int, trimesh.Trimesh]) -> list[PosedObject]:
    """Meshes placed in the world by their ``world_from_object``, with world COMs."""
    out = []
    for o in state.objects:
        mesh = meshes[o.id]
        pose = o.pose
        com = com_in_object_frame(mesh, o.com_in_object)
        out.append(PosedObject(id=o.id, label=o.label,
                               mesh_world=mesh.copy().apply_transform(pose),
                               com_world_m=pose[:3, :3] @ com + pose[:3, 3]))
    return out


def read_contact_graph(path: Path) -> ContactGraph:
    """Read ``graph/contact_graph.json``; :class:`StageError` if missing or malformed."""
    path = Path(path)
    if not path.is_file():
        raise StageError(f"{path}: missing; run the 'graph' stage first")
    try:
        return ContactGraph.model_validate(read_json_file(path))
    except ValidationError as exc:
        raise StageError(f"{path}: malformed contact graph ({exc.errors()[0]['msg']})") from None


def inputs(paths: ScenePaths, options: Options, manifest: Manifest) -> list[Path]:
    return [paths.stage_dir("init")]


def run(ctx: StageContext) -> dict:
    paths, opts = ctx.paths, ctx.options
    source = latest_state_stage(paths, ctx.manifest, candidates=SOURCE_STAGES)
    stage_dir = paths.stage_dir(source)
    state = read_state(stage_dir)
    if not state.objects:
        raise StageError(f"{paths.state(source)}: no objects to build a contact graph from")
    ctx.progress("loading meshes", 0.0)
    objects = posed_objects(state, load_object_meshes(stage_dir, state))
    ctx.progress("building the contact graph", 0.3)
    graph = build_contact_graph(objects, np.asarray(state.gravity),
                                np.asarray(state.support.point),
                                np.asarray(state.support.normal), opts.params())
    graph = ContactGraph.model_validate({**graph.model_dump(), "source_stage": source})
    atomic_write_json(ctx.out_dir / CONTACT_GRAPH_FILE, graph.model_dump())
    ctx.progress("drawing", 0.9)
    atomic_write_bytes(ctx.out_dir / "contact_graph.png",
                       draw_contact_graph(graph, title=f"contact graph ({paths.root.name})"))
    tree = [e for e in graph.support_edges if e.in_tree]
    return {
        "objects": len(state.objects),
        "on_table": sum(1 for e in tree if e.parent == 0),
        "stacked": sum(1 for e in tree if e.parent != 0),
        "extra_supports": sum(1 for e in graph.support_edges if not e.in_tree),
        "proximity_edges": len(graph.proximity_edges),
        "max_depth": max(n.depth for n in graph.nodes),
    }


STAGE = StageSpec("graph", Options, inputs, run)
