"""Stage machinery: atomic outputs, recovery after a kill, staleness, manifest records."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from pydantic import Field

from r2s.io.atomic import commit_dir, recover_dir, scratch_dir
from r2s.runner.base import StageContext, StageOptions, StageSpec, run_stage, staleness
from r2s.io.manifest import hash_path, load_manifest


class CountOptions(StageOptions):
    value: int = Field(1, description="what to write")


def _inputs(paths, options, manifest):
    return [paths.input / "rgb.png"]


def _run(ctx: StageContext) -> dict:
    (ctx.out_dir / "result.txt").write_text(str(ctx.options.value))
    return {"value": ctx.options.value}


COUNT = StageSpec("count", CountOptions, _inputs, _run)


def test_run_records_and_skips_when_current(tiny_scene: Path):
    first = run_stage(COUNT, tiny_scene, CountOptions(value=3), force=False)
    assert first.ran and (tiny_scene / "count" / "result.txt").read_text() == "3"
    rec = load_manifest(tiny_scene / "manifest.json").stages["count"]
    assert rec.status == "done" and rec.options == {"value": 3} and rec.seconds >= 0
    assert rec.output_hash == hash_path(tiny_scene / "count")

    second = run_stage(COUNT, tiny_scene, CountOptions(value=3), force=False)
    assert not second.ran

    assert run_stage(COUNT, tiny_scene, CountOptions(value=4), force=False).ran  # options
    (tiny_scene / "input" / "rgb.png").write_bytes((tiny_scene / "input" / "rgb.png").read_bytes() + b"x")
    manifest = load_manifest(tiny_scene / "manifest.json")
    assert staleness(COUNT, __import__("r2s.io.paths", fromlist=["ScenePaths"]).ScenePaths(tiny_scene),
                     CountOptions(value=4), manifest) == "inputs changed"
    (tiny_scene / "count" / "result.txt").write_text("tampered")
    assert run_stage(COUNT, tiny_scene, CountOptions(value=4), force=False).ran


def test_failing_stage_keeps_previous_result(tiny_scene: Path):
    run_stage(COUNT, tiny_scene, CountOptions(value=7))

    def boom(ctx: StageContext) -> dict:
        (ctx.out_dir / "result.txt").write_text("half")
        raise RuntimeError("crash in the middle")

    broken = StageSpec("count", CountOptions, _inputs, boom)
    with pytest.raises(RuntimeError):
        run_stage(broken, tiny_scene, CountOptions(value=8))
    assert (tiny_scene / "count" / "result.txt").read_text() == "7"
    assert not list(tiny_scene.glob(".tmp-count-*"))
    assert load_manifest(tiny_scene / "manifest.json").stages["count"].options == {"value": 7}


def test_killed_stage_leaves_previous_result_and_reruns_cleanly(tiny_scene: Path):
    run_stage(COUNT, tiny_scene, CountOptions(value=1))
    script = textwrap.dedent(f"""
        import time
        from pathlib import Path
        from r2s.runner.base import StageSpec, run_stage
        from tests.test_stage_machinery import CountOptions, _inputs
        def slow(ctx):
            (ctx.out_dir / "result.txt").write_text("partial")
            Path({str(tiny_scene)!r}, "started").write_text("1")
            time.sleep(60)
            return {{}}
        run_stage(StageSpec("count", CountOptions, _inputs, slow), {str(tiny_scene)!r}, CountOptions(value=2))
    """)
    repo = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=repo)
    deadline = time.time() + 60
    while not (tiny_scene / "started").exists() and time.time() < deadline:
        time.sleep(0.05)
    assert (tiny_scene / "started").exists()
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (tiny_scene / "count" / "result.txt").read_text() == "1"
    assert list(tiny_scene.glob(".tmp-count-*"))  # the half-written scratch folder
    result = run_stage(COUNT, tiny_scene, CountOptions(value=2), force=False)
    assert result.ran
    assert (tiny_scene / "count" / "result.txt").read_text() == "2"
    assert not list(tiny_scene.glob(".tmp-count-*"))


def test_commit_interrupted_between_renames_is_recovered(tmp_path: Path):
    final = tmp_path / "stage"
    final.mkdir()
    (final / "a.txt").write_text("old")
    tmp = scratch_dir(final)
    (tmp / "a.txt").write_text("new")
    # simulate a crash after the first rename of commit_dir: final moved away, new not in place
    os.replace(final, tmp_path / ".old-stage")
    recover_dir(final)
    assert (final / "a.txt").read_text() == "old"
    assert not tmp.exists()
    tmp = scratch_dir(final)
    (tmp / "a.txt").write_text("new")
    commit_dir(tmp, final)
    assert (final / "a.txt").read_text() == "new"
    assert not (tmp_path / ".old-stage").exists()


def test_downstream_reads_the_latest_current_state(tmp_path: Path):
    """A rerun of init that reproduces its output keeps geomopt's result current (it is
    read, although init ran last); one that changes its output makes geomopt stale."""
    from r2s.io.paths import ScenePaths
    from r2s.io.manifest import Manifest, StageRecord
    from r2s.io.latest_state import latest_state_stage

    paths = ScenePaths(tmp_path)
    for name in ("init", "geomopt"):
        paths.state(name).parent.mkdir(parents=True)
        paths.state(name).write_text("{}")
    manifest = Manifest(stages={
        "init": StageRecord(status="done", output_hash="A", started_at="2026-01-01T10:00:00"),
        "geomopt": StageRecord(status="done", input_hashes={"init": "A", "graph": "G"},
                               output_hash="B", started_at="2026-01-01T09:00:00"),
        "graph": StageRecord(status="done", output_hash="G"),
    })
    assert latest_state_stage(paths, manifest) == "geomopt"
    manifest.stages["init"].output_hash = "A2"
    assert latest_state_stage(paths, manifest) == "init"
    assert latest_state_stage(paths, manifest, source="geomopt") == "geomopt"
