"""physopt's whole pass on loaded data: depenetration, the per-object differentiable step,
the PyBullet check-and-repair rounds bounded by the observation, and the displacement flags.

Frames: poses are (4, 4) ``world_from_object``; ``seen`` are the poses the objects were seen
at (init's state), ``centres_in_object`` (3,) each mesh's centroid in its object frame.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Optional

import numpy as np

from r2s.console import ProgressFn
from r2s.io.state import SceneState
from r2s.physopt.contact_foot import with_foot
from r2s.physopt.diffsim_guard import keep_diffsim_where_it_rests
from r2s.physopt.object_opt import optimise_objects
from r2s.physopt.observation_bound import ObservationBound, displacement_flags
from r2s.physopt.params import Drift, Params
from r2s.physopt.pull_back import pull_back
from r2s.physopt.support_prop import Hidden, fell, with_prop
from r2s.physopt.repair import (check, depenetrate_scene, judge_orders, verify_and_repair,
                                world_factory, worst_severity)
from r2s.physical.provenance import com_provenance, friction_provenance


@dataclass(frozen=True)
class Solved:
    """params: the final per-object parameters; drift: id -> (m, deg) the judge-like check
    measured last; flags: id -> why an object ended beyond the observation tolerance;
    displacement: id -> (m, deg) from where it was seen to where it ends (objects with a
    seen pose)."""

    params: Params
    drift: Drift
    flags: dict[int, str]
    displacement: dict[int, tuple[float, float]]


@dataclass(frozen=True)
class Prepared:
    """A scene ready for the repairs: ``params`` after depenetration and the diffsim step,
    and ``start``, id -> world_from_object (4, 4) after depenetration, where
    :func:`finish_scene`'s pull-back puts poses back towards."""

    params: Params
    start: dict[int, np.ndarray]


def prepare_scene(make_world, pieces: dict, params: Params, meshes: dict, state: SceneState,
                  order: list[int], opt, log: dict, progress: ProgressFn) -> Prepared:
    """The physopt pass up to the repairs: depenetration, the differentiable-simulation step
    (kept where it rests) and the contact feet (in ``pieces`` in place); ``make_world``:
    :func:`r2s.physopt.repair.world_factory` of ``pieces``; ``log`` (physopt/log.json's
    record) is extended in place. Deterministic, so two solves of one scene (with and
    without support props) share it."""
    progress("depenetration", 0.1)
    params = depenetrate_scene(make_world, params, order, log)
    start = {i: p.world_from_object for i, p in params.items()}
    if opt.use_diffsim:
        free = [i for i in order if params[i].movable]
        stepped = optimise_objects(params, meshes, state, free, opt, log, progress)
        params = (keep_diffsim_where_it_rests(
            make_world, params, stepped, [o.id for o in state.objects],
            {o.id for o in state.objects if o.source != "prior"}, opt, log)
            if opt.diffsim_guard else stepped)
    if opt.foot_height_m > 0:
        give_feet(make_world, pieces, params, [o.id for o in state.objects], state, opt, log)
    return Prepared(params, start)


def finish_scene(make_world, prepared: Prepared, meshes: dict, state: SceneState,
                 order: list[int], seen: dict[int, np.ndarray], opt, log: dict,
                 progress: ProgressFn) -> Solved:
    """The rest of the physopt pass from ``prepared`` (:func:`prepare_scene`): the repairs,
    bounded by the observation then free, and the pull-back towards where the solve started,
    depenetrated, where the scene still rests (:mod:`r2s.physopt.pull_back`); ``opt`` holds
    the repair and observation settings; ``log`` is extended in place."""
    centres = {i: m.centroid for i, m in meshes.items()}
    bound = ObservationBound(seen, centres, opt.observation_tolerance_m,
                             opt.observation_tolerance_deg) if opt.observation_bound else None
    params, drift = repair_bounded_then_free(make_world, dict(prepared.params), order,
                                              [o.id for o in state.objects], opt, log,
                                              progress, bound)
    if opt.pull_back:
        progress("poses back towards where the solve started", 0.95)
        params, drift = pull_back(make_world, params, drift, prepared.start, centres,
                                  [o.id for o in state.objects], opt, log,
                                  seen=seen if opt.pull_back_to_seen else None,
                                  one_by_one=opt.pull_back_one_by_one)
    flags, displacement = displacement_flags(
        seen, {i: p.world_from_object for i, p in params.items()}, centres,
        opt.observation_tolerance_m, opt.observation_tolerance_deg)
    log["observation_flags"] = {str(i): reason for i, reason in flags.items()}
    return Solved(params, drift, flags, displacement)


