"""The Python API: docs/api.md's example runs as written (on a small scene), results are
typed and equal to what the scene's files say, and nothing is printed."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import r2s
from r2s.errors import UsageError

REPO = Path(__file__).resolve().parents[1]


def doc_example() -> str:
    text = (REPO / "docs" / "api.md").read_text()
    block = re.search(r"## Example.*?```python\n(.*?)```", text, re.S).group(1)
    first, rest = block.split("\n", 1)
    assert first.startswith("scene_dir = ")
    return rest


def test_import_r2s_is_light():
    probe = ("import sys, r2s; print(sorted(m for m in ('numpy', 'torch', 'pydantic', "
             "'typer', 'rich') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          cwd=REPO, timeout=60)
    assert proc.stdout.strip() == "[]", proc.stdout + proc.stderr


def test_docs_example_runs_and_prints_only_its_own_lines(tiny_scene, capfd):
    namespace = {"scene_dir": str(tiny_scene)}
    exec(compile(doc_example(), "docs/api.md", "exec"), namespace)
    out, err = capfd.readouterr()
    # the example's own prints: 4 stage lines, the stability line, one object line
    lines = out.strip().splitlines()
    assert [ln.split()[0] for ln in lines[:4]] == ["init", "graph", "export", "evaluate"]
    assert lines[4] == "stable objects: 1.0"
    assert lines[5].startswith("object 1: ") and len(lines) == 6, out
    assert err == ""
    result = namespace["result"]
    assert isinstance(result, r2s.RunResult)
    metrics = json.loads((tiny_scene / "evaluate" / "metrics.json").read_text())
    assert result.metrics == metrics
    assert result.export_dir == tiny_scene / "export"
    scene = namespace["scene"]
    assert isinstance(scene, r2s.ExportScene)
    exported = json.loads((tiny_scene / "export" / "scene.json").read_text())
    assert [o.id for o in scene.objects] == [o["id"] for o in exported["objects"]]
    assert scene.objects[0].mass_kg == pytest.approx(exported["objects"][0]["mass_kg"], rel=0)
    # the object of the tiny scene is a 2 cm high block on the table at z = 0
    import numpy as np
    import trimesh

    obj = scene.objects[0]
    mesh = trimesh.load(tiny_scene / "export" / obj.visual_mesh, force="mesh")
    mesh.apply_transform(np.asarray(obj.world_from_object))
    assert mesh.bounds[0][2] == pytest.approx(0.0, abs=0.004)
    assert mesh.bounds[1][2] == pytest.approx(0.02, abs=0.004)


def test_stage_function_and_option_errors(tiny_scene):
    r2s.run(tiny_scene, stages=["init"])
    run = r2s.api.graph(tiny_scene, seed=3)
    assert run.name == "graph" and run.ran
    manifest = json.loads((tiny_scene / "manifest.json").read_text())
    assert manifest["stages"]["graph"]["options"]["seed"] == 3
    with pytest.raises(UsageError, match="graph has no option 'sead'"):
        r2s.api.graph(tiny_scene, sead=3)
    with pytest.raises(UsageError, match="unknown stage 'phsyopt'"):
        r2s.run(tiny_scene, stages=["phsyopt"])
    with pytest.raises(UsageError, match="unknown stage 'phsyopt'"):
        r2s.run(tiny_scene, options={"phsyopt": {"max_rounds": 1}})
