"""Which state stage downstream stages read: the latest one in pipeline order that has run."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from r2s.errors import StageError
from r2s.io.paths import STATE_STAGES, ScenePaths
from r2s.stages.manifest import Manifest

GEOMETRY_STAGES: tuple[str, ...] = ("init", "geomopt", "physopt")
"""State stages that decide poses and physics (texture only repaints meshes)."""


def latest_state_stage(paths: ScenePaths, manifest: Manifest, source: Optional[str] = None,
                       candidates: tuple[str, ...] = STATE_STAGES) -> str:
    """Name of the most recently run state stage with a finished result (or ``source``)."""
    def done(name: str) -> bool:
        rec = manifest.stages.get(name)
        return rec is not None and rec.status == "done" and paths.state(name).is_file()

    if source is not None and source != "auto":
        if not done(source):
            raise StageError(f"stage '{source}' has no result in {paths.root}; run it first")
        return source
    finished = [(manifest.stages[n].started_at or "", k, n) for k, n in enumerate(candidates)
                if done(n)]
    if finished:
        # the most recently run result (a stage rerun upstream makes later ones stale);
        # ties (same second) go to the later stage in pipeline order
        return max(finished)[2]
    raise StageError(f"{paths.root}: no reconstruction yet; run 'r2s init' first")


def state_dir(paths: ScenePaths, stage: str) -> Path:
    return paths.stage_dir(stage)
