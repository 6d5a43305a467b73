"""Prior or completion (r2s/geometry/prior_choice.py and init's ``prior_choice``): known
answers from ray-cast views of boxes on a table at z = 0."""

import numpy as np
import pytest
import trimesh

from helpers_init import SynthObject, default_camera, pose, render_view, write_input_scene
from r2s.geometry.camera import backproject
from r2s.geometry.prior_choice import ChoiceMargins, ViewScore, choose, score_in_view

WIDTH, HEIGHT = 320, 240


def _view():
    """A camera 40 deg above the table, 0.5 m away."""
    elevation = np.radians(40.0)
    eye = 0.5 * np.array([np.cos(elevation) * 0.8, -np.cos(elevation) * 0.6, np.sin(elevation)])
    return default_camera(WIDTH, HEIGHT, eye=tuple(eye), target=(0.0, 0.0, 0.03))


def _scene() -> list[SynthObject]:
    """A 12 x 6 x 4 cm box whose prior is 1.6 x too long (its x axis), and a 5 cm cube
    given its own shape, at poses 1 cm and 5 deg off."""
    box = trimesh.creation.box((0.12, 0.06, 0.04))
    long_box = trimesh.creation.box((0.192, 0.06, 0.04))
    cube = trimesh.creation.box((0.05, 0.05, 0.05))
    turn = trimesh.transformations.rotation_matrix(np.radians(5.0), [0, 0, 1])
    return [SynthObject(1, box, pose([0.05, 0.05, 0.02]), label="box", prior=long_box,
                        world_from_prior=pose([0.06, 0.05, 0.02]) @ turn),
            SynthObject(2, cube, pose([-0.07, -0.06, 0.025]), (60, 60, 200), label="cube",
                        prior=cube, world_from_prior=pose([-0.06, -0.06, 0.025]) @ turn)]


def _posed(mesh: trimesh.Trimesh, world_from: np.ndarray) -> trimesh.Trimesh:
    return mesh.copy().apply_transform(world_from)


def test_scores_of_the_true_shape_and_of_a_box_too_long():
    objects = _scene()
    K, world_from_camera = _view()
    _, depth, masks = render_view(objects, K, world_from_camera, WIDTH, HEIGHT)
    box, cube = objects
    pts = backproject(depth, K, world_from_camera, masks == 1)
    others = [(2, _posed(cube.mesh, cube.world_from_object))]
    truth = score_in_view(_posed(box.mesh, box.world_from_object), 1, others, pts, K,
                          world_from_camera, depth, masks)
    # the true shape at the true pose: only pixel-centre sampling differs
    assert truth.iou > 0.97 and truth.ucd_mm < 0.1 and truth.free_space == 0.0
    # the 1.6 x long prior centred on the truth: 3.6 cm of box past each end, in front of
    # table the camera saw (its silhouette about 1.4 x the mask's)
    long_box = score_in_view(_posed(box.prior, box.world_from_object), 1, others, pts, K,
                             world_from_camera, depth, masks)
    assert 0.55 < long_box.iou < 0.8
    assert long_box.free_space > 0.2
    # the observed end face lies inside the long prior, at most 2 cm from its top and sides
    assert 0.5 < long_box.ucd_mm < 3.0


def test_choose_needs_every_margin():
    prior = ViewScore(iou=0.70, ucd_mm=5.0, free_space=0.05)
    margins = ChoiceMargins(iou_gain=0.1, ucd_gain_mm=1.0, free_space_slack=0.02,
                            large_iou_gain=1.0, large_ucd_gain_mm=float("inf"))
    # the rules for a far better silhouette or UCD off
    assert choose(prior, ViewScore(0.85, 2.0, 0.01), margins)[0] == "completion"
    assert choose(prior, ViewScore(0.79, 2.0, 0.01), margins)[0] == "prior"  # IoU gain 0.09
    assert choose(prior, ViewScore(0.85, 4.5, 0.01), margins)[0] == "prior"  # UCD gain 0.5
    assert choose(prior, ViewScore(0.85, 2.0, 0.08), margins)[0] == "prior"  # free +0.03
    assert choose(prior, ViewScore(0.85, 2.0, 0.065), margins)[0] == "completion"


