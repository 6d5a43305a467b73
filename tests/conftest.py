"""Shared fixtures: a tiny hand-made scene in the contract format, the peer demo scene."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault("MUJOCO_GL", os.environ["PYOPENGL_PLATFORM"])  # read at import

REPO = Path(__file__).resolve().parents[1]
SEED_DEMO = REPO.parent / "shared" / "seed_demo" / "ycb5"
SAMPLE_SCENE = REPO / "sample_data" / "tabletop5"


def write_tiny_input(scene: Path, width: int = 64, height: int = 48) -> Path:
    """A camera 0.5 m above a table looking straight down, one 20x16-pixel 'object'.

    The object's pixels are 2 cm closer than the table. Returns the scene directory.
    """
    inp = scene / "input"
    inp.mkdir(parents=True)
    fx = 60.0
    K = [[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1]]
    # camera at z=0.5 looking down -z: camera z axis = world -z, x = world x, y = world -y
    world_from_camera = [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 0.5], [0, 0, 0, 1]]
    (inp / "camera.json").write_text(json.dumps(
        {"width": width, "height": height, "K": K, "world_from_camera": world_from_camera,
         "depth_unit_m": 0.001}))
    depth = np.full((height, width), 0.5, np.float32)
    masks = np.zeros((height, width), np.uint8)
    masks[16:32, 22:42] = 1
    depth[masks == 1] = 0.48
    np.save(inp / "depth.npy", depth)
    Image.fromarray(masks).save(inp / "masks.png")
    rgb = np.full((height, width, 3), 200, np.uint8)
    rgb[masks == 1] = (200, 40, 40)
    Image.fromarray(rgb).save(inp / "rgb.png")
    return scene


@pytest.fixture
def tiny_scene(tmp_path: Path) -> Path:
    return write_tiny_input(tmp_path / "scene")


@pytest.fixture
def seed_demo(tmp_path: Path) -> Path:
    """A writable copy of ../shared/seed_demo/ycb5 (skips when it is absent)."""
    if not SEED_DEMO.is_dir():
        pytest.skip("../shared/seed_demo/ycb5 not present")
    dst = tmp_path / "ycb5"
    shutil.copytree(SEED_DEMO, dst)
    for p in dst.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    return dst


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes (to check it was not modified)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}
