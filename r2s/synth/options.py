"""Options of ``r2s synth`` (:class:`SynthOptions`); every problem is one :class:`R2SError` line."""

from __future__ import annotations

from typing import Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, \
    model_validator

from r2s.errors import R2SError
from r2s.synth import catalog
from r2s.synth.effects import parse_effects


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
