"""Realism in ``r2s synth``: sensor depth, segmenter masks, single-image priors, oblique
camera, each against a known answer (hand-made images and meshes, or the analytic model)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from r2s.errors import R2SError
from r2s.io.input_scene import load_input
from r2s.metrics.geometry import chamfer_distance_mm
from r2s.synth import depth_noise, depth_realsense, mask_errors, priors
from r2s.synth.generate import SynthOptions, synthesize
from r2s.synth.options import REALISM_FIELDS, options_from_command_line

FX = 500.0
K = np.array([[FX, 0.0, 100.0], [0.0, FX, 99.0], [0.0, 0.0, 1.0]])
GREY = np.full((200, 200, 3), 128, dtype=np.uint8)
NOTHING = np.full((200, 200), -1, dtype=np.int32)


def _sensor(depth: np.ndarray, seed: int = 0, rgb: np.ndarray = GREY,
            segment: np.ndarray = NOTHING) -> depth_realsense.SensorFrame:
    return depth_realsense.observe(depth, K, rgb, segment, np.random.default_rng(seed), 1.0)


# ---- depth ------------------------------------------------------------------------------
def test_axial_noise_and_quantisation_grow_with_depth_squared() -> None:
    stds = {}
    for z in (0.5, 1.0):
        out = _sensor(np.full((200, 200), z)).depth_m
        err = out[np.isfinite(out)] - z
        # the analytic model: sigma_z = a z^2 plus a uniform quantisation error of one step
        step = depth_realsense.depth_step_m(z, FX)
        expected = np.hypot(depth_realsense.AXIAL_A_PER_M * z * z, step / np.sqrt(12.0))
        stds[z] = float(err.std())
        assert stds[z] == pytest.approx(expected, rel=0.10)
        assert abs(float(err.mean())) < 0.1 * expected
        # every reading is on the disparity grid
        disparity_steps = FX * depth_realsense.BASELINE_M / out[np.isfinite(out)] \
            * depth_realsense.SUBPIXEL_STEPS
        assert np.allclose(disparity_steps, np.round(disparity_steps), atol=1e-6)
    assert stds[1.0] / stds[0.5] == pytest.approx(4.0, rel=0.10)


def _box_on_plane() -> tuple[np.ndarray, np.ndarray]:
    depth = np.full((200, 200), 1.0)
    depth[70:130, 80:140] = 0.7
    segment = NOTHING.copy()
    segment[70:130, 80:140] = 0
    return depth, segment


def test_holes_concentrate_at_depth_edges_and_in_the_stereo_shadow() -> None:
    depth, segment = _box_on_plane()
    sensor = _sensor(depth, seed=1, segment=segment)
    invalid = ~np.isfinite(sensor.depth_m)
    edges = depth_noise.depth_jumps(depth)
    near_edge = ndimage.distance_transform_edt(~edges) <= 1
    shadow = sensor.cause == depth_realsense.CAUSES["shadow"]
    elsewhere = (ndimage.distance_transform_edt(~edges) > 5) & ~shadow
    assert invalid[near_edge].mean() > 0.45
    assert invalid[elsewhere].mean() < 0.02
    # the second imager, b to the right, misses fx b (1/0.7 - 1/1.0) = 10.7 px of table
    # left of the box in every row of the box, and nothing else
    width = FX * depth_realsense.BASELINE_M * (1 / 0.7 - 1 / 1.0)
    shadow_true = depth_realsense.stereo_shadow(depth, FX)
    rows, cols = np.nonzero(shadow_true)
    assert set(rows) == set(range(70, 130))
    assert cols.min() >= 80 - np.ceil(width) and cols.max() == 79
    per_row = shadow_true[70:130].sum(axis=1)
    assert np.all(np.abs(per_row - width) <= 1.0)
    assert np.all(invalid[shadow_true])


def test_dark_pixels_lose_readings_with_the_declared_probability() -> None:
    rgb = GREY.copy()
    rgb[:, :100] = 0  # black left half: no IR texture
    sensor = _sensor(np.full((200, 200), 0.8), seed=2, rgb=rgb)
    invalid = ~np.isfinite(sensor.depth_m)
    assert invalid[:, :100].mean() == pytest.approx(depth_realsense.DARK_DROP, abs=0.03)
    assert invalid[:, 100:].mean() < 0.01


def test_thin_parts_are_found() -> None:
    segment = NOTHING.copy()
    segment[50:150, 50:60] = 0     # 10 px wide: not thin
    segment[50:150, 100:103] = 1   # 3 px wide: thin
    thin = depth_realsense.thin_parts(segment, width_px=5)
    assert thin[50:150, 100:103].all()
    assert thin[60:140, 50:60].sum() == 0


def test_flying_pixels_read_between_the_two_sides() -> None:
    depth, segment = _box_on_plane()
    sensor = _sensor(depth, seed=3, segment=segment)
    flying = sensor.cause == depth_realsense.CAUSES["flying"]
    assert flying.sum() > 20
    z = sensor.depth_m[flying]
    # mixed at 15-85 % of the way from the near (0.7 m) to the far side (1.0 m), unquantised
    assert np.all((z >= 0.7 + 0.15 * 0.3 - 1e-9) & (z <= 0.7 + 0.85 * 0.3 + 1e-9))


# ---- masks ------------------------------------------------------------------------------
def _disc(shape: tuple[int, int], centre: tuple[int, int], r: float) -> np.ndarray:
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= r * r


ONLY_BLEED = mask_errors.SegmenterErrors(split_probability=0, sliver_probability=0,
                                         hole_probability=0, bleed_probability=1.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bleed_grows_the_mask_by_the_declared_width(seed: int) -> None:
    exact = np.zeros((120, 120), dtype=np.int32)
    exact[_disc(exact.shape, (60, 60), 25)] = 1
    masks, events = mask_errors.apply(exact, np.full(exact.shape, 1.0),
                                      np.random.default_rng(seed), 2, ONLY_BLEED)
    (event,) = events
    added = (masks == 1) & (exact == 0)
    assert event["kind"] == "bleed" and event["onto"] == "background"
    assert added.sum() == event["pixels"] > 0
    dist = ndimage.distance_transform_edt(exact == 0)
    assert dist[added].max() <= event["width_px"] + 1e-9
    assert dist[added].max() > event["width_px"] - 1.0
    # only over the declared arc: about arc / 360 of the ring of that width
    ring = (dist > 0) & (dist <= event["width_px"])
    assert added.sum() / ring.sum() == pytest.approx(event["arc_deg"] / 360.0, abs=0.05)


def test_bleed_onto_a_neighbour_takes_its_pixels() -> None:
    exact = np.zeros((100, 140), dtype=np.int32)
    exact[20:80, 20:70] = 1
    exact[20:80, 70:120] = 2
    cfg = mask_errors.SegmenterErrors(split_probability=0, sliver_probability=0,
                                      hole_probability=0, bleed_probability=1.0,
                                      bleed_onto_neighbour=1.0, bleed_arc_deg=(360.0, 360.0))
    masks, events = mask_errors.apply(exact, np.full(exact.shape, 1.0),
                                      np.random.default_rng(0), 3, cfg)
    first = events[0]
    assert first["id"] == 1 and first["onto"] == "neighbour" and first["neighbours"] == [2]
    # a full-arc bleed of width w onto a straight 60 px neighbour takes a 60 x w band of it
    assert first["pixels"] == 60 * first["width_px"]
    # (2 bleeds back afterwards: what it takes is recorded the same way)
    second = events[1]
    assert second["id"] == 2 and second["neighbours"] == [1]
    assert second["pixels"] == 60 * second["width_px"]
    edge_of_1 = 70 + first["width_px"] - second["width_px"]
    assert np.all(masks[20:80, edge_of_1:] != 1) and np.all(masks[20:80, 20:edge_of_1] == 1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shadow_takes_in_background_in_one_direction_and_no_neighbour(seed: int) -> None:
    """A 30 x 30 px square with a neighbour beside it; every object casts its shadow
    (probability 1) in one direction for the scene. The square's mask takes in only
    background pixels, joined to it, reaching the drawn offset + 2 px of growth (within
    1.5 px) from it, on the side of the drawn direction (the added pixels' centroid lies
    within 30 deg of it seen from the square's centre). No other event is drawn."""
    exact = np.zeros((160, 160), dtype=np.int32)
    exact[65:95, 65:95] = 1
    exact[65:95, 20:40] = 2
    cfg = mask_errors.SegmenterErrors(split_probability=0, sliver_probability=0,
                                      hole_probability=0, bleed_probability=0,
                                      shadow_probability=1.0)
    masks, events = mask_errors.apply(exact, np.full(exact.shape, 1.0),
                                      np.random.default_rng(seed), 3, cfg)
    event = next(e for e in events if e["id"] == 1)
    assert {e["kind"] for e in events} == {"shadow"}
    added = (masks == 1) & (exact != 1)
    assert added.sum() == event["pixels"] > 0
    assert np.all(exact[added] == 0)
    assert np.all(masks[exact == 2] == 2)
    dist = ndimage.distance_transform_edt(exact != 1)
    assert dist[added].max() == pytest.approx(event["offset_px"] + 2.0, abs=1.5)
    labels, _ = ndimage.label(masks == 1)
    assert len(np.unique(labels[masks == 1])) == 1
    v, u = np.nonzero(added)
    angle = np.degrees(np.arctan2(v.mean() - 79.5, u.mean() - 79.5))
    assert abs((angle - event["direction_deg"] + 180.0) % 360.0 - 180.0) < 30.0


def test_no_shadow_by_default_leaves_the_draws_as_before() -> None:
    """Without shadows (the default) the events and masks are those of the same draws with
    shadow_probability=0 given explicitly, and no scene option is recorded."""
    exact = np.zeros((120, 160), dtype=np.int32)
    exact[30:90, 30:80] = 1
    exact[40:70, 90:130] = 2
    a = mask_errors.apply(exact, np.full(exact.shape, 1.0), np.random.default_rng(5), 3)
    b = mask_errors.apply(exact, np.full(exact.shape, 1.0), np.random.default_rng(5), 3,
                          mask_errors.SegmenterErrors(shadow_probability=0.0))
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]
    assert "mask_shadow" not in SynthOptions().record()
    assert SynthOptions(mask_shadow=0.5).record()["mask_shadow"] == 0.5


