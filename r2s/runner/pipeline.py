"""Drive stages on a scene: one stage alone, or every stale stage in order (``r2s run``).

Nothing here prints: progress goes to a ``progress_factory`` (``name -> context manager
yielding a ProgressFn``; the CLI passes rich's bars) and input warnings to ``on_warning``
(default: the ``r2s`` logger). The CLI prints the results (:mod:`r2s.cli_output`).
"""

from __future__ import annotations

import contextlib
import json
import logging
from pathlib import Path
from typing import Any, Callable, ContextManager, Iterator, Optional

from pydantic import ValidationError

from r2s.console import ProgressFn, silent_progress
from r2s.errors import R2SError, UsageError
from r2s.io.atomic import recover_scene
from r2s.io.input_scene import load_input
from r2s.io.paths import ScenePaths
from r2s.io.manifest import Manifest, load_manifest
from r2s.io.recorded_options import recorded_options
from r2s.io.scene_lock import scene_lock
from r2s.runner import noop
from r2s.runner.base import StageOptions, StageResult, StageSpec, run_stage, staleness
from r2s.runner.registry import PIPELINE, get_stage


def _coerce(value: Any) -> Any:
    if not isinstance(value, str):
        return value
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value


ProgressFactory = Callable[[str], ContextManager[ProgressFn]]
"""``factory(stage_name)`` -> context manager yielding the stage's progress callback."""


@contextlib.contextmanager
def silent_progress_factory(name: str) -> Iterator[ProgressFn]:  # noqa: ARG001
    """No progress display (the Python API's default)."""
    yield silent_progress


def _log_warning(message: str) -> None:
    logging.getLogger("r2s").warning(message)


def _option_error(spec: StageSpec, exc: ValidationError) -> R2SError:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err.get("loc", ()))
    if err.get("type") == "extra_forbidden":
        valid = ", ".join(spec.options_type.model_fields)
        return UsageError(f"{spec.name} has no option '{loc}'; its options are {valid}")
    return UsageError(f"{spec.name} option {loc}: {err.get('msg')}")


def check_option_names(spec: StageSpec, values: dict) -> None:
    """A :class:`UsageError` naming the stage's options when ``values`` has another key."""
    unknown = [k for k in values if k not in spec.options_type.model_fields]
    if unknown:
        raise UsageError(f"{spec.name} has no option '{unknown[0]}'; its options are "
                         f"{', '.join(spec.options_type.model_fields)}")


def check_overrides(per_stage: dict[str, dict]) -> None:
    """A :class:`UsageError` for the first override whose stage has no such option or whose
    value the option's type refuses (``per_stage`` as from :func:`split_overrides`)."""
    for name, values in per_stage.items():
        spec = get_stage(name)
        check_option_names(spec, values)
        build_options(spec, None, values)


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


def _check_scene(scene_dir: Path, on_warning: Callable[[str], None]) -> ScenePaths:
    paths = ScenePaths(Path(scene_dir))
    for warning in load_input(paths.root).warnings:  # validates input/ up front
        on_warning(warning)
    return paths


def _lock(scene_dir: Path, wait_s: float, notify: Callable[[str], None]):
    paths = ScenePaths(Path(scene_dir))
    if not paths.input.is_dir():
        load_input(paths.root)  # raises the one-line error; no lock file in a non-scene
    return scene_lock(paths.root, wait_s=wait_s, notify=notify)


def run_single_stage(scene_dir: Path, name: str, overrides: dict,
                     progress_factory: ProgressFactory = silent_progress_factory,
                     on_warning: Callable[[str], None] = _log_warning,
                     wait_s: float = 0.0) -> StageResult:
    """``r2s <stage> SCENE``: rerun that one stage with its recorded options (else the
    defaults) plus overrides.

    Holds the scene's write lock; another writer makes it fail at once (``wait_s`` 0) or
    wait up to ``wait_s`` seconds (``on_warning`` is told that it waits)."""
    with _lock(scene_dir, wait_s, on_warning):
        paths = _check_scene(scene_dir, on_warning)
        spec = get_stage(name)
        options = stage_options(spec, load_manifest(paths.manifest), overrides)
        with progress_factory(name) as progress:
            return run_stage(spec, paths.root, options, progress=progress, force=True)


