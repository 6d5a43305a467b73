"""Which state stage a reader uses: the latest one in pipeline order that has run and is
current. The one answer to "has stage X finished" for stages and for diagnose alike."""

from __future__ import annotations

from typing import Optional

from r2s.errors import StageError
from r2s.io.paths import STATE_STAGES, ScenePaths
from r2s.io.manifest import Manifest

GEOMETRY_STAGES: tuple[str, ...] = ("init", "geomopt", "physopt")
"""State stages that decide poses and physics (texture only repaints meshes)."""


def finished(paths: ScenePaths, manifest: Manifest, name: str) -> bool:
    """Whether state stage ``name`` has a finished result (recorded done, state on disk)."""
    rec = manifest.stages.get(name)
    return rec is not None and rec.status == "done" and paths.state(name).is_file()


def latest_state_stage(paths: ScenePaths, manifest: Manifest, source: Optional[str] = None,
                       candidates: tuple[str, ...] = STATE_STAGES) -> str:
    """Name of the state stage downstream stages should read (or ``source``).

    The last stage in pipeline order with a finished result that is *current*: every
    stage result it read (its recorded input hashes keyed by a stage name) is still that
    stage's result. A rerun upstream that changed its output makes the later results
    stale; one that reproduced its output (a forced rerun, a model change that did not
    touch it) does not, whichever ran last.
    """
    def done(name: str) -> bool:
        return finished(paths, manifest, name)

    def current(name: str) -> bool:
        for key, recorded in manifest.stages[name].input_hashes.items():
            upstream = manifest.stages.get(key)
            if upstream is not None and upstream.status == "done" \
                    and upstream.output_hash != recorded:
                return False
        return True

    if source is not None and source != "auto":
        if not done(source):
            raise StageError(f"stage '{source}' has no result in {paths.root}; run it first")
        return source
    ran = [n for n in candidates if done(n)]
    if ran:
        fresh = [n for n in ran if current(n)]
        return (fresh or ran)[-1]
    raise StageError(f"{paths.root}: no reconstruction yet; run 'r2s init' first")
