"""Residual blocks: each residual group as a vector of noise-normalised numbers.

A block holds raw residual values, their noise levels and a soft cap; its ``sse`` is the
sum of squares of ``cap * tanh(value / (sigma * cap))`` (plain chi-square for small
residuals; one wild object cannot dominate the total). Effects are compared through the
total SSE of all blocks (:mod:`r2s.diagnose.bic`).

Blocks:

- ``registration``: ``log(scale_i)`` per object with a prior (noise ``scale_sigma``; capped:
  a misregistered object is no evidence about the sensor).
- ``support``: the two components of the rotation taking ``up`` to the table normal,
  radians, in a frame orthogonal to ``up``.
- ``physics``: per object whose geometry fits the data, translation (m) and rotation (rad)
  magnitudes over the rollout.
- ``interaction``: per observed object, the 3 components of predicted minus observed
  displacement of a push.
- ``table_height``: the fitted table's distance from the camera minus the model's, m,
  where the declared world puts the table through its origin
  (:mod:`r2s.diagnose.stats.table_height`).
- ``table_shape``: per image tile, the mean distance of the table points to one plane
  fitted to all of them (:mod:`r2s.diagnose.stats.table_shape`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from r2s.diagnose.data import (InteractionData, PhysicsData, RegistrationData, Residuals,
                               SupportData, TableShapeData)


@dataclass(frozen=True)
class Block:
    """One residual group.

    values : (n,) raw residuals (``unit``); sigma : (n,) their noise levels;
    labels : what each entry is; cap : soft cap of a normalised entry (None = none).
    """

    name: str
    values: np.ndarray
    sigma: np.ndarray
    labels: tuple
    unit: str = ""
    cap: float | None = None

    @property
    def n(self) -> int:
        return int(len(self.values))

    def normalised(self) -> np.ndarray:
        """(n,) values / sigma, soft-capped."""
        r = np.asarray(self.values, dtype=np.float64) / np.asarray(self.sigma, dtype=np.float64)
        if self.cap is not None:
            r = self.cap * np.tanh(r / self.cap)
        return r

    @property
    def sse(self) -> float:
        return float(np.sum(self.normalised() ** 2))


def tangent_frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``up`` and each other (deterministic)."""
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    hint = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = hint - (hint @ up) * up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def tilt_vector(up: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(3,) rotation vector of the smallest rotation taking ``up`` to ``normal``."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    n = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    axis = np.cross(up, n)
    s, c = np.linalg.norm(axis), float(np.clip(up @ n, -1.0, 1.0))
    if s < 1e-15:
        return np.zeros(3)
    return axis / s * np.arctan2(s, c)


def registration_block(data: RegistrationData) -> Block:
    used = data.used()
    vals = np.array([np.log(o.scale) for o in used], dtype=np.float64)
    return Block("registration", vals, np.full(len(vals), data.scale_sigma),
                 tuple(f"object {o.id} log scale" for o in used), unit="log", cap=4.0)


def support_block(data: SupportData) -> Block:
    expected = data.up if data.model_normal is None else data.model_normal
    tilt = tilt_vector(expected, data.normal)
    e1, e2 = tangent_frame(data.up)
    vals = np.array([tilt @ e1, tilt @ e2])
    return Block("support", vals, np.full(2, data.sigma_rad), ("tilt e1", "tilt e2"),
                 unit="rad")


def table_height_block(data: SupportData) -> Block:
    """The fitted table's distance from the camera minus the model's (m), one entry."""
    return Block("table_height", np.array([data.height_m]), np.array([data.height_sigma_m]),
                 ("table farther than the model puts it",), unit="m", cap=6.0)


def physics_block(data: PhysicsData) -> Block:
    vals, sig, labels = [], [], []
    for obj_id in sorted(data.motion):
        obj = data.objects.get(obj_id)
        if obj is not None and not obj.geometry_ok:
            continue
        m = data.motion[obj_id]
        vals += [m.translation_norm_m, m.angle_rad]
        sig += [data.sigma_translation_m, data.sigma_rotation_rad]
        labels += [f"object {obj_id} translation", f"object {obj_id} rotation"]
    return Block("physics", np.array(vals, dtype=np.float64), np.array(sig, dtype=np.float64),
                 tuple(labels), unit="m|rad", cap=data.cap)


def interaction_block(data: InteractionData) -> Block:
    vals, labels = [], []
    for obj_id in sorted(data.observed_m):
        pred = np.asarray(data.predicted_m.get(obj_id, np.zeros(3)), dtype=np.float64)
        diff = pred - np.asarray(data.observed_m[obj_id], dtype=np.float64)
        vals += list(diff)
        labels += [f"object {obj_id} d{a}" for a in "xyz"]
    return Block("interaction", np.array(vals, dtype=np.float64),
                 np.full(len(vals), data.sigma_m), tuple(labels), unit="m", cap=6.0)


def table_shape_block(data: TableShapeData) -> Block:
    """Tile means of the table points' distance to their plane (m)."""
    tiles = data.tiles()
    return Block("table_shape", tiles.mean_m, np.full(len(tiles.mean_m), data.sigma_m),
                 tuple(f"tile at ({u:.0f}, {v:.0f}) px" for u, v in tiles.centre_px),
                 unit="m", cap=6.0)


def blocks_of(res: Residuals) -> dict[str, Block]:
    """Every block the residuals allow, by name."""
    out: dict[str, Block] = {}
    if res.registration is not None and res.registration.used():
        out["registration"] = registration_block(res.registration)
    if res.support is not None:
        out["support"] = support_block(res.support)
        if res.support.height_used:
            out["table_height"] = table_height_block(res.support)
    if res.physics is not None and res.physics.motion:
        out["physics"] = physics_block(res.physics)
    if res.interaction is not None and res.interaction.observed_m:
        out["interaction"] = interaction_block(res.interaction)
    if res.table_shape is not None and len(res.table_shape.points_camera) >= 100:
        out["table_shape"] = table_shape_block(res.table_shape)
    return out


def total_sse(blocks: dict[str, Block]) -> float:
    return float(sum(b.sse for b in blocks.values()))


def total_n(blocks: dict[str, Block]) -> int:
    return int(sum(b.n for b in blocks.values()))
