"""The scene-level size check of the priors against the depth (r2s/geometry/sanity.py
``priors_disagree_with_depth``, a warning from init): a depth unit off by 2 makes every
object look twice its prior's size, which no single prior's check (3x either way) sees."""

from __future__ import annotations

import pytest

from helpers_diagnose import write_scene
from r2s.geometry.sanity import SCENE_PRIOR_RATIO_RANGE, priors_disagree_with_depth
from r2s.runner.base import run_stage
from r2s.runner.registry import get_stage


def test_the_median_ratio_decides_and_one_prior_says_nothing():
    assert priors_disagree_with_depth([1.1, 1.25, 1.5]) is None
    assert priors_disagree_with_depth([0.6]) is None  # one prior may simply be wrong
    larger = priors_disagree_with_depth([0.66, 0.7, 1.3])
    assert larger is not None and "0.7x" in larger and "seen larger" in larger
    assert "depth_unit_m" in larger
    smaller = priors_disagree_with_depth([2.6, 2.4])
    assert smaller is not None and "seen smaller" in smaller
    lo, hi = SCENE_PRIOR_RATIO_RANGE
    assert priors_disagree_with_depth([lo, lo]) is None and priors_disagree_with_depth([hi, hi]) is None


@pytest.mark.slow
def test_init_warns_when_the_depth_reads_twice_as_far(tmp_path):
    """The four exact priors of the hand-made scene: no warning as rendered; with the depth
    read 2x long the median ratio falls to about 0.55 and init says so in one line."""
    init = get_stage("init")
    for scale, warned in ((1.0, False), (2.0, True)):
        scene = write_scene(tmp_path / f"x{scale:g}", depth_scale=scale)
        result = run_stage(init, scene, init.options_type())
        lines = [f for f in result.summary["flags"] if "depth_unit_m" in f]
        assert bool(lines) == warned, (scale, result.summary["flags"])