def test_split_gives_a_new_id_that_is_still_an_object(tmp_path: Path) -> None:
    exact = np.zeros((120, 160), dtype=np.int32)
    exact[20:100, 30:130] = 4
    cfg = mask_errors.SegmenterErrors(split_probability=1.0, split_min_px=100,
                                      sliver_probability=0, hole_probability=0,
                                      bleed_probability=0)
    masks, events = mask_errors.apply(exact, np.full(exact.shape, 1.0),
                                      np.random.default_rng(5), 9, cfg)
    (event,) = events
    assert event["kind"] == "split" and event["new_id"] == 9
    assert (masks == 9).sum() == event["pixels"]
    assert (masks == 4).sum() + (masks == 9).sum() == (exact == 4).sum()
    assert 0.2 < event["pixels"] / (exact == 4).sum() < 0.8


def test_sliver_behind_an_occluder_gets_its_own_id() -> None:
    # object 1 (far, 1.0 m) seen on both sides of object 2 (near, 0.6 m): its 4 px right
    # part is a sliver cut off by the occluder
    exact = np.zeros((100, 100), dtype=np.int32)
    depth = np.full(exact.shape, 1.2)
    exact[20:80, 10:60] = 1
    exact[20:80, 64:68] = 1
    depth[20:80, 10:68] = 1.0
    exact[10:90, 60:64] = 2
    depth[10:90, 60:64] = 0.6
    cfg = mask_errors.SegmenterErrors(split_probability=0, sliver_probability=1.0,
                                      hole_probability=0, bleed_probability=0)
    masks, events = mask_errors.apply(exact, depth, np.random.default_rng(0), 3, cfg)
    sliver = [e for e in events if e["kind"] == "sliver" and e["id"] == 1]
    assert len(sliver) == 1 and sliver[0]["how"] == "piece"
    assert np.array_equal(masks == sliver[0]["new_id"], (exact == 1) & (np.arange(100) >= 64))


