"""physopt's PyBullet rounds: check the scene as the judge will, repair what moves.

The scene is rebuilt from frozen :class:`r2s.physopt.params.ObjectParams` for every check
(a fresh world per check: PyBullet's answer for a marginal contact depends on the order
bodies were created in and on the contact manifolds a world has accumulated). A round
moves the movers' COM over their support (:func:`com_repair`), raises their friction to
its upper bound, and settles the scene quasi-statically; when rounds run out with objects
moving, a damped dynamic rest is the last resort (:func:`damped_rest`). The best checked
state is kept (:func:`score`).

Repairs are bounded by the observation (:class:`r2s.physopt.observation_bound.ObservationBound`),
in tiers of least observation change (:func:`verify_and_repair`): the COM and friction
repairs, which change nothing the camera sees, are checked before any settling (and
undone for an object they make fall); settling and the damped rest may not carry an
object beyond ``repair_tolerance_m`` / ``_deg`` from where it was seen, then (objects
still moving) beyond the flagging tolerance; the unbounded repairs run only when an
object still drifts at least ``fallback_severity`` of the judge's criterion (what they
move far is flagged by the stage).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Optional, Sequence, Union

import numpy as np
import pybullet as pb

from r2s.console import ProgressFn
from r2s.forked_map import forked_map
from r2s.io.state import SceneState
from r2s.physopt.observation_bound import ObservationBound
from r2s.physopt.params import Drift, ObjectParams, Params
from r2s.physopt.settings import RepairSettings
from r2s.physopt.pybullet_world import (SimBody, World, build_world, depenetrate, drift,
                                        settle, settle_damped, world_gravity)

SHIFT_NOTED_M = 1e-4
"""A pose or COM change smaller than this is not logged."""


MakeWorld = Callable[[Params, Optional[Sequence[int]]], World]


def world_factory(pieces: dict, state: SceneState, order: list[int],
                  settings: RepairSettings) -> MakeWorld:
    """``make_world(params, body_order=None)``: a PyBullet world of the scene; an object
    that is not ``movable`` is static (mass 0) and cannot move."""
    def make_world(params: Params, body_order: Optional[Sequence[int]] = None) -> World:
        bodies = [SimBody(i, pieces[i], params[i].world_from_object,
                          params[i].mass_kg if params[i].movable else 0.0,
                          params[i].com_in_object, params[i].friction)
                  for i in (body_order or order)]
        return build_world(bodies, state.support.point, state.support.normal,
                           settings.support_friction, state.gravity)
    make_world.checked = {}  # type: ignore[attr-defined]  # the rollouts' memo (_remembered)
    make_world.order = list(order)  # type: ignore[attr-defined]
    return make_world


def _remembered(make_world: MakeWorld, key: tuple, rollout: Callable[[], dict]) -> dict:
    """``rollout()`` (a dict of one rollout's results in fresh worlds), remembered on
    ``make_world`` under ``key`` when it is :func:`world_factory`'s: a fresh PyBullet world
    is deterministic, and the repair rounds often repeat a rollout (a round that changed
    nothing; the unbounded attempt's first check, which is the bounded attempt's)."""
    memo = getattr(make_world, "checked", None)
    if memo is None:
        return rollout()
    if key not in memo:
        memo[key] = rollout()
    return {i: v.copy() if isinstance(v, np.ndarray) else v for i, v in memo[key].items()}


def _check_key(params: Params, orders: list[list[int]], duration_s: float) -> tuple:
    """Everything a fresh world of :func:`world_factory` takes from ``params``, exactly."""
    bodies = tuple((i, params[i].world_from_object.tobytes(), params[i].mass_kg,
                    params[i].movable, params[i].com_in_object.tobytes(), params[i].friction)
                   for i in sorted({i for o in orders for i in o}))
    return bodies, tuple(tuple(o) for o in orders), duration_s


def _rollout_key(make_world: MakeWorld, params: Params, started: list[int], kind: str,
                 *settings: float) -> tuple:
    """The key of a rollout in a world of ``make_world``'s default body order, started
    from the poses of ``started``."""
    return (kind, tuple(started), *settings) + _check_key(
        params, [list(getattr(make_world, "order", started))], 0.0)


def _remembered_rollout(make_world: MakeWorld, params: Params, order: list[int], kind: str,
                        simulate: Callable[..., dict], start: dict, *settings: float) -> dict:
    """``simulate(world, start, *settings)`` in a fresh world of ``params`` (closed after),
    remembered under its :func:`_rollout_key` (see :func:`_remembered`)."""
    def rollout() -> dict:
        world = make_world(params)
        try:
            return simulate(world, start, *settings)
        finally:
            world.close()

    return _remembered(make_world, _rollout_key(make_world, params, order, kind, *settings),
                       rollout)


def depenetrate_scene(make_world: MakeWorld, params: Params, order: list[int],
                      log: dict) -> Params:
    """Separate the collision geometry (children move, parents stay) before anything else."""
    world = make_world(params)
    try:
        fixed = depenetrate(world, order, movable={i for i in order if params[i].movable})
    finally:
        world.close()
    out = dict(params)
    for i in order:
        shift = float(np.linalg.norm(fixed[i][:3, 3] - params[i].world_from_object[:3, 3]))
        if shift > SHIFT_NOTED_M:
            log["objects"][i].append(f"depenetrated by {shift * 1000:.1f} mm")
        out[i] = params[i].with_pose(fixed[i])
    return out


def com_repair(world: World, oid: int, p: ObjectParams, max_step_m: float
               ) -> tuple[ObjectParams, float]:
    """Make a moving object's rest robust by its mass distribution (bounded, non-uniform
    density): the COM moves horizontally towards the centroid of the contacts that carry
    its weight (at most ``max_step_m``) and down along gravity (half of that), within the
    inner box of the shape. A COM over its support stops toppling; a lower COM turns the
    neutral balance of a round object on one contact into a stable one.

    Returns the new parameters and how far the COM moved (m).
    """
    pb.performCollisionDetection(physicsClientId=world.client)
    up = -np.asarray(world_gravity(world), dtype=float)
    up /= np.linalg.norm(up)
    pts = pb.getContactPoints(bodyA=world.body_ids[oid], physicsClientId=world.client)
    # contactNormalOnB points from the other body towards this one: up for a support
    support = [np.asarray(c[5]) for c in pts if float(np.dot(c[7], up)) > 0.3]
    pose = p.world_from_object
    com_world = pose[:3, :3] @ p.com_in_object + pose[:3, 3]
    delta = -up * (0.5 * max_step_m)
    if support:
        horizontal = np.mean(support, axis=0) - com_world
        horizontal -= up * float(horizontal @ up)
        horizontal *= min(1.0, max_step_m / max(float(np.linalg.norm(horizontal)), 1e-12))
        delta = delta + horizontal
    step = pose[:3, :3].T @ delta
    new_com = np.clip(p.com_in_object + step, p.com_lo, p.com_hi)
    moved = float(np.linalg.norm(new_com - p.com_in_object))
    if moved > SHIFT_NOTED_M:
        return replace(p, com_in_object=new_com), moved
    return p, moved


def judge_orders(export_order: list[int]) -> list[list[int]]:
    """The body-creation orders a check runs: the judge's (``export_order``) forwards and
    backwards."""
    return [export_order, export_order[::-1]] if len(export_order) > 1 else [export_order]


def check(make_world: MakeWorld, params: Params, orders: list[list[int]],
          duration_s: float) -> Drift:
    """The judge's test, in fresh worlds: per object the worst (translation m, rotation
    deg) over ``orders`` of body creation.

    Remembered for the same parameters (:func:`_remembered`)."""
    return _remembered(make_world, ("check",) + _check_key(params, orders, duration_s),
                       lambda: _check(make_world, params, orders, duration_s))


def _check(make_world: MakeWorld, params: Params, orders: list[list[int]],
           duration_s: float) -> Drift:
    """The orders' worlds are independent: they run side by side (:func:`forked_map`)."""
    def one_order(order: list[int]) -> dict[int, tuple[float, float]]:
        world = make_world(params, order)
        try:
            return drift(world, {i: params[i].world_from_object for i in order}, duration_s)
        finally:
            world.close()

    worst: Drift = {}
    for res in forked_map(one_order, orders):
        for i, (t, r) in res.items():
            a, b = worst.get(i, (0.0, 0.0))
            worst[i] = (max(a, t), max(b, r))
    return worst


