"""The Python API: run the pipeline or one stage on a scene folder, read an export.

Nothing here prints (pass ``progress=`` to see progress); see docs/api.md.

>>> import r2s
>>> result = r2s.run("scenes/s0", stages=["init", "graph"], options={"graph": {"seed": 1}})
>>> [s.name for s in result.stages if s.ran]
>>> scene = r2s.load_export("scenes/s0/export")
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Optional, Sequence

from r2s.errors import UsageError
from r2s.io.paths import ScenePaths
from r2s.io.scene_json import ExportObject, ExportScene, read_export_scene

ProgressFn = Callable[[str, float], None]
"""``progress(message, fraction)``; ``fraction`` in [0, 1] or negative for unknown."""

STAGES = ("init", "graph", "geomopt", "physopt", "texture", "export", "evaluate", "diagnose")
"""Every stage; :data:`r2s.runner.registry.PIPELINE` (all but diagnose) is what ``run`` drives."""


@dataclass(frozen=True)
class StageRun:
    """One stage of a run: ``ran`` False when it was up to date (``reason``)."""

    name: str
    ran: bool
    seconds: float
    reason: str
    summary: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RunResult:
    """What :func:`run` did on ``scene_dir``; ``metrics`` is evaluate/metrics.json (None
    when evaluate has not run) and ``export_dir`` export/ (None when export has not run)."""

    scene_dir: Path
    stages: tuple[StageRun, ...]
    metrics: Optional[dict]
    export_dir: Optional[Path]
    warnings: tuple[str, ...] = ()

    def stage(self, name: str) -> StageRun:
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(name)


def _quiet_native_imports() -> None:
    """Import PyBullet with file descriptors 1 and 2 pointed at /dev/null: its C code
    prints a build banner at import, which an API call must not."""
    import os
    import sys

    if "pybullet" in sys.modules:
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved, devnull = [os.dup(1), os.dup(2)], os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        import pybullet  # noqa: F401
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [devnull]:
            os.close(fd)


def _progress_factory(progress: Optional[ProgressFn]) -> Callable:
    @contextlib.contextmanager
    def factory(name: str) -> Iterator[ProgressFn]:
        if progress is None:
            yield lambda message, fraction: None
        else:
            yield lambda message, fraction: progress(f"{name}: {message}", fraction)

    return factory


def _result(scene_dir: Path, results: Sequence[Any], warnings: list[str]) -> RunResult:
    paths = ScenePaths(Path(scene_dir))
    metrics = json.loads(paths.metrics.read_text()) if paths.metrics.is_file() else None
    return RunResult(
        scene_dir=Path(scene_dir),
        stages=tuple(StageRun(r.name, r.ran, float(r.seconds), r.reason, dict(r.summary))
                     for r in results),
        metrics=metrics,
        export_dir=paths.export if (paths.export / "scene.json").is_file() else None,
        warnings=tuple(warnings))


def run(scene_dir: str | Path, stages: Optional[Sequence[str]] = None,
        options: Optional[Mapping[str, Mapping[str, Any]]] = None, force: bool = False,
        progress: Optional[ProgressFn] = None) -> RunResult:
    """``r2s run`` from Python: run the stale stages of the pipeline on ``scene_dir``.

    stages: the pipeline stages to consider (default: all of init..evaluate; the others
        are left out, upstream results are used as they are).
    options: ``{stage: {option: value}}`` applied to the options each stage last ran with
        (else its defaults), e.g. ``{"physopt": {"max_rounds": 2}}``.
    force: rerun every considered stage even when up to date.
    progress: optional callback; nothing is printed either way.
    """
    from r2s.runner.pipeline import run_pipeline
    from r2s.runner.registry import PIPELINE

    _quiet_native_imports()
    chosen = list(PIPELINE if stages is None else stages)
    unknown = [s for s in chosen if s not in PIPELINE]
    if unknown:
        raise UsageError(f"unknown stage '{unknown[0]}'; stages are {', '.join(PIPELINE)}")
    overrides = {f"{stage}.{key}": _as_text(value)
                 for stage, values in (options or {}).items() for key, value in values.items()}
    warnings: list[str] = []
    results = run_pipeline(Path(scene_dir), force=force,
                           until=max(chosen, key=PIPELINE.index) if chosen else None,
                           skip=[s for s in PIPELINE if s not in chosen], overrides=overrides,
                           progress_factory=_progress_factory(progress),
                           on_warning=warnings.append)
    return _result(Path(scene_dir), results, warnings)


def run_stage(scene_dir: str | Path, name: str, progress: Optional[ProgressFn] = None,
              **options: Any) -> StageRun:
    """``r2s <name> SCENE --set k=v``: rerun one stage with its recorded options (else the
    defaults) updated by ``options``."""
    from r2s.runner.pipeline import run_single_stage

    if name not in STAGES:
        raise UsageError(f"unknown stage '{name}'; stages are {', '.join(STAGES)}")
    _quiet_native_imports()
    r = run_single_stage(Path(scene_dir), name, {k: _as_text(v) for k, v in options.items()},
                         progress_factory=_progress_factory(progress), on_warning=lambda m: None)
    return StageRun(r.name, r.ran, float(r.seconds), r.reason, dict(r.summary))


def _as_text(value: Any) -> Any:
    """Option values travel as the CLI's ``--set`` text (JSON for non-strings)."""
    return value if isinstance(value, str) else json.dumps(value)


def _stage_function(name: str) -> Callable[..., StageRun]:
    def stage(scene_dir: str | Path, progress: Optional[ProgressFn] = None,
              **options: Any) -> StageRun:
        return run_stage(scene_dir, name, progress=progress, **options)

    stage.__name__ = name
    stage.__qualname__ = name
    stage.__doc__ = (f"Run the {name} stage on ``scene_dir`` (``r2s {name}``); keyword "
                     f"arguments are its options (``r2s {name} --help``).")
    return stage


init = _stage_function("init")
graph = _stage_function("graph")
geomopt = _stage_function("geomopt")
physopt = _stage_function("physopt")
texture = _stage_function("texture")
export = _stage_function("export")
evaluate = _stage_function("evaluate")
diagnose = _stage_function("diagnose")


def load_export(path: str | Path) -> ExportScene:
    """``export/scene.json`` as typed objects (:class:`r2s.io.scene_json.ExportScene`):
    ``path`` is the scene folder, its ``export/`` folder or the ``scene.json`` file. Mesh
    paths in the result are relative to ``export/``."""
    p = Path(path)
    if p.is_dir() and (p / "export" / "scene.json").is_file():
        p = p / "export" / "scene.json"
    elif p.is_dir():
        p = p / "scene.json"
    return read_export_scene(p)


__all__ = ["run", "run_stage", "load_export", "RunResult", "StageRun", "ExportScene",
           "ExportObject", "STAGES", *STAGES]
