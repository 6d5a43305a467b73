"""A COM and friction repair that makes its object fall is undone (physopt rounds)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import r2s.physopt.repair as repair
from r2s.physopt.params import ObjectParams
from r2s.physopt.settings import RepairSettings


def _params() -> dict[int, ObjectParams]:
    box = np.full(3, 0.02)
    return {i: ObjectParams(world_from_object=np.eye(4), mass_kg=0.1, nominal_mass_kg=0.1,
                            com_in_object=np.zeros(3), friction=0.6, com_lo=-box, com_hi=box)
            for i in (1, 2)}


def _fake_engine(monkeypatch, drift_of) -> list[dict]:
    """The repair moves every mover's COM 5 mm along x and raises its friction to 1; the
    check answers ``drift_of(params)``. Returns the list of checked parameter sets."""
    checked: list[dict] = []

    def fake_repair(make_world, params, movers, result, rnd, settings, log):
        return {**params, **{i: replace(params[i], com_in_object=np.array([0.005, 0, 0]),
                                        friction=1.0) for i in movers}}

    def fake_check(make_world, params, orders, duration_s):
        checked.append(params)
        return drift_of(params)

    monkeypatch.setattr(repair, "mass_and_friction_repair", fake_repair)
    monkeypatch.setattr(repair, "check", fake_check)
    return checked


def _repaired(p: ObjectParams) -> bool:
    return p.friction == 1.0


def test_a_repair_that_makes_its_object_fall_is_undone(monkeypatch):
    # object 1 creeps (2 mm, 20 deg) and its repair makes it fall 120 mm, past the judge's
    # 50 mm; object 2's repair halves its drift
    def drift_of(params):
        one = (0.120, 90.0) if _repaired(params[1]) else (0.002, 20.0)
        two = (0.004, 1.0) if _repaired(params[2]) else (0.008, 4.0)
        return {1: one, 2: two}

    checked = _fake_engine(monkeypatch, drift_of)
    settings = RepairSettings()
    start = _params()
    log = {"objects": {1: [], 2: []}, "rounds": []}
    kept_back: set[int] = set()
    out, drifts = repair._unseen_repair_checked(None, start, [1, 2], drift_of(start), [[1, 2]],
                                                (1, 1), settings, log, kept_back)
    assert kept_back == {1}
    assert out[1] is start[1]  # COM and friction back
    assert _repaired(out[2]) and np.allclose(out[2].com_in_object, [0.005, 0, 0], atol=1e-12)
    assert drifts == {1: (0.002, 20.0), 2: (0.004, 1.0)}
    assert len(checked) == 2 and "moved 2 -> 120 mm" in log["objects"][1][0]
    # the next round leaves object 1's COM and friction alone: one check, nothing undone
    checked.clear()
    out2, _ = repair._unseen_repair_checked(None, out, [1, 2], drifts, [[1, 2]], (2, 2),
                                            settings, log, kept_back)
    assert out2[1] is start[1] and len(checked) == 1


@pytest.mark.parametrize("before_m, after_m, undone", [
    (0.002, 0.049, False),  # more drift, but it does not fall
    (0.060, 0.200, False),  # it fell before the repair already
    (0.049, 0.050, True),   # exactly the judge's 50 mm: it falls
])
def test_only_a_repair_that_makes_the_object_fall_is_undone(monkeypatch, before_m, after_m,
                                                             undone):
    def drift_of(params):
        return {1: (after_m if _repaired(params[1]) else before_m, 30.0), 2: (0.0, 0.0)}

    _fake_engine(monkeypatch, drift_of)
    start = _params()
    out, _ = repair._unseen_repair_checked(
        None, start, [1], drift_of(start), [[1, 2]], (1, 1), RepairSettings(),
        {"objects": {1: [], 2: []}, "rounds": []}, set())
    assert _repaired(out[1]) is not undone


@pytest.mark.parametrize("before, after, undone", [
    ((0.002, 3.1), (0.006, 12.8), True),   # crept 3.1 deg, tips 12.8 deg: fails the judge's 5
    ((0.002, 3.1), (0.002, 4.9), False),   # turns more, still under 5 deg
    ((0.002, 6.0), (0.003, 20.0), False),  # it failed by rotation before the repair already
    ((0.002, 4.9), (0.002, 5.0), True),    # exactly the judge's 5 deg: it fails
])
def test_undo_tipping_repairs_undoes_a_repair_that_tips_its_object_past_the_judge(
        monkeypatch, before, after, undone):
    def drift_of(params):
        return {1: after if _repaired(params[1]) else before, 2: (0.0, 0.0)}

    _fake_engine(monkeypatch, drift_of)
    start = _params()
    for option in (False, True):
        log = {"objects": {1: [], 2: []}, "rounds": []}
        out, _ = repair._unseen_repair_checked(
            None, start, [1], drift_of(start), [[1, 2]], (1, 1),
            RepairSettings(undo_tipping_repairs=option), log, set())
        assert _repaired(out[1]) is not (undone and option)  # off (the default): kept
        if undone and option:
            assert f"turned {before[1]:.1f} -> {after[1]:.1f} deg" in log["objects"][1][0]


def test_undoing_is_an_option(monkeypatch):
    def drift_of(params):
        return {1: (0.120, 90.0) if _repaired(params[1]) else (0.002, 2.0), 2: (0.0, 0.0)}

    _fake_engine(monkeypatch, drift_of)
    start = _params()
    out, drifts = repair._unseen_repair_checked(
        None, start, [1], drift_of(start), [[1, 2]], (1, 1),
        RepairSettings(undo_falling_repairs=False), {"objects": {1: [], 2: []}, "rounds": []},
        set())
    assert _repaired(out[1]) and drifts[1] == (0.120, 90.0)
