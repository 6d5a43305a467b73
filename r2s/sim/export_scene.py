"""Build the judge's bodies from a list of objects and write them as ``export/``.

The body parameters (:class:`BodyParams`: density where no mass is estimated, friction
where none is, restitution, the convex decomposition) have one home here: the export
stage's options default to them, diagnose reads the recorded ones into this type, and the
ground truth is exported with the defaults (:func:`export_ground_truth`).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Optional

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field

from r2s.console import ProgressFn, silent_progress
from r2s.geometry.convex_cache import cached_convex_decomposition
from r2s.geometry.convex_params import DEFAULT_CONVEX, ConvexMethod, ConvexParams
from r2s.geometry.mass_properties import mass_properties
from r2s.geometry.open_container import open_container
from r2s.io.export_writer import ExportBody, write_export
from r2s.io.mesh_io import load_mesh, same_triangles, welded
from r2s.io.paths import ScenePaths
from r2s.io.pieces_file import read_pieces
from r2s.io.scene_json import read_gt_scene
from r2s.physical.provenance import container_mass, resolve_physics


class BodyParams(BaseModel):
    """How export turns an object into a rigid body (the export stage's options but its
    source). Field names are the export options' (``r2s export --set density_kg_m3=...``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    density_kg_m3: Optional[float] = Field(
        None, gt=0, description="Density where no mass is estimated (unset: by label, "
                                "r2s/physical/density_table.py).")
    default_friction: float = Field(0.8, gt=0, description="Body friction where none is estimated.")
    convex_method: ConvexMethod = Field(DEFAULT_CONVEX.method,
                                        description="Convex decomposition: vhacd or coacd.")
    convex_threshold: float = Field(DEFAULT_CONVEX.threshold, gt=0,
                                    description="CoACD concavity threshold "
                                                "(convex_method=coacd only).")
    max_convex_pieces: int = Field(DEFAULT_CONVEX.max_pieces, ge=1,
                                   description="Most convex pieces per object.")
    restitution: float = Field(0.0, ge=0, le=1, description="Restitution of every body.")

    @property
    def convex(self) -> ConvexParams:
        return ConvexParams(self.convex_threshold, self.max_convex_pieces, self.convex_method)


@dataclass(frozen=True)
class ObjectItem:
    """One object to export: its mesh file and what a stage estimated (None: not estimated).

    pose : (4, 4) world_from_object; com : (3,) object frame, metres.
    """

    id: int
    label: str
    mesh_path: Path
    pose: np.ndarray
    mass_kg: Optional[float]
    com: Optional[np.ndarray]
    friction: Optional[float]
    restitution: Optional[float] = None
    extra: dict[str, Any] = field(default_factory=dict)
    stage: Optional[str] = None
    provenance: Optional[dict] = None
    """A stage's own record of where its values came from (physopt writes one)."""
    fitted: tuple[str, ...] = ()
    """Values a diagnose fit set ("friction", "com")."""
    from_gt: bool = False
    collision_mesh_path: Optional[Path] = None
    """A mesh whose convex pieces to use when it holds the same triangles as ``mesh_path``
    (physopt's, whose pieces its checks verified: texture reorders the vertices, and V-HACD
    depends on their order)."""
    collision_pieces_path: Optional[Path] = None
    """physopt's file of the pieces it checked (:mod:`r2s.io.pieces_file`; trimmed against
    the neighbours, so not a function of the mesh alone), for ``collision_mesh_path``'s mesh
    or, when that is None, for ``mesh_path``'s. Used when it holds pieces made with the
    export's decomposition parameters and the meshes hold the same triangles."""


def gt_items(paths: ScenePaths) -> tuple[list, dict, list[ObjectItem]]:
    """``(gravity, support dict, items)`` of the ground truth ``gt/scene.json``."""
    gt = read_gt_scene(paths.gt_scene)
    items = [ObjectItem(id=obj.id, label=obj.label, mesh_path=paths.gt / obj.mesh,
                        pose=np.asarray(obj.world_from_object), mass_kg=obj.mass_kg,
                        com=np.asarray(obj.com_in_object), friction=obj.friction,
                        from_gt=True, extra={"source": "gt"})
             for obj in gt.objects]
    return gt.gravity, gt.support.model_dump(), items