def test_a_far_better_silhouette_needs_no_ucd_margin():
    """fresh7 scene_01's cup: the prior's silhouette IoU 0.635, UCD 1.83 mm, free space
    0.013; the completion's 0.838, 1.38 mm, 0. Its UCD gain (0.45 mm) misses the 1 mm
    margin, its IoU gain (0.20) clears the large one (0.10)."""
    prior = ViewScore(iou=0.635, ucd_mm=1.83, free_space=0.013)
    margins = ChoiceMargins()
    assert choose(prior, ViewScore(0.838, 1.38, 0.0), margins)[0] == "completion"
    assert choose(prior, ViewScore(0.838, 1.84, 0.0), margins)[0] == "prior"   # UCD 0.01 worse
    assert choose(prior, ViewScore(0.730, 1.38, 0.0), margins)[0] == "prior"   # IoU gain 0.095
    assert choose(prior, ViewScore(0.838, 1.38, 0.034), margins)[0] == "prior"  # free +0.021
    assert choose(prior, ViewScore(0.838, 1.38, 0.032), margins)[0] == "completion"


def test_a_far_closer_surface_replaces_a_prior_of_about_the_same_silhouette():
    """fresh9 scene_00's banana: the prior (scale at its bound, 18 mm into the table) has
    silhouette IoU 0.639, UCD 5.72 mm, free space 0.001; the completion 0.627, 2.54 mm, 0.
    The UCD gain (3.2 mm) clears the 1 mm margin but the IoU is lower; the completion's UCD
    is under half the prior's, so it replaces the prior (CD against gt 9.8 -> 5.4 mm)."""
    prior = ViewScore(iou=0.639, ucd_mm=5.72, free_space=0.001)
    margins = ChoiceMargins()
    assert choose(prior, ViewScore(0.627, 2.54, 0.0), margins)[0] == "completion"
    assert choose(prior, ViewScore(0.627, 2.87, 0.0), margins)[0] == "prior"   # UCD 0.50x
    assert choose(prior, ViewScore(0.585, 2.54, 0.0), margins)[0] == "prior"   # IoU -0.054
    assert choose(prior, ViewScore(0.627, 2.54, 0.022), margins)[0] == "prior"  # free +0.021
    # a small UCD: 0.4 times the prior's, but the gain (1.8 mm) is under 2 mm
    small = ViewScore(iou=0.8, ucd_mm=3.0, free_space=0.0)
    assert choose(small, ViewScore(0.8, 1.2, 0.0), margins)[0] == "prior"


@pytest.mark.slow
def test_init_completes_a_prior_too_long_and_keeps_an_exact_one(tmp_path):
    from r2s.io.paths import ScenePaths
    from r2s.io.state import read_state
    from r2s.runner.base import run_stage
    from r2s.stages.init import STAGE, Options

    K, world_from_camera = _view()
    scene = write_input_scene(tmp_path / "scene", _scene(), WIDTH, HEIGHT, K=K,
                              world_from_camera=world_from_camera)
    result = run_stage(STAGE, scene, Options(icp_yaw_hypotheses=1))
    state = {o.id: o for o in read_state(ScenePaths(scene).stage_dir("init")).objects}
    assert {i: o.source for i, o in state.items()} == {1: "completed", 2: "prior"}
    box, cube = state[1].prior_choice, state[2].prior_choice
    assert box["chosen"] == "completion" and cube["chosen"] == "prior"
    # the completion of a box seen on three sides fits the view; the long prior cannot
    # (its scale is bounded to 0.85-1.15)
    assert box["completion"]["iou"] > 0.9 and box["prior"]["iou"] < 0.8
    assert cube["prior"]["iou"] > 0.95 and cube["prior"]["ucd_mm"] < 0.5
    # the cube stands alone on the table: its exact prior, set down there, rests (it only
    # drops the 0.5 mm set-down gap)
    assert cube["rest_alone"]["prior"]["moved_mm"] < 2.0
    assert cube["rest_alone"]["prior"]["turned_deg"] < 1.0
    assert abs(cube["rest_alone"]["prior"]["com_drop_mm"]) < 0.2  # the gap does not count
    assert result.summary["prior_choice"] == {"1": "completion", "2": "prior"}
    assert any(f.startswith("object 1: its prior was replaced by the completion")
               for f in result.summary["flags"])
    assert not any(f.startswith("object 2: its prior") for f in result.summary["flags"])
    forced = run_stage(STAGE, scene, Options(icp_yaw_hypotheses=1, prior_choice="prior"))
    assert forced.summary["completed"] == 0


