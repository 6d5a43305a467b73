"""The no-op ``r2s run`` shortcut (r2s.runner.noop) only confirms what a full, hash-based
check found: same files (size, mtime), same arguments, same r2s source -> "up to date";
anything else -> the full check runs again."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from r2s.runner import noop
from r2s.runner.pipeline import run_pipeline

REPO = Path(__file__).resolve().parents[1]
SKIP = ["geomopt", "physopt", "texture", "export", "evaluate"]


def test_shortcut_matches_the_full_check(tiny_scene):
    first = run_pipeline(tiny_scene, skip=SKIP)
    assert [r.name for r in first] == ["init", "graph"] and all(r.ran for r in first)
    quick = noop.quick_up_to_date(tiny_scene, None, SKIP, {})
    assert quick is not None
    results, warnings = quick
    assert [(r.name, r.ran, r.reason) for r in results] == [
        ("init", False, "up to date"), ("graph", False, "up to date")]
    assert [r.summary for r in results] == [r.summary for r in first]
    # other arguments: no shortcut
    assert noop.quick_up_to_date(tiny_scene, None, SKIP[1:], {}) is None
    assert noop.quick_up_to_date(tiny_scene, None, SKIP, {"graph.seed": "1"}) is None

    # the same bytes written again (mtime changes): full check, which finds nothing to do
    rgb = tiny_scene / "input" / "rgb.png"
    data = rgb.read_bytes()
    rgb.write_bytes(data)
    os.utime(rgb, ns=(rgb.stat().st_atime_ns, rgb.stat().st_mtime_ns + 10_000_000))
    assert noop.quick_up_to_date(tiny_scene, None, SKIP, {}) is None
    again = run_pipeline(tiny_scene, skip=SKIP)
    assert not any(r.ran for r in again)
    assert noop.quick_up_to_date(tiny_scene, None, SKIP, {}) is not None  # recorded again

    # a stage output edited: the full check reruns what depends on it
    graph_file = tiny_scene / "graph" / "contact_graph.json"
    graph_file.write_text(graph_file.read_text() + " ")
    assert noop.quick_up_to_date(tiny_scene, None, SKIP, {}) is None
    rerun = run_pipeline(tiny_scene, skip=SKIP)
    assert [(r.name, r.ran) for r in rerun] == [("init", False), ("graph", True)]
    assert rerun[1].reason.startswith("output")  # "output modified" / "output inconsistent: ..."


def test_cli_noop_run_imports_no_stage(tiny_scene):
    run_pipeline(tiny_scene, skip=SKIP)
    args = ["run", str(tiny_scene)] + [a for s in SKIP for a in ("--skip", s)]
    probe = ("import sys; from r2s.cli import main\n"
             f"main({args!r})\n"
             "print('HEAVY', sorted(m for m in ('torch', 'numpy', 'pybullet', 'open3d', "
             "'r2s.runner.pipeline') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=REPO, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "HEAVY []" in proc.stdout
    assert "up to date" in proc.stdout
