"""A mis-declared focal length: what diagnose's residuals see of it (docs/diagnose.md §6).

The hand-made scene of ``helpers_diagnose`` is rendered with the true K and declared with
fx, fy 4 % too long, so every point is back-projected 1/1.04 too close to the optical axis
at its true depth. Known answers: the table stays a plane (the generic table model sees no
structure) whose normal turns by the angle between n and diag(1.04, 1.04, 1) n (camera
frame), and an exact metric prior registers 1/1.04 small across the view and at its size
along it (the per-axis fit of ``fit_prior_scale``), which no catalogued effect predicts.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers_diagnose import HEIGHT, WIDTH, render
from r2s.diagnose.data import Residuals
from r2s.diagnose.measure.observe import (object_points_camera, support_residual,
                                          table_shape_residual)
from r2s.diagnose.measure.scale_fit import SurfaceModel, fit_prior_scale, free_space
from r2s.diagnose.stats.structure_test import test_structure as structure_test
from r2s.io.input_scene import Camera, InputScene, ObjectSpec

FOCAL_ERROR = 0.04


def _declared(r: dict, focal_error: float) -> InputScene:
    """The rendered scene with camera.json's fx, fy (1 + focal_error) times the true ones."""
    K = r["K"].copy()
    K[0, 0] *= 1.0 + focal_error
    K[1, 1] *= 1.0 + focal_error
    depth = np.where(r["depth"] > 0, r["depth"], np.nan).astype(np.float32)
    return InputScene(rgb=np.zeros((HEIGHT, WIDTH, 3), np.uint8), depth_m=depth,
                      masks=r["masks"].astype(np.int32),
                      camera=Camera(K=K, world_from_camera=r["declared"], width=WIDTH,
                                    height=HEIGHT),
                      objects=[ObjectSpec(id=i, label=f"object_{i}") for i, _, _ in r["objects"]])


@pytest.fixture(scope="module")
def scene() -> dict:
    return render(noise_m=0.0005)


def test_focal_error_keeps_the_table_a_plane_and_turns_its_normal(scene):
    inp = _declared(scene, FOCAL_ERROR)
    shape = structure_test(Residuals(table_shape=table_shape_residual(inp, 0.0004)))
    assert not shape.structured and shape.p_value > 0.01
    support = support_residual(inp, np.array([0.0, 0.0, -9.81]), float(np.radians(0.3)))
    measured_deg = np.degrees(np.arccos(np.clip(support.normal @ support.up, -1.0, 1.0)))
    # analytic: the camera-frame normal n becomes diag(1 + e, 1 + e, 1) n, normalised
    n = np.linalg.inv(scene["world_from_camera"])[:3, :3] @ np.array([0.0, 0.0, 1.0])
    turned = n * np.array([1.0 + FOCAL_ERROR, 1.0 + FOCAL_ERROR, 1.0])
    expected_deg = np.degrees(np.arccos(n @ turned / np.linalg.norm(turned)))
    # about e sin(2 elevation) / 2, the elevation being the optical axis's angle to the table
    elevation = np.arcsin(abs(n[2]))
    assert expected_deg == pytest.approx(np.degrees(FOCAL_ERROR * np.sin(2 * elevation) / 2),
                                         rel=0.05)
    assert measured_deg == pytest.approx(expected_deg, abs=0.05)


@pytest.mark.parametrize("focal_error", [0.0, FOCAL_ERROR])
def test_across_along_fit_separates_a_focal_error_on_exact_priors(scene, focal_error):
    inp = _declared(scene, focal_error)
    across_expected = -np.log1p(focal_error)
    for i, mesh, pose in scene["objects"]:
        pts = object_points_camera(inp, i)
        view = free_space(inp.camera.K, inp.depth_m, inp.masks == i)
        start = np.linalg.inv(pose) @ scene["declared"]
        fit = fit_prior_scale(SurfaceModel(mesh), pts, start, view=view, free_space_weight=0.5,
                              axes="across_along")
        across, across_y, along = fit.log_scale_axes
        assert across == across_y
        assert across == pytest.approx(across_expected, abs=0.004), i
        assert along == pytest.approx(0.0, abs=0.006), i
        assert np.log(fit.scale) == pytest.approx((2 * across + along) / 3, abs=1e-12)


def test_isotropic_fit_is_the_one_scale_of_the_per_axis_model(scene):
    """``axes="isotropic"`` reports one scale on all three axes; starting from a fitted
    pose (a rotation times a scale) starts from that scale."""
    inp = _declared(scene, 0.0)
    i, mesh, pose = scene["objects"][0]
    pts = object_points_camera(inp, i)
    start = np.linalg.inv(pose) @ scene["declared"]
    iso = fit_prior_scale(SurfaceModel(mesh), pts, start)
    assert len(set(iso.log_scale_axes)) == 1
    assert iso.log_scale_axes[0] == pytest.approx(np.log(iso.scale), abs=1e-12)
    held = fit_prior_scale(SurfaceModel(mesh), pts, iso.object_from_camera, fit_scale=False,
                           fit_rotation=False, schedule_m=(0.003,))
    assert held.scale == pytest.approx(iso.scale, rel=1e-9)


@pytest.mark.parametrize("focal_error", [0.0, FOCAL_ERROR, -0.03])
def test_focal_length_is_fitted_from_the_tables_turn_and_distance(scene, focal_error):
    """camera.json's fx, fy (1 + e) times the true ones: the table turns and moves as one
    factor says, and ``focal_length`` fits the true focal length's factor 1 / (1 + e) to
    within 0.3 % from the table alone; it is named over a camera rotation and a depth
    effect; without the error nothing is named."""
    from r2s.diagnose.effects import all_effects, get_effect
    from r2s.diagnose.stats.ranking import NoiseBar, diagnose

    inp = _declared(scene, focal_error)
    support = support_residual(inp, np.array([0.0, 0.0, -9.81]), float(np.radians(0.3)))
    assert support.height_used
    res = Residuals(support=support, table_shape=table_shape_residual(inp, 0.0004))
    fit = get_effect("focal_length").fit(res)
    assert fit.size == pytest.approx(1.0 / (1.0 + focal_error), abs=0.003)
    d = diagnose(res, all_effects(), max_effects=2, noise=NoiseBar(draws=50))
    assert [c.effect for c in d.chosen] == ([] if focal_error == 0.0 else ["focal_length"])
