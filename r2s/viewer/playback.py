"""The judge's rollout for the viewer's player: export/ re-simulated in PyBullet.

The rollout uses the judge's duration and step rate (evaluate/metrics.json) and records
poses at ``PLAYBACK_HZ``; the judge's own trajectory is not stored, so it is run again
(PyBullet is deterministic for the same scene, step and order of bodies).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from r2s.metrics.motion import ObjectMotion, object_motions
from r2s.sim.pybullet_bodies import connect_direct
from r2s.sim.pybullet_scene import load_export_scene
from r2s.sim.rollout import rollout

PLAYBACK_HZ = 30.0
"""Frames per second of the player."""


@dataclass(frozen=True)
class Playback:
    """Recorded poses of the rollout.

    ``ids`` (N,) object ids; ``times_s`` (T,); ``world_from_object`` (T, N, 4, 4);
    ``motions``: per object, how far it moved from the first to the last frame.
    """

    ids: np.ndarray
    times_s: np.ndarray
    world_from_object: np.ndarray
    motions: list[ObjectMotion]

    @property
    def moved_ids(self) -> list[int]:
        return [m.id for m in self.motions if m.moved]

    def frame_at(self, t_s: float) -> int:
        """Index of the last frame at or before ``t_s`` (clamped to the recording)."""
        return int(np.clip(np.searchsorted(self.times_s, t_s + 1e-9) - 1, 0, len(self.times_s) - 1))


def simulate_playback(export_dir: Path, duration_s: float, rate_hz: float,
                      record_hz: float = PLAYBACK_HZ) -> Playback:
    """Load ``export_dir`` into a fresh PyBullet DIRECT client and roll it out under gravity."""
    client = connect_direct()
    try:
        loaded = load_export_scene(client, Path(export_dir))
        traj = rollout(client, loaded, duration_s, rate_hz, record_hz)
    finally:
        pb.disconnect(physicsClientId=client)
    labels = {o.id: o.label for o in loaded.scene.objects}
    return Playback(ids=traj.ids, times_s=traj.times_s, world_from_object=traj.world_from_object,
                    motions=object_motions(traj, labels))
