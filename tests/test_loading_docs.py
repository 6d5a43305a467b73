"""Every code block of docs/loading.md runs against an exported scene and gives the
scene's values."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from helpers_scene_export import BOX_MASS_KG, CAN_MASS_KG, exported_scene

DOC = Path(__file__).resolve().parents[1] / "docs" / "loading.md"


def _blocks() -> dict[str, str]:
    """{section heading: its python code block}."""
    text = DOC.read_text()
    out = {}
    for section in re.split(r"^## ", text, flags=re.M)[1:]:
        heading = section.splitlines()[0]
        code = re.findall(r"```python\n(.*?)```", section, flags=re.S)
        if code:
            out[heading.split()[0]] = code[0]
    return out


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return exported_scene(tmp_path_factory.mktemp("scene"))


def _run(name: str, export_dir: Path) -> dict:
    code = _blocks()[name]
    assert '"my_scene/export"' in code
    namespace: dict = {}
    exec(compile(code.replace('"my_scene/export"', repr(str(export_dir))), str(DOC), "exec"),
         namespace)
    return namespace


def test_the_doc_has_the_four_loaders():
    assert set(_blocks()) == {"PyBullet", "MuJoCo", "USD", "trimesh"}


def test_pybullet_snippet_keeps_the_files_inertia(export_dir: Path):
    import pybullet as pb

    ns = _run("PyBullet", export_dir)
    client, bodies = ns["client"], ns["bodies"]
    try:
        info = pb.getDynamicsInfo(bodies[1], -1, physicsClientId=client)
        assert info[0] == pytest.approx(BOX_MASS_KG)
        assert np.allclose(info[2], [BOX_MASS_KG / 12 * 0.02] * 3, rtol=1e-4)
        # the can: without the flag PyBullet would use its bounding box's inertia (5 % off)
        scene = json.loads((export_dir / "scene.json").read_text())
        can = np.asarray(scene["objects"][1]["inertia_about_com"])
        info = pb.getDynamicsInfo(bodies[2], -1, physicsClientId=client)
        assert np.allclose(sorted(info[2]), np.linalg.eigvalsh(can), rtol=1e-4)
        pos = pb.getBasePositionAndOrientation(bodies[1], physicsClientId=client)[0]
        assert np.allclose(pos, [0.02, -0.01, 0.05], atol=2e-3)  # at rest on the table
    finally:
        pb.disconnect(client)


def test_mujoco_snippet(export_dir: Path):
    pytest.importorskip("mujoco")
    ns = _run("MuJoCo", export_dir)
    assert ns["model"].body("object_2").mass[0] == pytest.approx(CAN_MASS_KG, rel=1e-6)
    assert np.allclose(ns["positions"][1], [0.02, -0.01, 0.05], atol=2e-3)


def test_usd_snippet(export_dir: Path):
    ns = _run("USD", export_dir)
    scene = json.loads((export_dir / "scene.json").read_text())
    for obj in scene["objects"]:
        got = ns["masses"][f"object_{obj['id']}"]
        assert got["mass_kg"] == pytest.approx(obj["mass_kg"], rel=1e-6)
        assert np.allclose(got["com_in_object"], obj["com_in_object"], atol=1e-7)
    assert np.allclose(ns["masses"]["object_1"]["principal_inertia"],
                       [BOX_MASS_KG / 12 * 0.02] * 3, rtol=1e-4)


def test_trimesh_snippet(export_dir: Path):
    ns = _run("trimesh", export_dir)
    box = ns["world_meshes"][1]
    assert np.allclose(box.bounds, [[-0.03, -0.06, 0.0], [0.07, 0.04, 0.1]], atol=1e-6)
    assert len(ns["whole"].geometry) == 3  # two objects and the support
    assert all(p.is_convex for p in ns["pieces"])