def test_sliver_strip_along_an_occluder() -> None:
    exact = np.zeros((100, 100), dtype=np.int32)
    depth = np.full(exact.shape, 1.0)
    exact[20:80, 10:60] = 1
    exact[20:80, 60:90] = 2
    depth[20:80, 60:90] = 0.6  # 2 is in front of 1
    cfg = mask_errors.SegmenterErrors(split_probability=0, sliver_probability=1.0,
                                      hole_probability=0, bleed_probability=0)
    masks, events = mask_errors.apply(exact, depth, np.random.default_rng(1), 3, cfg)
    (event,) = [e for e in events if e["kind"] == "sliver"]
    assert event["id"] == 1 and event["how"] == "strip"  # 2 has no occluder in front
    strip = masks == event["new_id"]
    assert strip.sum() == event["pixels"] >= cfg.sliver_min_px
    assert np.all(exact[strip] == 1)
    dist = ndimage.distance_transform_edt(exact != 2)
    assert dist[strip].max() <= cfg.sliver_width_px[1]


def test_unusable_new_ids_go_back() -> None:
    exact = np.zeros((50, 50), dtype=np.int32)
    exact[10:40, 10:40] = 1
    masks = exact.copy()
    masks[10:13, 10:15] = 7  # 15 px: less than r2s accepts
    events = [{"kind": "sliver", "id": 1, "new_id": 7, "pixels": 15}]
    kept_masks, kept = mask_errors.keep_usable(masks, exact, np.ones(exact.shape, bool),
                                               events, 20)
    assert np.array_equal(kept_masks, exact) and kept == []


