"""Every path of a scene directory, declared once.

Layout (``input/``, ``gt/``, ``export/`` are the fixed contract of SCENE_FORMAT.md; the
rest is r2s's own, one folder per stage)::

    SCENE/
      input/            user data, never modified
      gt/               benchmark ground truth, never read by reconstruction stages
      init/             state.json, meshes/<id>.glb, points/<id>.npy, init.png
      graph/            contact_graph.json, contact_graph.png
      geomopt/          state.json, meshes/, sdf/<id>.npy + <id>.json, loss.json
      physopt/          state.json, meshes/, log.json
      texture/          state.json, meshes/<id>.glb (textured)
      export/           scene.json, meshes/, collision/, urdf/
      evaluate/         metrics.json, rollout.png
      diagnose/         report.json, report.md, plots
      manifest.json     per stage: options, input/output hashes, timing, status
      .cache/convex/    memo of convex decompositions (safe to delete)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

# ---- files inside stage folders (a stage writes them into its scratch folder by name) ----
STATE_FILE = "state.json"
"""Every state stage's :class:`r2s.io.state.SceneState`."""
CONTACT_GRAPH_FILE = "contact_graph.json"
METRICS_FILE = "metrics.json"
"""evaluate's (and texture's own photometric) metrics."""
PHYSOPT_LOG_FILE = "log.json"
PHYSOPT_COLLISION_DIR = "collision"
"""physopt/collision/<id>.npz: the convex pieces physopt checked (r2s/io/pieces_file.py)."""
INIT_ALTERNATES_DIR = "alternates"
"""init/alternates/: ``state.json`` and ``meshes/<id>.glb`` of the completions of the priors
init kept, which physopt may swap in (r2s/stages/physopt.py)."""
INIT_REPLACED_PRIORS_DIR = "replaced_priors"
"""init/replaced_priors/: ``state.json`` and ``meshes/<id>.glb`` of the registered priors init
replaced by their completions: still metric, so diagnose measures their scale
(r2s/diagnose/measure/scene_dir.py)."""
GEOMOPT_LOSS_FILE = "loss.json"
DIAGNOSE_REPORT_FILE = "report.json"
EXPORT_SCENE_FILE = "scene.json"
"""``export/scene.json`` (the contract) and ``gt/scene.json``."""
EXPORT_MJCF_FILE = "scene.xml"
CACHE_DIR = ".cache"
CONVEX_CACHE_DIR = "convex"

STATE_STAGES: tuple[str, ...] = ("init", "geomopt", "physopt", "texture")
"""Stages that write a :class:`r2s.io.state.SceneState` (poses, meshes, physics)."""


@dataclass(frozen=True)
class ScenePaths:
    """Paths inside one scene directory."""

    root: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root).resolve())

    # ---- fixed contract -------------------------------------------------------------
    @property
    def input(self) -> Path:
        return self.root / "input"

    @property
    def rgb(self) -> Path:
        return self.input / "rgb.png"

    @property
    def depth_png(self) -> Path:
        return self.input / "depth.png"

    @property
    def depth_npy(self) -> Path:
        return self.input / "depth.npy"

    @property
    def masks(self) -> Path:
        return self.input / "masks.png"

    @property
    def camera(self) -> Path:
        return self.input / "camera.json"

    @property
    def objects(self) -> Path:
        return self.input / "objects.json"

    @property
    def interaction(self) -> Path:
        """``input/interaction/``: an observed push (layout in docs/interaction.md)."""
        return self.input / "interaction"

    @property
    def push_action(self) -> Path:
        """The push that was made, in ``r2s predict``'s action format."""
        return self.interaction / "push.json"

    @property
    def depth_after_png(self) -> Path:
        return self.interaction / "depth_after.png"

    @property
    def depth_after_npy(self) -> Path:
        return self.interaction / "depth_after.npy"

    @property
    def masks_after(self) -> Path:
        return self.interaction / "masks_after.png"

    @property
    def observed_push(self) -> Path:
        """Per-object displacement seen between the images before and after the push."""
        return self.interaction / "observed.json"

    @property
    def gt(self) -> Path:
        return self.root / "gt"

    @property
    def gt_scene(self) -> Path:
        return self.gt / EXPORT_SCENE_FILE

    @property
    def gt_push(self) -> Path:
        """``gt/push.json``: true final poses after the push of ``input/interaction/``."""
        return self.gt / "push.json"

    @property
    def export(self) -> Path:
        return self.root / "export"

    @property
    def export_scene(self) -> Path:
        return self.export / EXPORT_SCENE_FILE

    # ---- r2s's own ----------------------------------------------------------------
    @property
    def manifest(self) -> Path:
        return self.root / "manifest.json"

    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def state(self, stage: str) -> Path:
        """``<stage>/state.json`` of a state-writing stage."""
        return self.stage_dir(stage) / STATE_FILE

    @property
    def cache(self) -> Path:
        """``.cache/``: memos that are safe to delete (never hashed: a dot folder)."""
        return self.root / CACHE_DIR

    @property
    def convex_cache(self) -> Path:
        """``.cache/convex/``: convex pieces keyed by mesh and parameters."""
        return self.cache / CONVEX_CACHE_DIR

    @property
    def contact_graph(self) -> Path:
        return self.stage_dir("graph") / CONTACT_GRAPH_FILE

    @property
    def metrics(self) -> Path:
        return self.stage_dir("evaluate") / METRICS_FILE
