"""Injected effects: controlled deviations from the nominal setup, recorded only in gt/.

========================  ============================================================
``depth_scale``           observed depth = true depth x value (e.g. 1.03)
``depth_offset_m``        observed depth = true depth + value
``camera_rotation_deg``   camera.json's world_from_camera is the true one turned by value
                          about a random world axis through the camera centre
``com_offset_m``          the true COM of one object (or all, see ``com_offset_scope``)
                          is moved by value in a random horizontal direction
``com_offset_scope``      ``one`` (default) or ``all``
``friction``              every object's friction is value
``table_tilt_deg``        the support plane is tilted by value about a random horizontal
                          axis (gravity stays (0, 0, -9.81))
``lens_k1``, ``lens_k2``  radial lens distortion of the RGB-D camera (Brown's model,
                          r2s.geometry.lens): the rendered RGB, depth and masks are
                          resampled as a lens with these coefficients records them;
                          camera.json keeps the ideal pinhole K (k1 < 0: barrel)
========================  ============================================================
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Literal, Optional

import numpy as np
from pydantic import BaseModel, ConfigDict

from r2s.errors import R2SError
from r2s.geometry.lens import distort_image

_RANGES: dict[str, tuple[float, float]] = {
    "depth_scale": (0.5, 2.0),
    "depth_offset_m": (-0.2, 0.2),
    "camera_rotation_deg": (0.0, 45.0),
    "com_offset_m": (0.0, 0.1),
    "friction": (0.01, 3.0),
    "table_tilt_deg": (0.0, 30.0),
    "lens_k1": (-0.5, 0.5),
    "lens_k2": (-0.5, 0.5),
}
EFFECT_NAMES: tuple[str, ...] = tuple(_RANGES) + ("com_offset_scope",)


class Effects(BaseModel):
    """Parsed effects; None means not injected."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    depth_scale: Optional[float] = None
    depth_offset_m: Optional[float] = None
    camera_rotation_deg: Optional[float] = None
    com_offset_m: Optional[float] = None
    com_offset_scope: Literal["one", "all"] = "one"
    friction: Optional[float] = None
    table_tilt_deg: Optional[float] = None
    lens_k1: Optional[float] = None
    lens_k2: Optional[float] = None

    @property
    def any(self) -> bool:
        return any(getattr(self, name) is not None for name in _RANGES)


def parse_effects(raw: dict[str, object]) -> Effects:
    """Validate ``NAME -> VALUE`` pairs (values as strings or numbers).

    Raises :class:`R2SError` with one line naming the first bad effect.
    """
    values: dict[str, object] = {}
    for name, value in raw.items():
        if name not in EFFECT_NAMES:
            raise R2SError(f"unknown effect {name!r} (known: {', '.join(EFFECT_NAMES)})")
        if name == "com_offset_scope":
            if str(value) not in ("one", "all"):
                raise R2SError(f"effect com_offset_scope={value}: expected one or all")
            values[name] = str(value)
            continue
        try:
            number = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise R2SError(f"effect {name}={value}: expected a number") from None
        lo, hi = _RANGES[name]
        if not (lo <= number <= hi):
            raise R2SError(f"effect {name}={value}: must be within [{lo:g}, {hi:g}]")
        values[name] = number
    if "com_offset_scope" in values and "com_offset_m" not in values:
        raise R2SError("effect com_offset_scope needs com_offset_m")
    return Effects(**values)


def lens_coefficients(effects: Effects) -> Optional[tuple[float, float]]:
    """(k1, k2) of the injected lens distortion, None when none is injected."""
    if effects.lens_k1 is None and effects.lens_k2 is None:
        return None
    return float(effects.lens_k1 or 0.0), float(effects.lens_k2 or 0.0)


def distorted_frame(frame: Any, K: np.ndarray, effects: Effects) -> Any:
    """The rendered frame (``rgb``, ``depth_m``, ``segment``) as a lens with the injected
    radial distortion records it (unchanged without one): depth and segment by nearest
    sample (no blending across edges), rgb bilinear; pixels seen through no part of the
    ideal image read no depth and no object."""
    coeffs = lens_coefficients(effects)
    if coeffs is None:
        return frame
    k1, k2 = coeffs
    return replace(frame,
                   rgb=distort_image(frame.rgb, K, k1, k2, nearest=False, fill=0.0),
                   depth_m=distort_image(frame.depth_m, K, k1, k2, nearest=True),
                   segment=distort_image(frame.segment, K, k1, k2, nearest=True, fill=-1))