def severity(drift: tuple[float, float], settings: RepairSettings) -> float:
    """One object's check drift (COM translation m, rotation deg) as a fraction of the
    judge's criterion (>= 1: fails)."""
    return max(drift[0] / settings.judge_translation_m, drift[1] / settings.judge_rotation_deg)


def severities(drifts: Drift, settings: RepairSettings) -> dict[int, float]:
    """Per object, its drift as a fraction of the judge's criterion (:func:`severity`)."""
    return {i: severity(d, settings) for i, d in drifts.items()}


def worst_severity(drifts: Drift, settings: RepairSettings) -> float:
    """The largest :func:`severity` of ``drifts`` (0 for none)."""
    return max(severities(drifts, settings).values(), default=0.0)


def score(drifts: Drift, settings: RepairSettings, params: Optional[Params] = None,
          bound: Optional[ObservationBound] = None) -> tuple:
    """Rank of a checked state, lower is better: fewest objects failing the judge's
    criterion; among those, the failures closest to passing (a state whose failures creep
    is a better start for the damped rest than one where they fly off); then fewest moving
    at all; then (with a ``bound``) fewest objects beyond the observation tolerance; then
    least drift. The bounded repairs come first (:func:`verify_and_repair`), so a state
    beyond the tolerance only wins when it is the only one that rests."""
    shares = severities(drifts, settings)
    failing = [i for i, s in shares.items() if s >= 1.0]
    far = 0
    if bound is not None and params is not None:
        far = len(bound.beyond({i: p.world_from_object for i, p in params.items()}))
    return (len(failing), round(sum(shares[i] for i in failing), 1),
            len(settings.moving(drifts)), far, sum(t for t, _ in drifts.values()))


