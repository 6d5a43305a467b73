"""``r2s batch``: scenes found at any depth, run by local processes (2 at a time) and by a
local Ray instance; the reports have one row per scene and the aggregate of ``r2s report``,
and both executors give the same metrics. Cheap stages only (init, graph, export, evaluate
without rendering) on the tiny hand-made scene."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

from conftest import write_tiny_input
from r2s.batch import aggregate
from r2s.errors import UsageError
from r2s.runner.batch import BatchConfig, find_scenes, run_batch

pytestmark = pytest.mark.slow

LAYOUT = ("a/s1", "a/s2", "b/c/s3", "s4")
CHEAP = dict(overrides={"evaluate.render": "false"}, skip=("geomopt", "physopt", "texture"))


def make_root(root: Path) -> Path:
    for k, sub in enumerate(LAYOUT):
        write_tiny_input(root / sub, width=64 + 8 * k)  # four different scenes
    (root / "notes").mkdir()  # a folder without input/ is not a scene
    return root


def rows(csv_path: Path) -> list[dict]:
    with open(csv_path) as fh:
        return list(csv.DictReader(fh))


def test_find_scenes_at_any_depth(tmp_path):
    root = make_root(tmp_path / "data")
    assert find_scenes(root) == [root / s for s in sorted(LAYOUT)]
    with pytest.raises(UsageError, match="no scene"):
        find_scenes(root / "notes") or run_batch(root / "notes", BatchConfig())


@pytest.fixture(scope="module")
def local_batch(tmp_path_factory):
    root = make_root(tmp_path_factory.mktemp("batch") / "data")
    outcome = run_batch(root, BatchConfig(jobs=2, **CHEAP))
    return root, outcome


def test_local_batch_two_jobs(local_batch):
    root, outcome = local_batch
    assert outcome.failed == 0, [s.error for s in outcome.scenes]
    table = rows(root / "report.csv")
    assert [r["scene"] for r in table[:4]] == sorted(LAYOUT)
    assert len(table) == 5 and table[4]["scene"] == "r2s (all)"  # 4 scene rows + aggregate
    for r in table[:4]:  # each scene row is that scene's own metrics
        metrics = json.loads((root / r["scene"] / "evaluate" / "metrics.json").read_text())
        assert float(r["settling_time_s"]) == pytest.approx(metrics["settling_time_s"], rel=1e-5)
        assert float(r["stability_pct"]) == pytest.approx(
            100.0 * sum(o["stable"] for o in metrics["objects"]) / len(metrics["objects"]))
    pooled = aggregate([root / s for s in LAYOUT])  # the aggregate is r2s report's
    assert float(table[4]["mean_linear_speed_mps"]) == pytest.approx(
        pooled.values["mean_linear_speed_mps"], rel=1e-5)
    md = (root / "report.md").read_text().splitlines()
    assert len(md) == 2 + 4 + 1 and md[-1].startswith("| **r2s: 4 scenes** |")
    for s in LAYOUT:
        assert (root / s / "run.log").is_file()
        assert (root / s / "export" / "scene.json").is_file()


def test_local_batch_resumes(local_batch):
    root, _ = local_batch
    before = {s: (root / s / "manifest.json").read_text() for s in LAYOUT}
    outcome = run_batch(root, BatchConfig(jobs=2, **CHEAP))
    assert outcome.failed == 0
    # nothing reran: the manifests (which record every run) are unchanged
    assert {s: (root / s / "manifest.json").read_text() for s in LAYOUT} == before


def test_ray_batch_gives_the_same_report(local_batch, tmp_path):
    pytest.importorskip("ray", reason="ray is not installed (pip install 'r2s[ray]')")
    local_root, _ = local_batch
    root = make_root(tmp_path / "data")
    outcome = run_batch(root, BatchConfig(jobs=2, executor="ray", **CHEAP))
    assert outcome.failed == 0, [s.error for s in outcome.scenes]
    ray_rows, local_rows = rows(root / "report.csv"), rows(local_root / "report.csv")
    assert len(ray_rows) == 5
    for a, b in zip(ray_rows, local_rows):
        a = {k: v for k, v in a.items() if k not in ("wall_s", "time_per_scene_s")}
        b = {k: v for k, v in b.items() if k not in ("wall_s", "time_per_scene_s")}
        assert a == b
