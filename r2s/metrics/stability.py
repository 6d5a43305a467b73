"""Stability of a rollout (pure numpy on a :class:`r2s.sim.rollout.Trajectory`).

Per object, between the first and the last recorded sample:

- translation drift: distance moved by the centre of mass, metres;
- rotation drift: the rotation angle of ``R0^T R_end`` (``R`` = rotation of
  ``world_from_object``), degrees. The paper speaks of an "Euler angles change"; the angle
  of the relative rotation is its frame- and convention-independent version;
- stable: translation drift < ``translation_threshold_m`` (5 cm) and rotation drift <
  ``rotation_threshold_deg`` (5 deg), as in the paper;
- settling time: the first sample time after which the COM speed stays below
  ``rest_linear_mps`` and the angular speed below ``rest_angular_radps`` until the end;
  the rollout duration if the object is still moving at the end;
- mean linear / angular speed over all samples.

Scene level: ``stability_ratio`` (stable / all), and the means over objects of settling
time and speeds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from r2s.sim.rollout import Trajectory


@dataclass(frozen=True)
class ObjectStability:
    id: int
    translation_drift_m: float
    rotation_drift_deg: float
    stable: bool
    settling_time_s: float
    mean_linear_speed_mps: float
    mean_angular_speed_radps: float

    def as_dict(self) -> dict:
        return asdict(self)


def rotation_angle_deg(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Angle of ``rot_a^T rot_b``, degrees; ``rot_a``, ``rot_b`` : (..., 3, 3) -> (...)."""
    rel = np.swapaxes(rot_a, -1, -2) @ rot_b
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def settling_time_s(times_s: np.ndarray, at_rest: np.ndarray) -> float:
    """First time from which ``at_rest`` (T,) bool holds to the end; ``times_s[-1]`` if never."""
    moving = np.flatnonzero(~at_rest)
    if moving.size == 0:
        return float(times_s[0])
    last = int(moving[-1])
    return float(times_s[last + 1]) if last + 1 < len(times_s) else float(times_s[-1])


def object_stability(traj: Trajectory, translation_threshold_m: float = 0.05,
                     rotation_threshold_deg: float = 5.0, rest_linear_mps: float = 0.01,
                     rest_angular_radps: float = 0.1) -> list[ObjectStability]:
    """One :class:`ObjectStability` per object of ``traj``, in ``traj.ids`` order."""
    com = traj.com_world_m                                   # (T, N, 3)
    drift_t = np.linalg.norm(com[-1] - com[0], axis=-1)      # (N,)
    rot = traj.world_from_object[..., :3, :3]
    drift_r = rotation_angle_deg(rot[0], rot[-1])            # (N,)
    lin = np.linalg.norm(traj.linear_velocity_mps, axis=-1)  # (T, N)
    ang = np.linalg.norm(traj.angular_velocity_radps, axis=-1)
    at_rest = (lin < rest_linear_mps) & (ang < rest_angular_radps)
    out = []
    for k, obj_id in enumerate(traj.ids):
        stable = bool(drift_t[k] < translation_threshold_m and drift_r[k] < rotation_threshold_deg)
        out.append(ObjectStability(
            id=int(obj_id),
            translation_drift_m=float(drift_t[k]),
            rotation_drift_deg=float(drift_r[k]),
            stable=stable,
            settling_time_s=settling_time_s(traj.times_s, at_rest[:, k]),
            mean_linear_speed_mps=float(lin[:, k].mean()),
            mean_angular_speed_radps=float(ang[:, k].mean()),
        ))
    return out


def scene_stability(objects: list[ObjectStability]) -> dict:
    """Scene-level scalars; NaN (written as null) for a scene without objects."""
    if not objects:
        nan = float("nan")
        return {"stability_ratio": nan, "settling_time_s": nan,
                "mean_linear_speed_mps": nan, "mean_angular_speed_radps": nan}
    return {
        "stability_ratio": float(np.mean([o.stable for o in objects])),
        "settling_time_s": float(np.mean([o.settling_time_s for o in objects])),
        "mean_linear_speed_mps": float(np.mean([o.mean_linear_speed_mps for o in objects])),
        "mean_angular_speed_radps": float(np.mean([o.mean_angular_speed_radps for o in objects])),
    }