def _drift_log(drifts: Drift) -> dict[str, list]:
    return {str(i): list(v) for i, v in drifts.items()}


def repair_round(make_world: MakeWorld, params: Params, order: list[int], movers: list[int],
                 result: Drift, rnd: int, settings: RepairSettings, log: dict,
                 bound: Optional[ObservationBound] = None, movers_only: bool = False
                 ) -> Params:
    """One round on the movers: COM towards the support, friction to its bound, then a
    quasi-static settle of the whole scene (:func:`settle_round`), whose moves are kept for
    every object or, with ``movers_only``, for the movers only (the others keep their
    poses). Returns the new parameters."""
    params = mass_and_friction_repair(make_world, params, movers, result, rnd, settings, log)
    return settle_round(make_world, params, order, rnd, settings, log, bound,
                        only=set(movers) if movers_only else None)


def mass_and_friction_repair(make_world: MakeWorld, params: Params, movers: list[int],
                             result: Drift, rnd: int, settings: RepairSettings, log: dict
                             ) -> Params:
    """The repairs the camera cannot see: the movers' COM towards their support
    (:func:`com_repair`) and their friction to its upper bound."""
    params = dict(params)
    if settings.com_repair:
        world = make_world(params)
        try:
            for i in movers:
                params[i], moved = com_repair(world, i, params[i], settings.max_com_step_m)
                if moved > SHIFT_NOTED_M:
                    log["objects"][i].append(f"round {rnd}: COM moved {moved * 1000:.1f} mm "
                                             "towards its support")
        finally:
            world.close()
    hi = settings.friction_bounds[1]
    for i in movers:
        if params[i].friction < hi and params[i].user_friction is None:
            log["objects"][i].append(f"round {rnd}: friction {params[i].friction:.2f} -> "
                                     f"{hi:.2f} (moved {result[i][0] * 1000:.1f} mm, "
                                     f"{result[i][1]:.1f} deg)")
            params[i] = replace(params[i], friction=hi)
    return params