def build_and_write(out_dir: Path, gravity: list, support: dict, items: list[ObjectItem],
                    params: BodyParams, cache_dir: Optional[Path],
                    progress: ProgressFn = silent_progress, users: Optional[dict] = None,
                    camera=None) -> list[ExportBody]:
    """Decompose, weigh and write every object into ``out_dir`` (export/'s layout).

    ``users``: ``input/objects.json`` entries by id (their mass_kg, density_kg_m3, friction
    win); ``camera``: the input camera for the MJCF and USD scenes. Mass, friction and COM
    and their provenance: :func:`r2s.physical.provenance.resolve_physics`."""
    bodies = []
    for k, item in enumerate(items):
        progress(f"object {item.id}: convex decomposition", k / max(len(items), 1))
        mesh = load_mesh(item.mesh_path)
        geom = welded(mesh)
        collision = _collision_geometry(item, geom)
        pieces = _checked_pieces(item, collision is geom, params.convex) or \
            cached_convex_decomposition(collision, cache_dir, **params.convex.as_kwargs())
        unit = mass_properties(geom, pieces, mass_kg=1.0)
        record = dict(label=item.label, mass_kg=item.mass_kg, friction=item.friction,
                      com=item.com, stage=item.stage, provenance=item.provenance,
                      fitted=item.fitted, from_gt=item.from_gt)
        mass, friction, com, provenance = resolve_physics(
            record, unit.volume_m3, unit.com_in_object, (users or {}).get(item.id),
            params.density_kg_m3, params.default_friction)
        if item.mass_kg is None and item.extra.get("source", "prior") != "prior":
            # no stage weighed this completion (physopt skipped): as physopt would
            mass, provenance["mass"] = container_mass(partial(open_container, geom), mass,
                                                      provenance["mass"])
        # An estimated COM (non-uniform density) keeps the uniform body's inertia: the
        # inertia of a non-uniform body is not observable from one image.
        bodies.append(ExportBody(
            id=item.id, label=item.label, visual_mesh=mesh, collision_pieces=pieces,
            world_from_object=item.pose, mass_kg=mass, com_in_object=com,
            inertia_about_com=unit.inertia_about_com * mass, friction=friction,
            restitution=item.restitution or params.restitution,
            extra={**item.extra, "provenance": provenance},
        ))
    support = dict(support)
    support.setdefault("friction", params.default_friction)
    write_export(out_dir, gravity, support, bodies, camera=camera)
    return bodies


def _checked_pieces(item: ObjectItem, own_geometry: bool, convex: ConvexParams
                    ) -> Optional[list[trimesh.Trimesh]]:
    """The pieces physopt checked (``item.collision_pieces_path``) when they belong to this
    mesh and these parameters, else None. ``own_geometry``: :func:`_collision_geometry`
    fell back to the item's own mesh."""
    if item.collision_pieces_path is None:
        return None
    if item.collision_mesh_path is not None and own_geometry:
        return None  # physopt's mesh holds other triangles: its pieces are not this mesh's
    return read_pieces(item.collision_pieces_path, convex.as_kwargs())


def _collision_geometry(item: ObjectItem, geom: trimesh.Trimesh) -> trimesh.Trimesh:
    """What to decompose: the welded mesh of ``item.collision_mesh_path`` when it holds the
    same triangles as ``geom`` (the item's welded mesh), else ``geom``."""
    if item.collision_mesh_path is None or not Path(item.collision_mesh_path).is_file():
        return geom
    other = welded(load_mesh(item.collision_mesh_path))
    return other if same_triangles(other, geom) else geom


def export_ground_truth(scene_dir: Path, work_dir: Path) -> Path:
    """Export ``scene_dir/gt`` with the default body parameters into ``work_dir/export``.

    Reuses the scene's ``.cache/convex`` (pieces primed by ``r2s synth``) read-only, so
    nothing is decomposed again; ``scene_dir`` itself is not written. Returns the folder.
    """
    src = ScenePaths(Path(scene_dir))
    work = Path(work_dir) / "gt_scene"
    cache = ScenePaths(work).convex_cache
    if src.convex_cache.is_dir():
        shutil.copytree(src.convex_cache, cache)
    gravity, support, items = gt_items(src)
    out = ScenePaths(work).export
    out.mkdir(parents=True)
    build_and_write(out, gravity, support, items, BodyParams(), cache)
    return out
