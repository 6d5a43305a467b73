"""The structure of each residual, as JSON-able summaries (what the report shows).

- registration: per-object prior scale, depth, fit quality; the scales' weighted mean;
- support: tilt angle (deg) and axis of the table normal against ``up``;
- physics: per object, translation, rotation angle and axis; the objects that move; the
  mean horizontal direction of the movers and how aligned they are (1 = all the same way,
  the mark of a tilted gravity);
- interaction: observed and predicted displacement per object;
- depth: observed minus rendered depth binned by depth and by image radius, on objects
  and on the table.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from r2s.diagnose.stats.blocks import blocks_of, tilt_vector
from r2s.diagnose.data import DepthMapData, PhysicsData, Residuals


def block_table(res: Residuals) -> dict[str, dict]:
    """Per block: n, sse, and its entries."""
    return {name: {"n": b.n, "sse": b.sse, "unit": b.unit,
                   "entries": [{"label": lab, "value": float(v), "sigma": float(s)}
                               for lab, v, s in zip(b.labels, b.values, b.sigma)]}
            for name, b in blocks_of(res).items()}


def physics_structure(phys: PhysicsData) -> dict[str, Any]:
    up = -np.asarray(phys.base.gravity, dtype=np.float64)
    up /= np.linalg.norm(up)
    rows, movers = [], []
    for obj_id in sorted(phys.motion):
        m = phys.motion[obj_id]
        obj = phys.objects.get(obj_id)
        level = max(m.translation_norm_m / phys.sigma_translation_m,
                    m.angle_rad / phys.sigma_rotation_rad)
        axis = m.rotation_rad / m.angle_rad if m.angle_rad > 1e-9 else np.zeros(3)
        moving = bool(level > 2.0)
        rows.append({"id": int(obj_id), "translation_m": m.translation_m.tolist(),
                     "translation_mm": m.translation_norm_m * 1000.0,
                     "rotation_deg": float(np.degrees(m.angle_rad)), "axis": axis.tolist(),
                     "axis_horizontal": bool(abs(axis @ up) < 0.5) if m.angle_rad > 1e-9 else None,
                     "geometry_ok": None if obj is None else obj.geometry_ok,
                     "moving": moving})
        if moving and (obj is None or obj.geometry_ok):
            movers.append(m.translation_m - (m.translation_m @ up) * up)
    common = None
    alignment = None
    if movers:
        dirs = [v / np.linalg.norm(v) for v in movers if np.linalg.norm(v) > 1e-6]
        if dirs:
            mean = np.mean(dirs, axis=0)
            alignment = float(np.linalg.norm(mean))
            common = (mean / max(np.linalg.norm(mean), 1e-12)).tolist()
    return {"objects": rows, "moving_ids": [r["id"] for r in rows if r["moving"]],
            "common_direction": common, "direction_alignment": alignment,
            "gravity": np.asarray(phys.base.gravity).tolist(), "horizon_s": phys.horizon_s}


def depth_structure(dm: DepthMapData, bins: int = 8) -> dict[str, Any]:
    """Binned statistics of the depth residual (mm)."""
    h, w = dm.residual_m.shape
    v, u = np.mgrid[0:h, 0:w]
    radius = np.hypot(u - (w - 1) / 2, v - (h - 1) / 2) / np.hypot((w - 1) / 2, (h - 1) / 2)
    out: dict[str, Any] = {}
    for name, sel in (("objects", dm.on_object), ("table", ~dm.on_object)):
        ok = sel & np.isfinite(dm.residual_m) & np.isfinite(dm.depth_m)
        if ok.sum() < 10:
            out[name] = None
            continue
        r = dm.residual_m[ok] * 1000.0
        out[name] = {"mean_mm": float(np.mean(r)), "median_mm": float(np.median(r)),
                     "rms_mm": float(np.sqrt(np.mean(r ** 2))), "pixels": int(ok.sum()),
                     "by_depth": _binned(dm.depth_m[ok], r, bins),
                     "by_radius": _binned(radius[ok], r, bins)}
    return out


def _binned(x: np.ndarray, y: np.ndarray, bins: int) -> list[dict]:
    edges = np.quantile(x, np.linspace(0, 1, bins + 1))
    rows = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (x >= a) & (x <= b)
        if sel.sum() >= 5:
            rows.append({"from": float(a), "to": float(b), "median_mm": float(np.median(y[sel])),
                         "mad_mm": float(np.median(np.abs(y[sel] - np.median(y[sel])))),
                         "n": int(sel.sum())})
    return rows


def structure(res: Residuals) -> dict[str, Any]:
    """Every residual's structure (see the module docstring)."""
    out: dict[str, Any] = {}
    reg = res.registration
    if reg is not None:
        used = {o.id for o in reg.used()}
        rows = [{"id": o.id, "scale": o.scale, "depth_m": o.depth_m, "fitness": o.fitness,
                 "rmse_mm": o.rmse_m * 1000.0, "used": o.id in used} for o in reg.objects]
        scales = np.array([o.scale for o in reg.used()])
        out["registration"] = {
            "objects": rows, "scale_sigma": reg.scale_sigma,
            "mean_scale": float(np.exp(np.mean(np.log(scales)))) if len(scales) else None,
            "scale_spread": float(np.std(np.log(scales))) if len(scales) > 1 else None}
    sup = res.support
    if sup is not None:
        expected = sup.up if sup.model_normal is None else sup.model_normal
        tilt = tilt_vector(expected, sup.normal)
        angle = float(np.linalg.norm(tilt))
        out["support"] = {"tilt_deg": float(np.degrees(angle)),
                          "axis": (tilt / angle).tolist() if angle > 1e-12 else None,
                          "normal": np.asarray(sup.normal).tolist(),
                          "up": np.asarray(sup.up).tolist(), "points": sup.n_points,
                          "sigma_deg": float(np.degrees(sup.sigma_rad))}
    if res.physics is not None:
        out["physics"] = physics_structure(res.physics)
    inter = res.interaction
    if inter is not None:
        out["interaction"] = [{"id": int(i), "observed_m": np.asarray(inter.observed_m[i]).tolist(),
                               "predicted_m": np.asarray(inter.predicted_m.get(i, np.zeros(3)))
                               .tolist()} for i in sorted(inter.observed_m)]
    if res.depth_map is not None:
        out["depth"] = depth_structure(res.depth_map)
    return out


def sse_by_block(res: Optional[Residuals]) -> dict[str, float]:
    if res is None:
        return {}
    return {name: b.sse for name, b in blocks_of(res).items()}
