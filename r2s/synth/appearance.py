"""Procedural albedo textures and texture coordinates for untextured meshes.

A texture is an (H, 2W, 3) uint8 image made of two copies of one (H, W) pattern side by
side; texture coordinates wrap once around the object's z axis (cylindrical) and use only
``u`` in [0, 0.5] plus the seam-crossing faces, which reach into the second copy. That
keeps a seam triangle from spanning the whole pattern without needing a repeating sampler
(PyBullet's software renderer reads outside [0, 1] as black).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

Rgb = tuple[float, float, float]


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cells: int) -> np.ndarray:
    """(H, W) float noise in about [-1, 1], smooth over ``shape / cells`` pixels."""
    coarse = rng.uniform(-1.0, 1.0, size=(cells + 1, cells + 1))
    zoom = (shape[0] / (cells + 1), shape[1] / (cells + 1))
    field = ndimage.zoom(coarse, zoom, order=3, mode="grid-wrap", grid_mode=True)
    return np.clip(field[: shape[0], : shape[1]], -1.5, 1.5)


def _blend(base: np.ndarray, colour: Rgb, weight: np.ndarray) -> np.ndarray:
    w = np.clip(weight, 0.0, 1.0)[..., None]
    return base * (1 - w) + np.asarray(colour, dtype=np.float64) * w


def _rectangles(rng: np.random.Generator, img: np.ndarray, colours: list[Rgb], count: int,
                v_range: tuple[float, float] = (0.0, 1.0), size: float = 0.25) -> None:
    h, w = img.shape[:2]
    for _ in range(count):
        rh = int(h * rng.uniform(0.03, size))
        rw = int(w * rng.uniform(0.03, size))
        r0 = int(h * rng.uniform(*v_range))
        c0 = int(rng.integers(0, w))
        rows = np.arange(r0, min(r0 + rh, h))
        cols = np.arange(c0, c0 + rw) % w
        img[np.ix_(rows, cols)] = colours[int(rng.integers(len(colours)))]


def pattern_image(pattern: str, colour: Rgb, accent: Rgb, rng: np.random.Generator,
                  size: int = 128) -> np.ndarray:
    """One (size, 2*size, 3) float image in [0, 1] of a named pattern.

    Patterns: ``band`` (a label around a can or bottle), ``patches`` (printed box),
    ``speckle`` (fruit, ball), ``solid`` (plastic), ``wood`` (grain), ``checker`` (Rubik's
    cube stickers).
    """
    h, w = size, 2 * size
    jitter = rng.uniform(0.9, 1.08)
    base = np.ones((h, w, 3)) * np.clip(np.asarray(colour) * jitter, 0, 1)
    dark = (0.08, 0.08, 0.08)
    white = (0.93, 0.93, 0.9)
    if pattern == "band":
        lo, hi = sorted(rng.uniform(0.2, 0.8, size=2))
        lo, hi = min(lo, 0.4), max(hi, 0.6)
        band = slice(int(lo * h), int(hi * h))
        base[band] = accent
        sub = base[band]
        _rectangles(rng, sub, [dark, white, colour], 14, size=0.3)
        base[band] = sub
    elif pattern == "patches":
        _rectangles(rng, base, [accent, white, dark], 18, size=0.35)
    elif pattern == "speckle":
        base = _blend(base, accent, 0.5 * (smooth_noise(rng, (h, w), 4) + 0.3))
        dots = rng.random((h, w)) < 0.01
        base[dots] = 0.7 * base[dots] + 0.3 * np.asarray(accent)
    elif pattern == "wood":
        wobble = smooth_noise(rng, (h, w), 3)
        u = np.linspace(0, 1, w)[None, :]
        grain = 0.5 + 0.5 * np.sin(2 * np.pi * (rng.uniform(6, 14) * u + 0.6 * wobble))
        base = _blend(base, accent, 0.6 * grain**3)
    elif pattern == "checker":
        palette = [(0.9, 0.15, 0.1), (0.1, 0.55, 0.2), (0.1, 0.3, 0.8), (0.95, 0.85, 0.1),
                   (0.95, 0.5, 0.05), (0.95, 0.95, 0.95)]
        cells = 12
        rows, cols = np.mgrid[0:h, 0:w]
        ci = (rows * cells // h) * 1000 + (cols * 2 * cells // w)
        keys = np.unique(ci)
        lut = {k: palette[int(rng.integers(len(palette)))] for k in keys}
        for k, c in lut.items():
            base[ci == k] = c
        border = ((rows * cells) % h < h * 0.12) | ((cols * 2 * cells) % w < w * 0.06)
        base[border] = dark
    elif pattern != "solid":
        raise ValueError(f"unknown texture pattern {pattern!r}")
    shade = 1.0 + 0.06 * smooth_noise(rng, (h, w), 6)
    return np.clip(base * shade[..., None], 0.0, 1.0)


def texture_image(pattern: str, colour: Rgb, accent: Rgb, rng: np.random.Generator,
                  size: int = 128) -> np.ndarray:
    """(size, 4*size, 3) uint8: the pattern twice side by side (see module docstring)."""
    one = pattern_image(pattern, colour, accent, rng, size)
    return (np.concatenate([one, one], axis=1) * 255.0 + 0.5).astype(np.uint8)


def cylindrical_uv(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy of ``mesh`` with texture coordinates wrapped around its z axis.

    Vertices of faces that cross the seam are duplicated so that no face spans the seam;
    ``u`` is in [0, 0.5] for the first copy of a :func:`texture_image` and up to ~0.5 + one
    face's width for seam faces; ``v`` is the height in [0, 1].

    Returns
    -------
    ``trimesh.Trimesh`` with ``visual.uv`` (V', 2); the same surface, the same object frame.
    """
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).copy()
    centre = mesh.bounds.mean(axis=0)
    u = (np.arctan2(verts[:, 1] - centre[1], verts[:, 0] - centre[0]) / (2 * np.pi)) % 1.0
    zmin, zmax = mesh.bounds[:, 2]
    v = (verts[:, 2] - zmin) / max(zmax - zmin, 1e-9)
    fu = u[faces]
    seam = (fu.max(axis=1) - fu.min(axis=1)) > 0.5
    extra_verts, extra_uv = [], []
    new_index: dict[int, int] = {}
    for f in np.nonzero(seam)[0]:
        for k in range(3):
            vi = int(faces[f, k])
            if u[vi] < 0.5:
                if vi not in new_index:
                    new_index[vi] = len(verts) + len(extra_verts)
                    extra_verts.append(verts[vi])
                    extra_uv.append((u[vi] + 1.0, v[vi]))
                faces[f, k] = new_index[vi]
    uv = np.column_stack([u, v])
    if extra_verts:
        verts = np.vstack([verts, np.asarray(extra_verts)])
        uv = np.vstack([uv, np.asarray(extra_uv)])
    uv[:, 0] *= 0.5
    out = trimesh.Trimesh(verts, faces, process=False)
    out.visual = trimesh.visual.TextureVisuals(uv=uv)
    return out


