"""r2s.forked_map: the same results as a plain loop, in order, from forked children; a
child that fails is recomputed here; PyBullet checks are bit-identical side by side."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from r2s.forked_map import THREADS_VARIABLE, cpu_budget, forked_map


def test_results_come_back_in_order_from_children():
    parent = os.getpid()
    out = forked_map(lambda x: (x * x, os.getpid()), range(5), workers=2)
    assert [v for v, _ in out] == [0, 1, 4, 9, 16]
    pids = [pid for _, pid in out]
    assert pids[0] == pids[2] == pids[4] == parent  # the first of each group runs here
    assert pids[1] != parent and pids[3] != parent


def test_one_worker_runs_everything_here():
    parent = os.getpid()
    assert [p for p in forked_map(lambda _: os.getpid(), range(3), workers=1)] == [parent] * 3


def test_a_child_that_dies_is_recomputed_here():
    parent = os.getpid()

    def dies_in_child(x):
        if os.getpid() != parent:
            os._exit(3)
        return x + 100

    assert forked_map(dies_in_child, [1, 2], workers=2) == [101, 102]


def test_an_error_reaches_the_caller():
    def fails_on_two(x):
        if x == 2:
            raise ValueError("two")
        return x

    with pytest.raises(ValueError, match="two"):
        forked_map(fails_on_two, [1, 2], workers=2)


def test_budget_follows_the_batch_share(monkeypatch):
    monkeypatch.setenv(THREADS_VARIABLE, "1")
    assert cpu_budget() == 1
    monkeypatch.setenv(THREADS_VARIABLE, "3")
    assert cpu_budget() == 3
    monkeypatch.setenv(THREADS_VARIABLE, "")
    assert cpu_budget() >= 1


def test_torch_in_a_child_after_the_parent_used_its_thread_pool_does_not_hang():
    # without the one-thread rule this script hangs (a 2-thread torch op in the child)
    script = textwrap.dedent("""
        import torch
        from r2s.forked_map import forked_map
        torch.set_num_threads(2)
        torch.randn(2_000_000).exp().sum()
        f = lambda k: float(torch.ones(2_000_000).exp().sum()) + k
        print(forked_map(f, [0, 1], workers=2))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    values = eval(done.stdout.strip().splitlines()[-1])  # noqa: S307  our own print
    assert values == pytest.approx([2e6 * np.e, 2e6 * np.e + 1], rel=1e-5)


def test_pybullet_checks_side_by_side_match_one_after_the_other(monkeypatch):
    import trimesh

    from r2s.io.state import SceneState, SupportPlane
    from r2s.physopt.params import ObjectParams, inner_box
    from r2s.physopt.repair import check, world_factory
    from r2s.physopt.settings import RepairSettings

    box = trimesh.creation.box((0.05, 0.05, 0.05))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    pose_box = np.eye(4)
    pose_box[:3, 3] = (0.0, 0.0, 0.025)
    pose_ball = np.eye(4)
    pose_ball[:3, 3] = (0.012, 0.0, 0.08)  # off the box's centre: it rolls off
    params = {}
    for i, mesh, pose, mass in ((1, box, pose_box, 0.1), (2, ball, pose_ball, 0.05)):
        lo, hi = inner_box(mesh.bounds)
        params[i] = ObjectParams(world_from_object=pose, mass_kg=mass, nominal_mass_kg=mass,
                                 com_in_object=np.zeros(3), friction=0.5, com_lo=lo, com_hi=hi)
    state = SceneState(stage="init", support=SupportPlane(point=[0, 0, 0], normal=[0, 0, 1]),
                       objects=[])
    pieces = {1: [box], 2: [ball]}
    orders = [[1, 2], [2, 1]]
    results = {}
    for budget in ("1", "2"):
        monkeypatch.setenv(THREADS_VARIABLE, budget)
        make_world = world_factory(pieces, state, [1, 2], RepairSettings())
        results[budget] = check(make_world, params, orders, 1.0)
    assert results["2"][2][0] > 0.01  # the ball moved: the check is not trivial
    assert results["1"] == results["2"]