def made_worse(before: tuple[float, float], after: tuple[float, float],
               settings: RepairSettings) -> bool:
    """Whether a repair made an object fall: its check drift (COM translation m, rotation
    deg) reaches ``judge_translation_m``, which it did not ``before``; with
    ``settings.undo_tipping_repairs`` also when it passed the judge's whole criterion
    (translation and rotation) before and fails it after, as an object that crept 3 deg
    and tips 13 deg once its COM moved."""
    if before[0] < settings.judge_translation_m <= after[0]:
        return True
    if not settings.undo_tipping_repairs:
        return False
    return severity(before, settings) < 1.0 <= severity(after, settings)


def _unseen_repair_checked(make_world: MakeWorld, params: Params, movers: list[int],
                           result: Drift, orders: list[list[int]], rnd_name: tuple,
                           settings: RepairSettings, log: dict, kept_back: set[int]
                           ) -> tuple[Params, Drift]:
    """The movers' COM and friction repair (:func:`mass_and_friction_repair`; not for the
    ids in ``kept_back``), checked and logged as round ``rnd_name`` (number, label).

    With ``settings.undo_falling_repairs``, a mover that the repair makes fall
    (:func:`made_worse`, against its drift in ``result``) gets its COM and friction back
    and joins ``kept_back`` (updated in place): the repair pushed the wrong way, as a COM
    moved towards contacts that tip the object over. The scene is then checked again.
    Returns the parameters and their check.
    """
    rnd, name = rnd_name
    repaired = mass_and_friction_repair(make_world, params, [i for i in movers
                                                              if i not in kept_back],
                                        result, rnd, settings, log)
    new = check(make_world, repaired, orders, settings.verify_duration_s)
    log["rounds"].append({"round": name, "action": "COM+friction", "bounded": True,
                          "moving": settings.moving(new), "drift": _drift_log(new)})
    if not settings.undo_falling_repairs:
        return repaired, new
    worse = [i for i in movers if not _same(params[i], repaired[i])
             and made_worse(result[i], new[i], settings)]
    if not worse:
        return repaired, new
    for i in worse:
        kept_back.add(i)
        how = (f"fall: moved {1000 * result[i][0]:.0f} -> {1000 * new[i][0]:.0f} mm"
               if new[i][0] >= settings.judge_translation_m else
               f"tip: turned {result[i][1]:.1f} -> {new[i][1]:.1f} deg")
        log["objects"][i].append(f"round {rnd}: COM and friction repair undone (it made "
                                 f"the object {how} in the check)")
    repaired = {**repaired, **{i: params[i] for i in worse}}
    new = check(make_world, repaired, orders, settings.verify_duration_s)
    log["rounds"].append({"round": name, "action": f"COM+friction undone for {worse}",
                          "bounded": True, "moving": settings.moving(new),
                          "drift": _drift_log(new)})
    return repaired, new


def settle_round(make_world: MakeWorld, params: Params, order: list[int], rnd: int,
                 settings: RepairSettings, log: dict,
                 bound: Optional[ObservationBound] = None,
                 only: Optional[set[int]] = None) -> Params:
    """Quasi-static settle of the whole scene; a settling move beyond the round's limit,
    with a ``bound`` one that carries an object beyond the observation tolerance, and with
    ``only`` the move of an object outside it, is refused (the object keeps its pose)."""
    params = dict(params)
    start = {i: params[i].world_from_object for i in order}
    settled = _remembered_rollout(make_world, params, order, "settle", settle, start,
                                  settings.settle_duration_s, settings.settle_reset_steps)
    last = rnd == settings.max_rounds
    limit = settings.final_settle_shift_m if last else settings.max_settle_shift_m
    for i in order:
        shift = float(np.linalg.norm(settled[i][:3, 3] - start[i][:3, 3]))
        if only is not None and i not in only:
            continue
        if bound is not None and not bound.allows(i, start[i], settled[i]):
            log["objects"][i].append(f"round {rnd}: settling would carry it beyond the "
                                     "observation tolerance; kept in place")
        elif shift <= limit:
            if shift > SHIFT_NOTED_M:
                log["objects"][i].append(f"round {rnd}: settled by {shift * 1000:.1f} mm")
            params[i] = params[i].with_pose(settled[i])
        else:
            log["objects"][i].append(f"round {rnd}: settling moved it "
                                     f"{shift * 1000:.0f} mm; kept in place")
    return params


