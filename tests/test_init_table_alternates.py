"""init's completion down to the table, kept for physopt where a completed object stands on
others (r2s/stages/init.py ``_table_alternates``): which objects get one, against boxes
whose base heights are known."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from r2s.geometry.plane import PlaneFit
from r2s.stages import init as init_stage


def _box_at(base_m: float, height_m: float = 0.05) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A 4 cm box (object frame centred) posed with its base ``base_m`` above z = 0."""
    pose = np.eye(4)
    pose[2, 3] = base_m + height_m / 2
    return trimesh.creation.box((0.04, 0.04, height_m)), pose


@pytest.fixture
def table_completion(monkeypatch):
    """``_complete_shape`` replaced: the completion without the others as supports is the
    box ``to_table[id]`` (base height in metres), and the call is recorded."""
    calls = []
    to_table: dict[int, float] = {}

    def fake(scene, spec, observed, plane, o, *args, stand_on_others=True, **kwargs):
        assert stand_on_others is False
        calls.append(spec.id)
        mesh, pose = _box_at(to_table[spec.id])
        return SimpleNamespace(mesh=mesh, world_from_object=pose, bridged=False)

    monkeypatch.setattr(init_stage, "_complete_shape", fake)
    return calls, to_table


def test_only_a_completion_resting_on_others_gets_one_that_reaches_the_table(table_completion):
    calls, to_table = table_completion
    plane = PlaneFit(point=np.zeros(3), normal=np.array([0.0, 0.0, 1.0]), inliers=np.zeros(0, bool))
    scene = SimpleNamespace(objects=[SimpleNamespace(id=i) for i in (1, 2, 3, 4, 5)])
    shapes = {1: (*_box_at(0.0), None),                 # on the table: nothing to do
              2: (*_box_at(0.054), None),               # lies on something 54 mm up
              3: (*_box_at(0.030), None),               # 30 mm up, to the table only 25 mm
              4: (*_box_at(0.040), "prior"),            # a registered prior keeps its shape
              5: (*_box_at(0.040), None)}               # has a second completion already
    to_table.update({2: 0.0, 3: 0.025})
    out = init_stage._table_alternates(scene, {}, shapes, plane, None, skip={5})
    assert sorted(calls) == [2, 3]
    assert list(out) == [2]
    mesh, pose, kind = out[2]
    assert kind == "completion to the table"
    assert init_stage._base_height_m(mesh, pose, plane) == pytest.approx(0.0, abs=1e-9)
    assert init_stage._base_height_m(*shapes[2][:2], plane) == pytest.approx(0.054, abs=1e-9)


def test_only_a_face_standing_on_the_table_gets_a_deepened_completion(monkeypatch):
    """``_deepened_alternates``: with the hidden back and the completion replaced, an object
    gets one only when completed (not a prior), standing on the table (not 54 mm up), not
    skipped, without an inferred top, with a back (``hidden_back`` not None), and only
    where the new shape is at least 10 mm deeper along the view (the camera looks along +y;
    object 6's completion is 6 mm deeper, object 1's 36 mm)."""
    plane = PlaneFit(point=np.zeros(3), normal=np.array([0.0, 0.0, 1.0]), inliers=np.zeros(0, bool))
    camera = SimpleNamespace(world_from_camera=np.eye(4))
    camera.world_from_camera[:3, 3] = (0.0, -0.6, 0.35)
    scene = SimpleNamespace(objects=[SimpleNamespace(id=i) for i in (1, 2, 3, 4, 5, 6, 7)],
                            camera=camera)
    shapes = {1: (*_box_at(0.0), None), 2: (*_box_at(0.054), None), 3: (*_box_at(0.0), "prior"),
              4: (*_box_at(0.0), None), 5: (*_box_at(0.0), None), 6: (*_box_at(0.0), None),
              7: (*_box_at(0.0), None)}
    deeper_by = {1: 0.036, 6: 0.006}
    calls = []

    def fake_complete(scene, spec, observed, plane, o, *args, **kwargs):
        calls.append(spec.id)
        assert spec.id in observed.hidden_tops  # completed with its back
        mesh = trimesh.creation.box((0.04, 0.04 + deeper_by[spec.id], 0.05))
        pose = np.eye(4)
        pose[1, 3], pose[2, 3] = deeper_by[spec.id] / 2, 0.025
        return SimpleNamespace(mesh=mesh, world_from_object=pose)

    monkeypatch.setattr(init_stage, "_complete_shape", fake_complete)
    monkeypatch.setattr(init_stage, "hidden_back",
                        lambda pts, *a, **k: None if len(pts) == 0 else np.zeros((3, 3)))
    observed = init_stage.ObservedPoints({i: (np.zeros((0 if i == 7 else 5, 3)), None)
                                          for i in shapes})
    observed.hidden_tops = {5: object()}
    out = init_stage._deepened_alternates(scene, observed, shapes, plane,
                                          SimpleNamespace(completion_cell_m=0.002), skip={4})
    assert sorted(calls) == [1, 6]
    assert list(out) == [1]
    assert out[1][2] == "deepened completion"
    assert init_stage._view_depth_m(*out[1][:2], plane, camera.world_from_camera[:3, 3]) == \
        pytest.approx(0.076, abs=1e-9)