def test_a_prior_is_kept_when_its_completion_fails(tmp_path, monkeypatch):
    """Where the observation cannot be completed (too few or collinear points: init's
    completion raises a StageError), the choice keeps the registered prior and records no
    scores, instead of failing the stage: both objects of the scene keep their priors."""
    import r2s.stages.init as init_stage
    from r2s.errors import StageError
    from r2s.io.paths import ScenePaths
    from r2s.io.state import read_state
    from r2s.runner.base import run_stage

    def no_completion(*args, **kwargs):
        raise StageError("object: completion failed (collinear points)")

    monkeypatch.setattr(init_stage, "_complete", no_completion)
    K, world_from_camera = _view()
    scene = write_input_scene(tmp_path / "scene", _scene(), WIDTH, HEIGHT, K=K,
                              world_from_camera=world_from_camera)
    result = run_stage(init_stage.STAGE, scene, init_stage.Options(icp_yaw_hypotheses=1))
    state = {o.id: o for o in read_state(ScenePaths(scene).stage_dir("init")).objects}
    assert {i: o.source for i, o in state.items()} == {1: "prior", 2: "prior"}
    assert state[1].prior_choice == {"chosen": "prior", "prior": None, "completion": None}
    assert result.summary["prior_choice"] == {"1": "prior", "2": "prior"}


def test_the_completion_kept_beside_a_prior_is_finished_as_if_init_had_chosen_it(tmp_path):
    """init/alternates/ holds the completion of every prior kept, for physopt to swap in.
    It is finished as init finishes its chosen shapes (hidden space shared, outline snapped
    onto the mask), with every kept prior completed: the cube's alternate is the very mesh,
    at the very pose, that ``prior_choice=completion`` gives it."""
    from r2s.io.mesh_io import load_mesh
    from r2s.io.paths import INIT_ALTERNATES_DIR, ScenePaths
    from r2s.io.state import read_state
    from r2s.runner.base import run_stage
    from r2s.stages.init import STAGE, Options

    K, world_from_camera = _view()
    runs = {}
    for choice in ("auto", "completion"):
        scene = write_input_scene(tmp_path / choice, _scene(), WIDTH, HEIGHT, K=K,
                                  world_from_camera=world_from_camera)
        run_stage(STAGE, scene, Options(icp_yaw_hypotheses=1, prior_choice=choice))
        runs[choice] = ScenePaths(scene).stage_dir("init")
    alternate = read_state(runs["auto"] / INIT_ALTERNATES_DIR).object(2)
    chosen = read_state(runs["completion"]).object(2)
    assert read_state(runs["auto"]).object(2).source == "prior"
    assert chosen.source == "completed"
    np.testing.assert_allclose(alternate.pose, chosen.pose, atol=1e-9)
    a = load_mesh(runs["auto"] / INIT_ALTERNATES_DIR / alternate.mesh)
    c = load_mesh(runs["completion"] / chosen.mesh)
    assert a.vertices.shape == c.vertices.shape
    np.testing.assert_allclose(a.vertices, c.vertices, atol=1e-6)