def table_texture(rng: np.random.Generator, size: int = 512) -> tuple[np.ndarray, str]:
    """A (size, size, 3) uint8 tabletop albedo and its kind (wood, laminate or cloth)."""
    kind = str(rng.choice(["wood", "laminate", "cloth"]))
    h = w = size
    if kind == "wood":
        colour = np.array([0.62, 0.45, 0.28]) * rng.uniform(0.85, 1.15)
        wobble = smooth_noise(rng, (h, w), 6)
        x = np.linspace(0, 1, w)[None, :]
        grain = 0.5 + 0.5 * np.sin(2 * np.pi * (rng.uniform(70, 110) * x + 0.5 * wobble))
        planks = 1.0 + 0.06 * np.repeat(rng.uniform(-1, 1, 16), -(-w // 16))[None, :w]
        fine = 1.0 + 0.03 * rng.normal(size=(h, w))
        img = np.ones((h, w, 3)) * colour * (
            (0.88 + 0.12 * grain**2) * planks * fine)[..., None]
    elif kind == "laminate":
        colour = np.array(rng.choice([[0.80, 0.80, 0.78], [0.55, 0.58, 0.62],
                                      [0.85, 0.82, 0.74]]))
        img = np.ones((h, w, 3)) * colour * (1 + 0.04 * smooth_noise(rng, (h, w), 8))[..., None]
    else:
        colour = np.array(rng.choice([[0.30, 0.38, 0.50], [0.32, 0.45, 0.36],
                                      [0.55, 0.52, 0.45]]))
        weave = 0.06 * np.sin(np.arange(w) * np.pi / 2)[None, :] * np.sin(
            np.arange(h) * np.pi / 2)[:, None]
        img = np.ones((h, w, 3)) * colour * (1 + weave + 0.05 * smooth_noise(
            rng, (h, w), 10))[..., None]
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8), kind
