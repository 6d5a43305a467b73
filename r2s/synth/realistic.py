"""The observation of a realistic synth scene: sensor depth and segmenter masks.

Used by the generator when ``depth_model`` or ``mask_model`` is not the default
(:mod:`~r2s.synth.depth_realsense`, :mod:`~r2s.synth.mask_errors`). Besides the input images
it keeps what was injected for gt/: ``gt/scene.json["realism"]`` (parameters, pixel counts
per depth-hole cause, mask events, ``extra_ids``: new id -> the gt id it belongs to) and two
images in ``gt/realism/``: ``masks_exact.png`` (the exact visible instance ids of the objects
in input/) and ``depth_causes.png`` (:data:`depth_realsense.CAUSES` codes; 0 = a valid
reading or no surface).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from r2s.io.input_scene import MIN_MASK_PIXELS
from r2s.synth import depth_noise, depth_realsense, mask_errors
from r2s.synth.effects import Effects
from r2s.synth.files import write_png
from r2s.synth.options import SynthOptions
from r2s.synth.render import Frame


def vertical_fov_deg(hfov_deg: float, width: int, height: int) -> float:
    """Vertical field of view of square pixels with horizontal field of view ``hfov_deg``."""
    return float(np.degrees(2.0 * np.arctan(np.tan(np.radians(hfov_deg) / 2.0)
                                            * height / width)))


@dataclass(frozen=True)
class RealisticObservation:
    """Input images (``rgb``, ``depth_m``, ``masks``) plus ``visible_px`` / ``in_input``
    per gt object (index k = id k + 1), the exact masks, the depth-cause codes and the
    record for gt/scene.json."""

    rgb: np.ndarray
    depth_m: np.ndarray
    masks: np.ndarray
    visible_px: np.ndarray
    in_input: np.ndarray
    masks_exact: np.ndarray
    depth_cause: np.ndarray
    record: dict = field(default_factory=dict)


DEPTHLESS_MIN_PX = 1000
"""An object made to read no depth (``depthless``) shows at least this many pixels."""
NO_RETURN_CAUSE = 9
"""gt/realism/depth_causes.png code of the pixels of a ``depthless`` object."""


def observe(frame: Frame, K: np.ndarray, options: SynthOptions, effects: Effects,
            noise_rng: np.random.Generator, mask_rng: np.random.Generator, n: int,
            depthless_rng: np.random.Generator | None = None) -> RealisticObservation:
    """Depth, masks and RGB of a realistic scene with ``n`` gt objects; with
    ``options.depthless``, that many objects (drawn with ``depthless_rng``) read no depth."""
    scale = effects.depth_scale if effects.depth_scale is not None else 1.0
    offset = effects.depth_offset_m or 0.0
    record: dict = {"depth_model": options.depth_model, "mask_model": options.mask_model}
    if options.depth_model == "realsense":
        sensor = depth_realsense.observe(frame.depth_m, K, frame.rgb, frame.segment, noise_rng,
                                         options.noise, scale=scale, offset_m=offset)
        depth, cause = sensor.depth_m, sensor.cause
        record["depth"] = {
            "axial_sigma": f"{depth_realsense.AXIAL_A_PER_M * options.noise:g} * z^2 m",
            "axial_a_per_m": depth_realsense.AXIAL_A_PER_M * options.noise,
            "baseline_m": depth_realsense.BASELINE_M,
            "disparity_step_px": 1.0 / depth_realsense.SUBPIXEL_STEPS,
            "pixels": sensor.counts,
            "causes": dict(depth_realsense.CAUSES)}
    else:
        depth = depth_noise.observe_depth(frame.depth_m, K, noise_rng, options.noise,
                                          scale=scale, offset_m=offset)
        cause = np.zeros(depth.shape, dtype=np.uint8)

    depthless: list[int] = []
    if options.depthless > 0:
        big = [k for k in range(n) if int((frame.segment == k).sum()) >= DEPTHLESS_MIN_PX]
        rng = depthless_rng if depthless_rng is not None else np.random.default_rng(0)
        depthless = sorted(int(k) for k in rng.permutation(big)[:options.depthless])
        for k in depthless:
            gone = frame.segment == k
            depth = np.where(gone, np.nan, depth)
            cause = np.where(gone, NO_RETURN_CAUSE, cause).astype(np.uint8)
        record["depthless_ids"] = [k + 1 for k in depthless]

    exact = np.zeros(frame.segment.shape, dtype=np.int32)
    visible_px = np.zeros(n, dtype=np.int64)
    in_input = np.zeros(n, dtype=bool)
    valid = np.isfinite(depth)
    for k in range(n):
        seen = frame.segment == k
        visible_px[k] = int(seen.sum())
        readable = int((seen & valid).sum()) >= MIN_MASK_PIXELS or k in depthless
        if visible_px[k] >= options.min_visible_px and readable:
            in_input[k] = True
            exact[seen] = k + 1

    masks = exact
    if options.mask_model == "segmenter":
        cfg = mask_errors.SegmenterErrors(shadow_probability=options.mask_shadow)
        masks, events = mask_errors.apply(exact, frame.depth_m, mask_rng, first_new_id=n + 1,
                                          cfg=cfg)
        masks, events = mask_errors.keep_usable(masks, exact, valid, events, MIN_MASK_PIXELS)
        extra = {int(e["new_id"]): int(e["id"]) for e in events if "new_id" in e
                 and (masks == e["new_id"]).any()}
        record["masks"] = {"events": events, "extra_ids": {str(k): v for k, v in extra.items()},
                           "changed_px": int((masks != exact).sum())}

    rgb = frame.rgb.astype(np.float64)
    rgb += noise_rng.normal(0.0, 2.0 * min(options.noise, 1.0), size=rgb.shape)
    dtype = np.uint8 if masks.max() < 256 else np.uint16
    return RealisticObservation(
        rgb=np.clip(np.round(rgb), 0, 255).astype(np.uint8), depth_m=depth,
        masks=masks.astype(dtype), visible_px=visible_px, in_input=in_input,
        masks_exact=exact.astype(dtype), depth_cause=cause, record=record)


def write_gt_images(gt_dir: Path, obs: RealisticObservation) -> None:
    """``gt/realism/masks_exact.png`` and ``gt/realism/depth_causes.png``."""
    folder = Path(gt_dir) / "realism"
    folder.mkdir(parents=True, exist_ok=True)
    write_png(folder / "masks_exact.png", obs.masks_exact)
    write_png(folder / "depth_causes.png", obs.depth_cause.astype(np.uint8))
