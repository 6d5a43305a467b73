"""Textures written at a faster zlib level (r2s/io/mesh_io.py ``PNG_COMPRESS_LEVEL``) stay
exact: PNG is lossless, so the texels read back from a saved GLB and from the visual OBJ's
PNG equal the texels written, to the last bit."""

from __future__ import annotations

import numpy as np
import trimesh
from PIL import Image

from r2s.io.mesh_io import PNG_COMPRESS_LEVEL, load_mesh, save_mesh
from r2s.io.visual_mesh import write_visual_obj


def _textured_box(seed: int = 3) -> tuple[trimesh.Trimesh, np.ndarray]:
    rng = np.random.default_rng(seed)
    texels = rng.integers(0, 256, size=(64, 96, 3), dtype=np.uint8)
    box = trimesh.creation.box([0.05, 0.04, 0.03])
    uv = rng.random((len(box.vertices), 2))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(texels))
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return box, texels


def test_a_glb_texture_reads_back_exactly(tmp_path):
    box, texels = _textured_box()
    save_mesh(box, tmp_path / "box.glb")
    back = load_mesh(tmp_path / "box.glb")
    image = back.visual.material.baseColorTexture
    assert np.array_equal(np.asarray(image.convert("RGB")), texels)
    assert box.visual.material.baseColorTexture.encoderinfo["compress_level"] == PNG_COMPRESS_LEVEL


def test_the_visual_obj_png_reads_back_exactly(tmp_path):
    box, texels = _textured_box(seed=5)
    files = write_visual_obj(box, tmp_path, "box")
    assert files.png is not None
    assert np.array_equal(np.asarray(Image.open(tmp_path / files.png).convert("RGB")), texels)