def split_overrides(overrides: dict, stages: tuple[str, ...] = PIPELINE) -> dict[str, dict]:
    """``{"physopt.iterations": "50"}`` -> ``{"physopt": {"iterations": "50"}}``; a key
    without a stage or with a stage not in ``stages`` is a :class:`UsageError`."""
    per_stage: dict[str, dict] = {}
    for key, value in overrides.items():
        if "." not in key:
            raise UsageError(f"--set {key}={value}: use stage.key=value with 'r2s run' "
                             f"(stages: {', '.join(stages)})")
        stage, field = key.split(".", 1)
        if stage not in stages:
            raise UsageError(f"--set {key}={value}: unknown stage '{stage}'; stages are "
                             f"{', '.join(stages)}")
        per_stage.setdefault(stage, {})[field] = value
    return per_stage


def run_pipeline(scene_dir: Path, force: bool = False, until: Optional[str] = None,
                 skip: Optional[list[str]] = None, overrides: Optional[dict] = None,
                 progress_factory: ProgressFactory = silent_progress_factory,
                 on_warning: Callable[[str], None] = _log_warning,
                 wait_s: float = 0.0) -> list[StageResult]:
    """Run each stage of :data:`PIPELINE` that is stale (or all with ``force``).

    Stages replay the options recorded in the manifest, updated by ``overrides``
    (``{"physopt.iterations": "50"}``). Every override is validated before any stage runs.
    The whole run holds the scene's write lock (``wait_s``: see :func:`run_single_stage`)
    and starts by removing scratch folders that killed runs left behind.
    """
    with _lock(scene_dir, wait_s, on_warning):
        return _run_pipeline_locked(Path(scene_dir), force, until, list(skip or []),
                                    dict(overrides or {}), progress_factory, on_warning)


def _run_pipeline_locked(scene_dir: Path, force: bool, until: Optional[str], skip: list[str],
                         overrides: dict, progress_factory: ProgressFactory,
                         on_warning: Callable[[str], None]) -> list[StageResult]:
    if not force:  # nothing changed since a full check found everything up to date
        quick = noop.quick_up_to_date(scene_dir, until, skip, overrides)
        if quick is not None:
            for warning in quick[1]:
                on_warning(warning)
            return quick[0]  # type: ignore[return-value]
    for name in skip + ([until] if until else []):
        if name not in PIPELINE:
            raise UsageError(f"unknown stage '{name}'; stages are {', '.join(PIPELINE)}")
    per_stage = split_overrides(overrides)
    check_overrides(per_stage)  # a misspelt option or a bad value fails before anything runs
    noop.forget(scene_dir)
    warnings: list[str] = []
    paths = _check_scene(scene_dir, lambda w: (warnings.append(w), on_warning(w)))
    recover_scene(paths.root)  # under the lock: no scratch folder here belongs to a live run
    order = [n for n in (PIPELINE[: PIPELINE.index(until) + 1] if until else PIPELINE)
             if n not in skip]
    results: list[StageResult] = []
    for name in order:
        spec = get_stage(name)
        manifest = load_manifest(paths.manifest)
        rec = manifest.stages.get(name)
        options = stage_options(spec, manifest, per_stage.get(name, {}))
        reason = "forced"
        if not force:
            reason = staleness(spec, paths, options, manifest)
            if not reason:
                results.append(StageResult(name, ran=False, seconds=0.0,
                                           summary=rec.summary if rec else {}, reason="up to date"))
                continue
        with progress_factory(name) as progress:
            result = run_stage(spec, paths.root, options, progress=progress, force=True)
        result.reason = reason  # why it ran: "never ran", "options changed", ...
        results.append(result)
    _remember_if_current(paths, order, per_stage, noop.arguments_key(until, skip, overrides),
                         warnings)
    return results


def _remember_if_current(paths: ScenePaths, order: list[str], per_stage: dict[str, dict],
                         args_key: str, warnings: list[str]) -> None:
    """When a full check now finds every stage of ``order`` up to date (the stage modules
    are loaded already; this costs the hashes), record it for :mod:`r2s.runner.noop`."""
    manifest = load_manifest(paths.manifest)
    external: set[str] = set()
    for name in order:
        spec = get_stage(name)
        if staleness(spec, paths, stage_options(spec, manifest, per_stage.get(name, {})),
                     manifest):
            return
        rec = manifest.stages[name]
        external |= {k for k in rec.input_hashes if Path(k).is_absolute()}
    noop.remember_up_to_date(paths.root, order, sorted(external), args_key, warnings)

