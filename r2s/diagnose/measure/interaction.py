"""An observed push (``input/interaction/``) and its simulation.

The layout is the one of docs/interaction.md (:mod:`r2s.io.interaction_input`):
``push.json`` is the push in ``r2s predict``'s action format, ``observed.json`` the
centre-of-mass displacement of each object seen before and after it (an object not listed
was not observed). The push is simulated exactly as ``r2s predict`` and ``r2s synth
--push`` do (:func:`r2s.interaction.push.run_push`): a heavy pusher dragged along the
waypoints by a stiff constraint, so it cannot pass through what it pushes, then removed
while the scene settles for ``settle_s``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np

from r2s.diagnose.data import PhysicsModel
from r2s.diagnose.measure.physics import WorldSpec, _poses, build_client, motion_between
from r2s.errors import InputError
from r2s.io.push_action import EndEffector, PushAction, Waypoint, read_action
from r2s.interaction.push import run_push
from r2s.io.input_scene import read_json_file
from r2s.io.interaction_input import read_observed

OBSERVED_FILE = "observed.json"


@dataclass(frozen=True)
class Push:
    """A straight-segment push of a sphere: (P, 3) waypoints ``path_m`` (world), pusher
    radius, one speed, settle time. Shorthand for a :class:`PushAction`."""

    path_m: np.ndarray
    radius_m: float = 0.01
    speed_mps: float = 0.1
    settle_s: float = 1.0

    def to_action(self) -> PushAction:
        path = np.asarray(self.path_m, dtype=np.float64)
        return PushAction(end_effector=EndEffector(type="sphere", radius_m=self.radius_m),
                          start=[float(x) for x in path[0]],
                          waypoints=[Waypoint(position=[float(x) for x in p],
                                              speed_mps=self.speed_mps) for p in path[1:]],
                          settle_s=self.settle_s)


def read_push(path: Path) -> tuple[PushAction, dict]:
    """The push of ``path`` (``input/interaction/push.json``) and ``{id: (3,) observed
    displacement}`` from ``observed.json`` beside it (empty when absent).

    Raises :class:`InputError` when either file is malformed.
    """
    path = Path(path)
    data = read_json_file(path)
    if isinstance(data, dict) and "pusher" in data:
        raise InputError(path, "old push layout (pusher.path_m); write the push in r2s "
                               "predict's action format and the displacements in "
                               "observed.json (docs/interaction.md)")
    action = read_action(path)
    observed_path = path.parent / OBSERVED_FILE
    if not observed_path.is_file():
        return action, {}
    observed = read_observed(observed_path)
    return action, {o.id: np.asarray(o.displacement_m, dtype=np.float64)
                    for o in observed.objects}


def simulate_push_motion(spec: WorldSpec, model: PhysicsModel,
                         push: Union[Push, PushAction]) -> dict:
    """{object id: :class:`~r2s.diagnose.data.Motion`} of the push under ``model`` (240 Hz)."""
    action = push.to_action() if isinstance(push, Push) else push
    c = build_client(spec, model)
    try:
        start = _poses(c)
        end = run_push(c.client, action, c.body_ids, c.coms)
    finally:
        c.close()
    return {i: motion_between(start[i], end[i], c.coms[i]) for i in start}


def simulate_push(spec: WorldSpec, model: PhysicsModel, push: Union[Push, PushAction]) -> dict:
    """{object id: (3,) COM displacement} of the push under ``model`` (240 Hz)."""
    return {i: m.translation_m for i, m in simulate_push_motion(spec, model, push).items()}