def damped_rest(make_world: MakeWorld, params: Params, order: list[int],
                orders: list[list[int]], settings: RepairSettings, log: dict, current: Drift,
                movers_only: bool, bound: Optional[ObservationBound] = None
                ) -> Optional[tuple[Params, Drift]]:
    """Let the engine bring the scene to a damped dynamic rest (with ``movers_only``, the
    objects that passed the ``current`` check are held fixed meanwhile) and check it.

    Returns the rest parameters and their check, or None when something would move further
    than ``final_settle_shift_m`` (with a ``bound``: or beyond the observation tolerance,
    :meth:`ObservationBound.allows`).
    """
    still = set(settings.moving(current))
    held = {i: replace(params[i], movable=params[i].movable and i in still) for i in order} \
        if movers_only else params
    start = {i: params[i].world_from_object for i in order}
    rest = _remembered_rollout(make_world, held, order, "damped", settle_damped, start,
                               settings.rest_duration_s, settings.rest_damping)
    what = "damped rest (" + ("moving objects only" if movers_only else "whole scene") + ")"
    shifts = {i: float(np.linalg.norm(rest[i][:3, 3] - start[i][:3, 3])) for i in order}
    worst = max(shifts, key=shifts.get)
    far = [i for i in order if bound is not None and not bound.allows(i, start[i], rest[i])]
    if far:
        log["rounds"].append({"round": "rest", "action": what + " rejected",
                              "reason": f"object {far[0]} would end beyond the observation "
                                        "tolerance"})
        return None
    if shifts[worst] > settings.final_settle_shift_m:
        log["rounds"].append({"round": "rest", "action": what + " rejected",
                              "reason": f"object {worst} would move {shifts[worst] * 1000:.0f} mm"})
        return None
    params = {**params, **{i: params[i].with_pose(rest[i]) for i in order}}
    result = check(make_world, params, orders, settings.verify_duration_s)
    for i in order:
        if shifts[i] > SHIFT_NOTED_M:
            log["objects"][i].append(f"{what}: moved {shifts[i] * 1000:.1f} mm")
    log["rounds"].append({"round": "rest", "action": what, "moving": settings.moving(result),
                          "drift": _drift_log(result)})
    return params, result


Kept = tuple[tuple, Params, Drift, Union[int, str]]
"""(score, parameters, their check, the round that produced them)."""


def verify_and_repair(make_world: MakeWorld, params: Params, order: list[int],
                      export_order: list[int], settings: RepairSettings, log: dict,
                      progress: ProgressFn, bound: Optional[ObservationBound] = None
                      ) -> tuple[Params, Drift]:
    """Check, then repair rounds while anything moves, then the damped rest if needed.

    Rounds need not improve monotonically (settling one object can unsettle its
    neighbour), so the best checked state (:func:`score`) is returned with its check.
    ``export_order``: the order bodies are created in by the judge (checked forwards and
    backwards). With a ``bound`` the rounds and the rest run in tiers of least observation
    change: within ``repair_tolerance_m`` / ``_deg`` of where each object was seen; when
    objects still move, within the bound's (flagging) tolerance; the unbounded ones only
    when an object's drift is still at least ``fallback_severity`` of the judge's
    criterion.
    """
    orders = judge_orders(export_order)
    result = check(make_world, params, orders, settings.verify_duration_s)
    log["rounds"].append({"round": 0, "action": "check", "moving": settings.moving(result),
                          "drift": _drift_log(result)})

    def rank(drifts: Drift, candidate: Params) -> tuple:
        return score(drifts, settings, candidate, bound)

    best: Kept = (rank(result, params), params, result, 0)
    phases: list[tuple[Optional[ObservationBound], str]] = [(None, "")]
    if bound is not None:
        tight = replace(bound, tolerance_m=min(settings.repair_tolerance_m, bound.tolerance_m),
                        tolerance_deg=min(settings.repair_tolerance_deg, bound.tolerance_deg))
        phases = [(tight, ""), (bound, "b"), (None, "u")]
    for k, (limit, label) in enumerate(phases):
        if k > 0 and not settings.moving(best[2]):
            break
        if limit is None and bound is not None:
            worst = worst_severity(best[2], settings)
            if worst < settings.fallback_severity:
                break
            log["rounds"].append({"round": "fallback", "action": "unbounded repairs",
                                  "reason": f"after the observation-bounded repairs an object "
                                            f"drifts {worst:.2f} of the judge's criterion"})
        elif k > 0:
            log["rounds"].append({"round": "wider", "action": "repairs within the observation "
                                  "tolerance", "reason": "objects still move"})
        best = _repair_phase(make_world, best, order, orders, settings, log, progress, limit,
                             rank, label)
    log["kept"] = {"round": best[3], "moving": settings.moving(best[2])}
    return best[1], best[2]