# ---- priors -----------------------------------------------------------------------------
def test_single_image_prior_error_on_a_known_box() -> None:
    truth = trimesh.creation.box([0.20, 0.12, 0.25])
    prior, error = priors.make_single_image_prior(truth, np.random.default_rng(4))
    ratio = prior.extents / truth.extents
    assert np.allclose(ratio, error.scale, atol=1e-6)
    assert np.all(np.abs(ratio - 1.0) <= priors.SINGLE_IMAGE_PROPORTION_ERROR + 1e-9)
    cd = chamfer_distance_mm(prior, truth)
    assert 10.0 <= cd <= 20.0
    assert cd == pytest.approx(error.chamfer_mm, abs=0.5)
    assert prior.is_watertight


def test_single_image_prior_reaches_a_reachable_target() -> None:
    truth = trimesh.creation.box([0.20, 0.12, 0.25])
    prior, error = priors.make_single_image_prior(truth, np.random.default_rng(4),
                                                  chamfer_mm=(6.0, 8.0))
    assert 6.0 <= error.target_chamfer_mm <= 8.0
    assert chamfer_distance_mm(prior, truth) == pytest.approx(error.target_chamfer_mm, abs=0.5)
    assert np.all(np.abs(prior.extents / truth.extents - 1.0) <= 0.15 + 1e-9)


def test_single_image_prior_of_a_small_box_stops_at_the_largest_deformation() -> None:
    truth = trimesh.creation.box([0.05, 0.05, 0.05])
    prior, error = priors.make_single_image_prior(truth, np.random.default_rng(0))
    assert error.deformation == priors.MAX_DEFORMATION
    assert error.chamfer_mm < error.target_chamfer_mm
    assert chamfer_distance_mm(prior, truth) == pytest.approx(error.chamfer_mm, abs=0.5)
    assert np.all(np.abs(prior.extents / truth.extents - 1.0) <= 0.15 + 1e-9)


# ---- options ----------------------------------------------------------------------------
def test_default_options_record_as_before_and_preset_expands() -> None:
    default = SynthOptions()
    assert not set(REALISM_FIELDS) & set(default.record())
    assert default.record() == {k: v for k, v in default.model_dump().items()
                                if k not in REALISM_FIELDS}
    real = options_from_command_line({}, {"realism": "realsense", "prior_model": "none"})
    assert (real.camera_model, real.mask_model, real.depth_model, real.prior_model) == (
        "realsense", "segmenter", "realsense", "none")
    assert real.elevation_deg == (27.0, 50.0)
    assert options_from_command_line({}, {"camera_model": "realsense",
                                          "elevation_deg": "30,45"}).elevation_deg == (30, 45)
    with pytest.raises(R2SError, match="both"):
        options_from_command_line({"count": 4}, {"count": "5"})
    with pytest.raises(R2SError, match="unknown option"):
        options_from_command_line({}, {"realsim": "x"})
    with pytest.raises(R2SError, match="realism"):
        SynthOptions(realism="kinect")


# ---- a whole realistic scene --------------------------------------------------------------
FAST_OBJECTS = ("003_cracker_box,004_sugar_box,008_pudding_box,009_gelatin_box,013_apple,"
                "017_orange,036_wood_block,077_rubiks_cube,jenga_block,061_foam_brick")
SMALL_REAL = dict(objects=FAST_OBJECTS, count=4, width=320, height=240, min_visible_px=20,
                  realism="realsense")