def give_feet(make_world, pieces: dict, params: Params, export_order: list[int],
              state: SceneState, opt, log: dict) -> None:
    """The objects that move in a first check get a flat foot under their lowest point
    (:mod:`r2s.physopt.contact_foot`), in ``pieces`` in place (the checks, and export, use
    them); ``log["feet"]``: id -> the foot's area, mm^2."""
    orders = judge_orders(export_order)
    movers = opt.moving(check(make_world, params, orders, opt.verify_duration_s))
    up = -np.asarray(state.gravity, dtype=float)
    feet = {}
    for i in movers:
        if not params[i].movable:
            continue
        footed, area = with_foot(pieces[i], params[i].world_from_object, up,
                                 opt.foot_height_m)
        if area > 0:
            pieces[i] = footed
            feet[str(i)] = round(area * 1e6, 1)
            log["objects"][i].append(f"foot of {area * 1e6:.0f} mm^2 under its lowest point")
    if feet:
        make_world.checked.clear()  # the rollouts remembered were of the footless pieces
    log["feet"] = feet


def give_props(make_world, pieces: dict, params: Params, export_order: list[int],
               parents: dict, state: SceneState, opt, log: dict,
               hidden: Optional[Hidden]) -> None:
    """Each object that falls off another in a first check (moves the judge's translation,
    or turns ``FALL_DEG``) gives its parent a hidden prop under it
    (:mod:`r2s.physopt.support_prop`), in ``pieces`` in place (the checks, and export, use
    them); ``log["support_props"]``: child id -> {"parent", "area_mm2"}."""
    orders = judge_orders(export_order)
    drifts = check(make_world, params, orders, opt.verify_duration_s)
    up = -np.asarray(state.gravity, dtype=float)
    props = {}
    for i, moved in sorted(drifts.items()):
        parent = parents.get(i, 0)
        if (not params[i].movable or parent not in pieces
                or not fell(moved, opt.judge_translation_m)):
            continue
        propped, area = with_prop(pieces[i], params[i].world_from_object, pieces[parent],
                                  params[parent].world_from_object, up, hidden)
        if area > 0:
            pieces[parent] = propped
            props[str(i)] = {"parent": parent, "area_mm2": round(area * 1e6, 1)}
            log["objects"][parent].append(
                f"hidden prop of {area * 1e6:.0f} mm^2 under object {i}, which fell off it")
    if props:
        make_world.checked.clear()  # the rollouts remembered were of the pieces before
    log["support_props"] = props


def repair_bounded_then_free(make_world, params: Params, order: list[int],
                              export_order: list[int], opt, log: dict, progress: ProgressFn,
                              bound) -> tuple[Params, Drift]:
    """The repair rounds bounded by the observation; where they leave an object moving by
    at least ``opt.free_attempt_severity`` of the judge's criterion, the same rounds again
    from the same start without the bound, kept only if fewer objects move after them
    (then ``log`` is the free attempt's, with ``bounded_attempt_moving``). The observation is
    kept whenever the bounded rounds suffice."""
    start_log = copy.deepcopy(log)
    bounded, drift = verify_and_repair(make_world, params, order, export_order, opt, log,
                                       progress, bound)
    still = opt.moving(drift)
    if bound is None or not still:
        return bounded, drift
    worst = worst_severity(drift, opt)
    if worst < opt.free_attempt_severity:
        log["free_attempt"] = (f"not run: the bounded repairs leave {sorted(still)} moving at "
                               f"{worst:.2f} of the judge's criterion at most")
        return bounded, drift
    free_log = copy.deepcopy(start_log)
    free, free_drift = verify_and_repair(make_world, params, order, export_order, opt,
                                         free_log, progress, None)
    if len(opt.moving(free_drift)) >= len(still):
        log["unbounded_attempt_moving"] = sorted(opt.moving(free_drift))
        return bounded, drift
    log.clear()
    log.update(free_log)
    log["bounded_attempt_moving"] = sorted(still)
    return free, free_drift


def physopt_provenance(p, notes: list[str], friction_init: float,
                       friction_bounds: tuple[float, float]) -> dict:
    """Where one object's physopt mass, friction and COM came from (r2s.physical.provenance);
    ``notes``: the object's entries in log.json (a friction raise reads "friction a -> b")."""
    raised = any("friction" in n and "->" in n for n in notes)
    mass = p.mass_provenance
    if abs(p.mass_kg - p.nominal_mass_kg) > 1e-9 * p.nominal_mass_kg:
        mass = {"source": "optimised", "nominal_kg": p.nominal_mass_kg, "prior": mass}
    return {"mass": mass,
            "friction": friction_provenance(p.friction, user=p.user_friction,
                                            initial=friction_init,
                                            bounds=tuple(friction_bounds),
                                            raised_for_stability=raised),
            "com": com_provenance(p.com_in_object, p.centroid_in_object)}