def _same(a: ObjectParams, b: ObjectParams) -> bool:
    return (a.friction == b.friction
            and np.allclose(a.world_from_object, b.world_from_object, rtol=0, atol=SHIFT_NOTED_M)
            and np.array_equal(a.com_in_object, b.com_in_object))


def _repair_phase(make_world: MakeWorld, best: Kept, order: list[int],
                  orders: list[list[int]], settings: RepairSettings, log: dict,
                  progress: ProgressFn, bound: Optional[ObservationBound],
                  rank: Callable[[Drift, Params], tuple], label: str) -> Kept:
    """The rounds, then the damped rest, from the state ``best`` (its params and check);
    settling and rest bounded by ``bound`` when given. Returns the best state seen."""
    params, result = best[1], best[2]
    kept_back: set[int] = set()  # movers whose COM and friction repair was undone
    rnd = 0
    while rnd < settings.max_rounds:
        rnd += 1
        movers = settings.moving(result)
        if not movers:
            break
        progress(f"verification round {label}{rnd}: {len(movers)} moving",
                 0.5 + 0.5 * rnd / (settings.max_rounds + 1))
        before = params
        name = f"{label}{rnd}" if label else rnd
        if bound is None:
            # after bounded phases (label "u"), the unbounded rounds move only what still
            # moves: an object that rests within the observation tolerance keeps its pose
            params = repair_round(make_world, params, order, movers, result, rnd, settings,
                                  log, movers_only=bool(label))
        else:
            # least observation change first: COM and friction, checked before any settling,
            # which then moves only what still moves
            params, result = _unseen_repair_checked(make_world, params, movers, result,
                                                    orders, (rnd, name), settings, log,
                                                    kept_back)
            if rank(result, params) < best[0]:
                best = (rank(result, params), params, result, name)
            if not settings.moving(result):
                break
            checked = params
            params = settle_round(make_world, params, order, rnd, settings, log, bound,
                                  only=set(settings.moving(result)))
            if all(_same(checked[i], params[i]) for i in order) and \
                    not all(_same(before[i], params[i]) for i in order):
                continue  # settling refused everything; the check above is current
        if all(_same(before[i], params[i]) for i in order):
            # nothing changed, so the check would repeat: on to the last round (its larger
            # settling limit), or done
            rnd = max(rnd, settings.max_rounds - 1)
            continue
        result = check(make_world, params, orders, settings.verify_duration_s)
        log["rounds"].append({"round": name, "action": "friction+settle" if bound is None
                              else "settle", "bounded": bound is not None,
                              "moving": settings.moving(result), "drift": _drift_log(result)})
        if rank(result, params) < best[0]:
            best = (rank(result, params), params, result, name)
    if settings.moving(best[2]) and settings.rest_duration_s > 0 and settings.max_rounds > 0:
        for movers_only in (True, False):  # the least disturbing first
            trial = damped_rest(make_world, best[1], order, orders, settings, log, best[2],
                                movers_only, bound)
            if trial is not None and rank(trial[1], trial[0]) < best[0]:
                best = (rank(trial[1], trial[0]), trial[0], trial[1], f"{label}rest")
            if not settings.moving(best[2]):
                break
    return best