def _hashes(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def realistic_scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("real") / "scene"
    synthesize(out, SynthOptions(seed=11, **SMALL_REAL))
    return out


def test_realistic_scene_camera_is_oblique_with_realsense_intrinsics(realistic_scene: Path
                                                                     ) -> None:
    gt = json.loads((realistic_scene / "gt" / "scene.json").read_text())
    cam = gt["camera"]
    assert 27.0 <= cam["elevation_deg"] <= 50.0 and 58.0 <= cam["hfov_deg"] <= 70.0
    K = np.asarray(cam["K"])
    hfov = np.degrees(2 * np.arctan(SMALL_REAL["width"] / 2 / K[0, 0]))
    assert hfov == pytest.approx(cam["hfov_deg"], abs=1e-6)
    axis = np.asarray(cam["world_from_camera"])[:3, 2]
    from_down_deg = np.degrees(np.arccos(-axis[2]))
    assert 40.0 <= from_down_deg <= 63.0
    assert from_down_deg == pytest.approx(90.0 - cam["elevation_deg"], abs=1e-6)
    assert 0.5 <= cam["distance_m"] <= 1.0


def test_realistic_scene_is_valid_input_and_records_what_was_injected(
        realistic_scene: Path) -> None:
    scene = load_input(realistic_scene)  # every id usable, split ids included
    gt = json.loads((realistic_scene / "gt" / "scene.json").read_text())
    real = gt["realism"]
    extra = {int(k): v for k, v in real["masks"]["extra_ids"].items()}
    gt_ids = {o["id"] for o in gt["objects"]}
    ids = {o.id for o in scene.objects}
    assert ids - gt_ids == set(extra) and not set(extra) & gt_ids
    from PIL import Image
    exact = np.asarray(Image.open(realistic_scene / "gt" / "realism" / "masks_exact.png"))
    causes = np.asarray(Image.open(realistic_scene / "gt" / "realism" / "depth_causes.png"))
    assert int((scene.masks != exact).sum()) == real["masks"]["changed_px"]
    for name, code in depth_realsense.CAUSES.items():
        assert int((causes == code).sum()) == real["depth"]["pixels"][name]
    holes = (causes > 0) & (causes != depth_realsense.CAUSES["flying"])
    assert not np.isfinite(scene.depth_m[holes]).any()
    for o in gt["objects"]:
        if "prior_error" in o:
            assert o["prior_error"]["model"] == "single_image"
            assert np.all(np.abs(np.asarray(o["prior_error"]["scale"]) - 1) <= 0.15 + 1e-9)


def test_realistic_scene_is_deterministic(realistic_scene: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    synthesize(again, SynthOptions(seed=11, **SMALL_REAL))
    assert _hashes(again) == _hashes(realistic_scene)


@pytest.mark.parametrize("sets,what", [
    (["--set", "realism=kinect"], "realism"),
    (["--count", "4", "--set", "count=5"], "both"),
])
def test_synth_command_line_rejects_bad_sets_in_one_line(tmp_path: Path, sets: list[str],
                                                         what: str) -> None:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "r2s.cli", "synth", str(tmp_path / "s"),
                           *sets], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 1  # R2SError's exit code
    lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and what in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert not (tmp_path / "s").exists()


def test_a_depthless_object_stays_in_the_masks_without_a_reading(tmp_path: Path) -> None:
    """``depthless=1``: one object of >= 1000 px reads no depth at all (cause code 9 in
    gt/realism/depth_causes.png) and keeps its mask; load_input reports it as not
    reconstructable from depth (skipped_ids) with its spec kept for init."""
    from PIL import Image

    from r2s.synth.realistic import NO_RETURN_CAUSE

    out = tmp_path / "scene"
    synthesize(out, SynthOptions(seed=11, **{**SMALL_REAL, "width": 640, "height": 480},
                                 depthless=1))
    gt = json.loads((out / "gt" / "scene.json").read_text())
    (lost,) = gt["realism"]["depthless_ids"]
    exact = np.asarray(Image.open(out / "gt" / "realism" / "masks_exact.png"))
    causes = np.asarray(Image.open(out / "gt" / "realism" / "depth_causes.png"))
    own = exact == lost
    assert own.sum() >= 1000 and np.all(causes[own] == NO_RETURN_CAUSE)
    scene = load_input(out)
    read = np.isfinite(scene.depth_m) & (scene.masks == lost)
    assert not read[own].any()  # readings left in its mask are the segmenter's bleed
    assert lost in scene.skipped_ids and [o.id for o in scene.skipped_objects] == [lost]
    assert SynthOptions(seed=11, **SMALL_REAL).record().get("depthless") is None
