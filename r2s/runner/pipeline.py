"""Drive stages on a scene: one stage alone, or every stale stage in order (``r2s run``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

from pydantic import ValidationError

from r2s.console import console, print_table, stage_progress
from r2s.errors import R2SError
from r2s.io.input_scene import load_input
from r2s.io.paths import ScenePaths
from r2s.io.manifest import Manifest, load_manifest
from r2s.io.recorded_options import recorded_options
from r2s.runner.base import StageOptions, StageResult, StageSpec, run_stage, staleness
from r2s.runner.registry import PIPELINE, get_stage


def _coerce(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value


def _option_error(spec: StageSpec, exc: ValidationError) -> R2SError:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err.get("loc", ()))
    return R2SError(f"{spec.name} option {loc}: {err.get('msg')}")


def build_options(spec: StageSpec, base: Optional[dict], overrides: dict) -> StageOptions:
    """Options model from ``base`` values (None: the defaults) plus ``key=value`` overrides."""
    data = dict(base or {})
    data.update({k: _coerce(v) for k, v in overrides.items()})
    try:
        return spec.options_type.model_validate(data)
    except ValidationError as exc:
        raise _option_error(spec, exc) from None


def stage_options(spec: StageSpec, manifest: Manifest, overrides: dict) -> StageOptions:
    """The options a stage runs with: those its last run recorded (else the defaults,
    :func:`r2s.io.recorded_options.recorded_options`), then ``key=value`` overrides. Both
    ``r2s run`` and ``r2s <stage> --set`` start here, so an option means one thing."""
    try:
        return recorded_options(manifest, spec.name, spec.options_type,
                                {k: _coerce(v) for k, v in overrides.items()})
    except ValidationError as exc:
        raise _option_error(spec, exc) from None


def _check_scene(scene_dir: Path) -> ScenePaths:
    paths = ScenePaths(Path(scene_dir))
    for warning in load_input(paths.root).warnings:  # validates input/ up front
        console.print(f"[yellow]warning:[/yellow] {warning}")
    return paths


def run_single_stage(scene_dir: Path, name: str, overrides: dict) -> StageResult:
    """``r2s <stage> SCENE``: rerun that one stage with its recorded options (else the
    defaults) plus overrides."""
    paths = _check_scene(scene_dir)
    spec = get_stage(name)
    options = stage_options(spec, load_manifest(paths.manifest), overrides)
    with stage_progress(name) as progress:
        result = run_stage(spec, paths.root, options, progress=progress, force=True)
    _print_results([result])
    return result


def _split_overrides(overrides: dict) -> dict[str, dict]:
    per_stage: dict[str, dict] = {}
    for key, value in overrides.items():
        if "." not in key:
            raise R2SError(f"--set {key}={value}: use stage.key=value with 'r2s run'")
        stage, field = key.split(".", 1)
        per_stage.setdefault(stage, {})[field] = value
    return per_stage


def run_pipeline(scene_dir: Path, force: bool = False, until: Optional[str] = None,
                 skip: Optional[list[str]] = None, overrides: Optional[dict] = None
                 ) -> list[StageResult]:
    """Run each stage of :data:`PIPELINE` that is stale (or all with ``force``).

    Stages replay the options recorded in the manifest, updated by ``overrides``
    (``{"physopt.iterations": "50"}``).
    """
    paths = _check_scene(scene_dir)
    skip = list(skip or [])
    for name in skip + ([until] if until else []):
        if name not in PIPELINE:
            raise R2SError(f"unknown stage '{name}'; stages are {', '.join(PIPELINE)}")
    per_stage = _split_overrides(overrides or {})
    order = list(PIPELINE[: PIPELINE.index(until) + 1] if until else PIPELINE)
    results: list[StageResult] = []
    for name in order:
        if name in skip:
            continue
        spec = get_stage(name)
        manifest = load_manifest(paths.manifest)
        rec = manifest.stages.get(name)
        options = stage_options(spec, manifest, per_stage.get(name, {}))
        if not force:
            reason = staleness(spec, paths, options, manifest)
            if not reason:
                results.append(StageResult(name, ran=False, seconds=0.0,
                                           summary=rec.summary if rec else {}, reason="up to date"))
                continue
        with stage_progress(name) as progress:
            results.append(run_stage(spec, paths.root, options, progress=progress, force=True))
    _print_results(results)
    return results


def _print_results(results: list[StageResult]) -> None:
    rows = []
    for r in results:
        status = "[green]ran[/green]" if r.ran else f"[dim]{r.reason}[/dim]"
        brief = ", ".join(f"{k}={_fmt(v)}" for k, v in list(r.summary.items())[:4]
                          if k != "warnings")
        rows.append([r.name, status, f"{r.seconds:.1f}", brief])
    print_table("stages", ["stage", "status", "seconds", "summary"], rows)
    for r in results:
        for warning in r.summary.get("warnings") or []:
            console.print(f"[yellow]warning:[/yellow] {r.name}: {warning}")
    for r in results:
        if r.name == "evaluate" and r.summary:
            _print_metrics(r.summary)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _print_metrics(summary: dict) -> None:
    rows = [[k, _fmt(v)] for k, v in summary.items() if not isinstance(v, (list, dict))]
    print_table("evaluation", ["metric", "value"], rows)
