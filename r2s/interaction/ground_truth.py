"""The ground truth (``gt/``) as an export folder, so that it replays in the same code as
a reconstruction: ``r2s declutter`` replays its order on it, ``r2s synth --push`` makes
the observed push on it."""

from __future__ import annotations

import shutil
from pathlib import Path


def export_ground_truth(scene_dir: Path, work_dir: Path) -> Path:
    """Export ``scene_dir/gt`` in a copy under ``work_dir``; returns that copy's ``export/``.

    The scene's ``.cache/`` (convex pieces primed by ``r2s synth``) is copied along, so
    nothing is decomposed again. ``scene_dir`` itself is not written.
    """
    from r2s.stages.base import run_stage
    from r2s.stages.export import STAGE as EXPORT, Options as ExportOptions

    scene_dir, scene = Path(scene_dir), Path(work_dir) / "gt_scene"
    shutil.copytree(scene_dir / "gt", scene / "gt")
    if (scene_dir / ".cache").is_dir():
        shutil.copytree(scene_dir / ".cache", scene / ".cache")
    run_stage(EXPORT, scene, ExportOptions(source="gt"))
    return scene / "export"
