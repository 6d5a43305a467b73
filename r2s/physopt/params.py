"""What physopt tunes per object, as frozen typed values (object frame, SI units).

A round of physopt never edits an object's parameters in place: it builds the next
:class:`ObjectParams` with :func:`dataclasses.replace`, so a kept snapshot of the scene
(``dict(params)``) stays what it was.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import partial
from typing import Iterable, Optional

import numpy as np

from r2s.geometry.mass_properties import mass_properties
from r2s.geometry.open_container import open_container
from r2s.io.state import SceneState
from r2s.physical.provenance import container_mass, nominal_mass

INNER_BOX_MARGIN = 0.3
"""The COM is kept inside the central box of the shape's bounding box that leaves this
fraction of each extent on either side (the central 40%)."""


def _frozen_array(values, shape: tuple[int, ...]) -> np.ndarray:
    out = np.array(values, dtype=np.float64).reshape(shape)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class ObjectParams:
    """One object's physics and pose.

    world_from_object : (4, 4) pose; mass_kg; nominal_mass_kg : volume x density (the
    prior the mass is bounded around); com_in_object : (3,) metres, object frame;
    friction : per-body coefficient; com_lo / com_hi : (3,) the COM's box (object frame);
    movable : False for an object held fixed (``--set only=ID`` keeps the rest).
    """

    world_from_object: np.ndarray
    mass_kg: float
    nominal_mass_kg: float
    com_in_object: np.ndarray
    friction: float
    com_lo: np.ndarray
    com_hi: np.ndarray
    movable: bool = field(default=True)
    mass_provenance: dict = field(default_factory=dict)
    """Where the nominal mass came from (:func:`r2s.physical.provenance.nominal_mass`)."""
    user_friction: Optional[float] = None
    """A friction given in input/objects.json: kept, never raised by a repair round."""
    centroid_in_object: Optional[np.ndarray] = None
    """(3,) the uniform-density centroid, to tell a repaired COM from the shape's own."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "world_from_object", _frozen_array(self.world_from_object, (4, 4)))
        for name in ("com_in_object", "com_lo", "com_hi"):
            object.__setattr__(self, name, _frozen_array(getattr(self, name), (3,)))

    def with_pose(self, world_from_object: np.ndarray) -> "ObjectParams":
        return replace(self, world_from_object=world_from_object)


Params = dict[int, ObjectParams]
"""Object id -> its parameters."""


def inner_box(bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COM bounds (lo, hi), each (3,), from a (2, 3) bounding box (object frame)."""
    lo, hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    return lo + INNER_BOX_MARGIN * (hi - lo), hi - INNER_BOX_MARGIN * (hi - lo)


def initial_params(state: SceneState, meshes: dict, pieces: dict,
                   density_kg_m3: Optional[float], mass_bounds: tuple[float, float],
                   friction_init: float, users: Optional[dict] = None) -> Params:
    """Start values: the state's estimates, else the uniform-density body; the mass
    clipped to ``mass_bounds`` times the nominal mass. The nominal mass is the user's
    (``users``: input/objects.json entries by id), else volume x the user's density, else
    ``density_kg_m3``, else the label's density (:mod:`r2s.physical.density_table`); a
    user's mass is not bounded around, it is kept. A completed shape that is an open
    container weighs its walls instead (:func:`r2s.physical.provenance.container_mass`)."""
    params: Params = {}
    for obj in state.objects:
        user = (users or {}).get(obj.id)
        volume = mass_properties(meshes[obj.id], pieces[obj.id], mass_kg=1.0).volume_m3
        nominal_kg, mass_prov = nominal_mass(obj.label, volume, user, density_kg_m3)
        if obj.source != "prior":
            nominal_kg, mass_prov = container_mass(partial(open_container, meshes[obj.id]),
                                                   nominal_kg, mass_prov)
        nominal = mass_properties(meshes[obj.id], pieces[obj.id], mass_kg=nominal_kg)
        lo, hi = (1.0, 1.0) if mass_prov["source"] == "user" else mass_bounds
        mass = obj.mass_kg if obj.mass_kg is not None else nominal.mass_kg
        user_mu = None if user is None else user.friction
        com_lo, com_hi = inner_box(meshes[obj.id].bounds)
        params[obj.id] = ObjectParams(
            world_from_object=obj.pose,
            mass_kg=float(np.clip(mass, lo * nominal.mass_kg, hi * nominal.mass_kg)),
            nominal_mass_kg=nominal.mass_kg,
            com_in_object=(obj.com_in_object if obj.com_in_object is not None
                           else nominal.com_in_object),
            friction=float(user_mu if user_mu is not None else obj.friction
                           if obj.friction is not None else friction_init),
            com_lo=com_lo, com_hi=com_hi, mass_provenance=mass_prov, user_friction=user_mu,
            centroid_in_object=np.asarray(nominal.com_in_object, dtype=float))
    return params


def keep_previous(params: Params, previous: SceneState, rerun: Iterable[int]) -> Params:
    """``--set only=ID``: objects outside ``rerun`` take their last physopt result and are
    held fixed; those in ``rerun`` start afresh."""
    rerun = set(rerun)
    out = {i: replace(p, movable=i in rerun) for i, p in params.items()}
    for obj in previous.objects:
        if obj.id in out and obj.id not in rerun:
            p = out[obj.id]
            out[obj.id] = replace(
                p, world_from_object=obj.pose,
                mass_kg=obj.mass_kg if obj.mass_kg is not None else p.mass_kg,
                com_in_object=(obj.com_in_object if obj.com_in_object is not None
                               else p.com_in_object),
                friction=obj.friction if obj.friction is not None else p.friction)
    return out


Drift = dict[int, tuple[float, float]]
"""Object id -> (COM translation m, rotation deg) over a rollout."""


def is_moving(drift: tuple[float, float], tolerance_m: float, tolerance_deg: float) -> bool:
    """The one "does it move" test: translation above ``tolerance_m`` or rotation above
    ``tolerance_deg``."""
    translation_m, rotation_deg = drift
    return translation_m > tolerance_m or rotation_deg > tolerance_deg


def drift_in_tolerances(drift: tuple[float, float], tolerance_m: float,
                        tolerance_deg: float) -> float:
    """How far a drift goes, in units of the at-rest tolerance: the larger of translation /
    ``tolerance_m`` and rotation / ``tolerance_deg`` (above 1: :func:`is_moving`)."""
    translation_m, rotation_deg = drift
    return max(translation_m / tolerance_m, rotation_deg / tolerance_deg)


def moving_objects(drifts: Drift, tolerance_m: float, tolerance_deg: float) -> list[int]:
    """Ids whose drift counts as moving, in ``drifts``' order."""
    return [i for i, d in drifts.items() if is_moving(d, tolerance_m, tolerance_deg)]
