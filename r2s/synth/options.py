"""Options of ``r2s synth`` (:class:`SynthOptions`); every problem is one :class:`R2SError` line."""

from __future__ import annotations

from typing import Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, \
    model_validator

from r2s.errors import R2SError
from r2s.synth import catalog
from r2s.synth.effects import parse_effects


REALSENSE_PRESET: dict[str, str] = {"camera_model": "realsense", "mask_model": "segmenter",
                                    "depth_model": "realsense", "prior_model": "single_image"}
"""What ``realism=realsense`` sets."""
REALSENSE_ELEVATION_DEG = (27.0, 50.0)
"""Elevation of ``camera_model=realsense``: 40-63 degrees from looking straight down."""
REALISM_FIELDS = ("realism", "camera_model", "hfov_deg", "mask_model", "depth_model",
                  "prior_model", "prior_pose", "depthless", "mask_shadow", "camera_roll_deg")


class SynthOptions(BaseModel):
    """Options of one synthetic scene (``r2s synth``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    objects: str = Field("ycb", description="Object set: ycb, pybullet, mixed, or a "
                                            "comma-separated list of catalogue names.")
    count: int = Field(6, description="Number of objects (1-15).")
    seed: int = Field(0, description="Random seed; the same options give identical files.")
    noise: float = Field(1.0, description="Depth noise level (0 = perfect depth, 1 = typical).")
    effects: dict[str, str] = Field(default_factory=dict,
                                    description="Injected effects NAME -> VALUE (gt/ only).")
    width: int = Field(640, description="Image width, pixels.")
    height: int = Field(480, description="Image height, pixels.")
    vfov_deg: float = Field(45.0, description="Vertical field of view, degrees.")
    elevation_deg: tuple[float, float] = Field((40.0, 70.0),
                                               description="Camera elevation range, degrees.")
    distance_m: tuple[float, float] = Field((0.5, 1.0),
                                            description="Camera distance range, metres.")
    prior_fraction: float = Field(1.0, description="Share of visible objects given a prior.")
    friction_range: tuple[float, float] = Field((0.5, 1.0),
                                                description="Object friction range.")
    support_friction: float = Field(0.8, description="Friction of the support plane.")
    min_visible_px: int = Field(50, description="Objects with fewer visible pixels are left "
                                                "out of input/ (kept in gt/).")
    stack_probability: float = Field(0.35, description="Chance that a dropped object aims "
                                                       "at the top of an earlier one.")
    adjacent_probability: float = Field(0.5, description="Chance that a dropped object "
                                                         "lands against an earlier one.")
    verify_duration_s: float = Field(3.0, description="Rest check: simulated seconds.")
    verify_translation_m: float = Field(0.005, description="Rest check: max COM motion, m.")
    verify_rotation_deg: float = Field(2.0, description="Rest check: max rotation, deg.")
    cache_dir: Optional[str] = Field(None, description="Memo of convex decompositions "
                                                       "(default ~/.cache/r2s/convex).")
    push: bool = Field(False, description="Also push one object on the ground truth and "
                                          "write what the camera saw after it "
                                          "(input/interaction/, gt/push.json).")
    # ---- realism (docs/realistic.md); every default reproduces the scenes made before ----
    realism: Literal["none", "realsense"] = Field(
        "none", description="Preset: realsense = camera_model=realsense, mask_model=segmenter, "
                            "depth_model=realsense, prior_model=single_image (each may still "
                            "be set on its own).")
    camera_model: Literal["tabletop", "realsense"] = Field(
        "tabletop", description="tabletop: vfov_deg and elevation_deg as given; realsense: "
                                "horizontal FOV drawn from hfov_deg, elevation 27-50 deg "
                                "(40-63 deg from looking straight down) unless elevation_deg "
                                "is set.")
    hfov_deg: tuple[float, float] = Field((58.0, 70.0), description="Horizontal field of view "
                                          "range of camera_model=realsense, degrees.")
    camera_roll_deg: tuple[float, float] = Field(
        (0.0, 0.0), description="Roll of the camera about its line of sight, drawn from this "
                                "range, degrees (a hand-held or wrist camera: the table's "
                                "horizon is not the image's x axis). 0,0: level, as before.")
    mask_model: Literal["exact", "segmenter"] = Field(
        "exact", description="segmenter: masks bleed, get holes, an object is split into two "
                             "ids, a sliver behind an occluder gets its own id (gt/realism/).")
    depth_model: Literal["default", "realsense"] = Field(
        "default", description="realsense: sigma_z = a z^2, disparity quantisation, stereo "
                               "shadows, holes at edges and on dark, specular and thin "
                               "surfaces, flying pixels (scaled by noise).")
    prior_model: Literal["default", "single_image", "none"] = Field(
        "default", description="default: mild prior errors; single_image: proportions off by "
                               "up to 15 % per axis, smoothed, 10-20 mm Chamfer; none: no "
                               "priors.")
    mask_shadow: float = Field(
        0.0, ge=0.0, le=1.0, description="With mask_model=segmenter: the chance per object "
                                         "that its mask takes in its shadow on the table (swept "
                                         "4-12 px in one direction for the whole scene, grown "
                                         "2 px, onto background pixels; gt/realism/). 0: none, "
                                         "as before.")
    depthless: int = Field(
        0, ge=0, description="This many visible objects (of at least 1000 px, drawn at "
                             "random) read no depth at all, as transparent, black or "
                             "mirror-like ones do; they stay in the masks "
                             "(gt/scene.json realism.depthless_ids).")
    prior_pose: Literal["perturbed", "exact"] = Field(
        "perturbed", description="world_from_prior: the true pose turned by 10-20 deg and "
                                 "shifted by 1-4 cm (perturbed) or the true pose (exact).")

    @model_validator(mode="before")
    @classmethod
    def _preset(cls, data: Any) -> Any:
        """Expand ``realism`` and ``camera_model`` into the options they imply (explicit
        options win)."""
        if not isinstance(data, dict):
            return data
        out = dict(data)
        if out.get("realism") == "realsense":
            for key, value in REALSENSE_PRESET.items():
                out.setdefault(key, value)
        if out.get("camera_model") == "realsense":
            out.setdefault("elevation_deg", REALSENSE_ELEVATION_DEG)
        return out

    def record(self) -> dict:
        """The options as gt/scene.json records them: the realism options only where they
        differ from their defaults (so scenes made without them keep their bytes)."""
        out = self.model_dump()
        for key in REALISM_FIELDS:
            if out[key] == type(self).model_fields[key].get_default():
                del out[key]
        return out

    def __init__(self, **data: object) -> None:
        try:
            super().__init__(**data)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = ".".join(str(p) for p in err.get("loc", ()))
            msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
            raise R2SError(f"synth option {loc}: {msg}" if loc else f"synth options: {msg}") \
                from None

    @field_validator("count")
    @classmethod
    def _count(cls, v: int) -> int:
        if not 1 <= v <= 15:
            raise ValueError(f"count must be within 1..15, got {v}")
        return v

    @field_validator("objects")
    @classmethod
    def _objects(cls, v: str) -> str:
        try:
            catalog.entries_for(v)
        except KeyError as exc:
            raise ValueError(f"unknown object set or object {exc.args[0]!r} (sets: "
                             f"{', '.join(catalog.OBJECT_SETS)})") from None
        return v

    @field_validator("effects")
    @classmethod
    def _effects(cls, v: dict) -> dict:
        out = {str(k): str(x) for k, x in v.items()}
        parse_effects(out)  # raises R2SError naming the first bad effect
        return out

    @model_validator(mode="after")
    def _ranges(self) -> "SynthOptions":
        checks = [
            (self.noise >= 0, "noise must be >= 0"),
            (32 <= self.width <= 4096 and 32 <= self.height <= 4096,
             "width and height must be within 32..4096"),
            (10 <= self.vfov_deg <= 120, "vfov_deg must be within 10..120"),
            (5 <= self.elevation_deg[0] <= self.elevation_deg[1] <= 90,
             "elevation_deg must be an increasing range within 5..90"),
            (0.2 <= self.distance_m[0] <= self.distance_m[1] <= 5,
             "distance_m must be an increasing range within 0.2..5"),
            (0 <= self.prior_fraction <= 1, "prior_fraction must be within 0..1"),
            (20 <= self.hfov_deg[0] <= self.hfov_deg[1] <= 120,
             "hfov_deg must be an increasing range within 20..120"),
            (-180 <= self.camera_roll_deg[0] <= self.camera_roll_deg[1] <= 180,
             "camera_roll_deg must be an increasing range within -180..180"),
            (0 < self.friction_range[0] <= self.friction_range[1],
             "friction_range must be an increasing positive range"),
            (self.support_friction > 0, "support_friction must be positive"),
            (self.min_visible_px >= 1, "min_visible_px must be >= 1"),
            (0 <= self.stack_probability and 0 <= self.adjacent_probability
             and self.stack_probability + self.adjacent_probability <= 1,
             "stack_probability and adjacent_probability must be >= 0 with a sum <= 1"),
            (self.verify_duration_s > 0 and self.verify_translation_m > 0
             and self.verify_rotation_deg > 0, "verify_* must be positive"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
        return self


def options_from_command_line(explicit: dict[str, object], sets: dict[str, str]
                              ) -> SynthOptions:
    """SynthOptions from the synth command's own options (``explicit``: those given a value
    other than their default) and its ``--set KEY=VALUE`` pairs (any field but
    ``effects``; a range as ``LO,HI``). A key given both ways is an error."""
    data: dict[str, object] = dict(explicit)
    fields = SynthOptions.model_fields
    for key, value in sets.items():
        if key not in fields or key == "effects":
            known = ", ".join(k for k in fields if k != "effects")
            raise R2SError(f"synth --set {key}: unknown option (known: {known})")
        if key in explicit:
            raise R2SError(f"synth option {key} given both as --{key.replace('_', '-')} "
                           "and --set")
        if str(fields[key].annotation).startswith("tuple"):
            parts = [p for p in str(value).split(",") if p.strip()]
            if len(parts) != 2:
                raise R2SError(f"synth --set {key}={value}: expected a range LO,HI")
            data[key] = tuple(p.strip() for p in parts)
        else:
            data[key] = value
    return SynthOptions(**data)


def set_help() -> str:
    """The --help epilog of ``r2s synth``: every option ``--set`` takes."""
    lines = ["Options for --set key=value (ranges as LO,HI); e.g. --set realism=realsense "
             "--set prior_model=none:\n\n"]
    for name, fld in SynthOptions.model_fields.items():
        if name != "effects":
            lines.append(f"{name} (default {fld.default!r}): {fld.description or ''}\n\n")
    return "".join(lines)
