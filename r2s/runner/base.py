"""The stage machinery: declared inputs, options, atomic outputs, staleness.

A stage module defines::

    class Options(StageOptions): ...            # pydantic; field docs become --help text
    def inputs(paths, options, manifest) -> list[Path]  # what decides staleness
    def run(ctx: StageContext) -> dict          # writes into ctx.out_dir, returns a summary
    STAGE = StageSpec("name", Options, inputs, run)

A stage that applies the scene's model (``manifest.model``, effects kept by ``r2s diagnose
--set apply=true``; :mod:`r2s.scene_model`) names the levels it applies in
``uses_model``; the part of the model of those levels is hashed with its inputs.

:func:`run_stage` recovers a half-finished previous run, skips the stage when nothing it
reads or is configured with has changed, otherwise runs it into a scratch folder and swaps
that folder into place, then records the run in the manifest.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Optional

from pydantic import BaseModel, ConfigDict

from r2s import __version__
from r2s.console import ProgressFn, silent_progress
from r2s.errors import R2SError, StageError
from r2s.io.atomic import commit_dir, recover_dir, scratch_dir
from r2s.io.manifest import Manifest, StageRecord, hash_path, load_manifest, save_manifest
from r2s.io.output_check import file_hashes, inconsistency, missing_declared
from r2s.io.paths import ScenePaths
from r2s.io.scene_lock import scene_lock
from r2s.scene_model import model_part


class StageOptions(BaseModel):
    """Base of every stage's options (frozen, no unknown keys)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass
class StageContext:
    """What a stage's ``run`` gets.

    ``out_dir`` is an empty scratch folder that becomes ``paths.stage_dir(name)`` on success.
    """

    paths: ScenePaths
    options: Any
    manifest: Manifest
    out_dir: Path
    progress: ProgressFn = silent_progress


@dataclass(frozen=True)
class StageSpec:
    name: str
    options_type: type[StageOptions]
    inputs: Callable[[ScenePaths, Any, Manifest], list[Path]]
    run: Callable[[StageContext], dict]
    output_name: Optional[str] = None
    """Folder the stage writes; defaults to ``name``."""
    uses_model: frozenset[str] = frozenset()
    """Levels of the scene's model the stage applies ("input": it corrects the observation
    with :func:`r2s.scene_model.corrected_input`; "state": it corrects a state with
    :func:`r2s.scene_model.corrected_state`). Their part of ``manifest.model`` counts
    among the stage's inputs."""

    @property
    def output(self) -> str:
        return self.output_name or self.name


@dataclass
class StageResult:
    name: str
    ran: bool
    seconds: float
    summary: dict = field(default_factory=dict)
    reason: str = ""


def _input_hashes(spec: StageSpec, paths: ScenePaths, options: Any, manifest: Manifest) -> dict[str, str]:
    hashes: dict[str, str] = {}
    for p in spec.inputs(paths, options, manifest):
        p = Path(p)
        try:
            key = str(p.resolve().relative_to(paths.root))
        except ValueError:
            key = str(p.resolve())
        hashes[key] = hash_path(p)
    hashes.update(model_hashes(spec, manifest))
    return hashes


def model_hashes(spec: StageSpec, manifest: Manifest) -> dict[str, str]:
    """``{"manifest.model[<levels>]": sha256}`` of the part of the scene's model the stage
    applies; empty when that part is empty (so a scene without a model keeps the hashes it
    had before models existed, and an unchanged model changes nothing)."""
    if not spec.uses_model or not manifest.model:
        return {}
    part = model_part(manifest.model, spec.uses_model)
    if not part:
        return {}
    text = json.dumps(part, sort_keys=True, separators=(",", ":"))
    return {f"manifest.model[{','.join(sorted(spec.uses_model))}]":
            hashlib.sha256(text.encode()).hexdigest()}


def staleness(spec: StageSpec, paths: ScenePaths, options: StageOptions,
              manifest: Manifest) -> str:
    """Why the stage must run, or "" when its recorded result is current."""
    record = manifest.stages.get(spec.name)
    out = paths.stage_dir(spec.output)
    if record is None or record.status != "done":
        return "never ran" if record is None or record.status == "never" else f"last run {record.status}"
    if not out.exists():
        return "output missing"
    problem = inconsistency(out, (record.model_extra or {}).get("output_files"))
    if problem:
        return f"output inconsistent: {problem}"
    if record.options != options.model_dump(mode="json"):
        return "options changed"
    current = _input_hashes(spec, paths, options, manifest)
    if record.input_hashes != current:
        changed = {k for k in set(current) | set(record.input_hashes)
                   if current.get(k) != record.input_hashes.get(k)}
        if all(k.startswith("manifest.model") for k in changed):
            return "model changed"
        return "inputs changed"
    if record.output_hash != hash_path(out):
        return "output modified"
    return ""


def run_stage(spec: StageSpec, scene_dir: Path, options: Optional[StageOptions] = None,
              progress: ProgressFn = silent_progress, force: bool = True) -> StageResult:
    """Run one stage on ``scene_dir`` (skipped when current unless ``force``), holding the
    scene's write lock (:mod:`r2s.io.scene_lock`; re-entrant, so a caller may hold it)."""
    with scene_lock(Path(scene_dir)):
        return _run_stage_locked(spec, Path(scene_dir), options, progress, force)


def _run_stage_locked(spec: StageSpec, scene_dir: Path, options: Optional[StageOptions],
                      progress: ProgressFn, force: bool) -> StageResult:
    paths = ScenePaths(Path(scene_dir))
    options = options if options is not None else spec.options_type()
    out = paths.stage_dir(spec.output)
    recover_dir(out)
    manifest = load_manifest(paths.manifest)
    if not force:
        reason = staleness(spec, paths, options, manifest)
        if not reason:
            rec = manifest.stages[spec.name]
            return StageResult(spec.name, ran=False, seconds=0.0, summary=rec.summary,
                               reason="up to date")
    else:
        reason = "forced"

    in_hashes = _input_hashes(spec, paths, options, manifest)
    tmp = scratch_dir(out)
    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    ctx = StageContext(paths=paths, options=options, manifest=manifest, out_dir=tmp,
                       progress=progress)
    try:
        summary = spec.run(ctx) or {}
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, R2SError):
            # keep the previous result and its record; remember why this run failed
            manifest = load_manifest(paths.manifest)
            rec = manifest.stages.get(spec.name, StageRecord())
            rec.error = str(exc)
            manifest.stages[spec.name] = rec
            save_manifest(paths.manifest, manifest)
        raise
    seconds = time.perf_counter() - t0
    missing = missing_declared(tmp)
    if missing:  # never record a stage as done with a file it names absent
        shutil.rmtree(tmp, ignore_errors=True)
        raise StageError(f"{out}: the {spec.name} stage did not write {', '.join(missing[:3])} "
                         "that its own JSON names; the previous result is kept")
    commit_dir(tmp, out)
    manifest = load_manifest(paths.manifest)
    manifest.stages[spec.name] = StageRecord(
        status="done", options=options.model_dump(mode="json"), input_hashes=in_hashes,
        output_hash=hash_path(out), started_at=started, seconds=round(seconds, 3),
        summary=summary, r2s_version=__version__, output_files=file_hashes(out),
    )
    save_manifest(paths.manifest, manifest)
    return StageResult(spec.name, ran=True, seconds=seconds, summary=summary, reason=reason)

