"""physopt flags what its repairs had to move far from where it was seen (init pose)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from r2s.io.state import read_state
from r2s.physopt.observation_bound import OBSERVATION_FLAG_KEY
from r2s.runner.base import run_stage
from r2s.stages.physopt import STAGE as PHYSOPT, Options as PhysOptions
from test_physopt_stage import _box_scene, _pose


@pytest.mark.slow
def test_box_seen_floating_is_dropped_and_flagged(tmp_path: Path):
    # a 6 cm cube seen 4 cm above the table: it can only rest 40 mm lower
    root = _box_scene(tmp_path / "s", [(1, "floating", 0.06, _pose(0.03 + 0.04)),
                                       (2, "resting", 0.06, _pose(0.03, x=0.2))])
    result = run_stage(PHYSOPT, root, PhysOptions(use_diffsim=False))
    assert result.summary["still_moving"] == 0
    state = read_state(root / "physopt")
    z = state.object(1).pose[2, 3]
    assert z == pytest.approx(0.03, abs=3e-3)
    assert result.summary["flagged_objects"] == 1
    reason = state.object(1).model_dump()[OBSERVATION_FLAG_KEY]
    moved_mm = round(1000 * (0.07 - z))
    assert reason.startswith(f"physopt moved {moved_mm} mm (> 20 mm)")
    assert OBSERVATION_FLAG_KEY not in state.object(2).model_dump()
    assert result.summary["warnings"] == [f"object 1: {reason}"]
    log = json.loads((root / "physopt" / "log.json").read_text())
    assert log["observation_flags"] == {"1": reason}
