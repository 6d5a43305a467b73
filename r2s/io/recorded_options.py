"""A stage's options as its last run recorded them in ``manifest.json``, else the defaults.

The one reading of "recorded options": ``r2s run`` and ``r2s <stage> --set`` start from it
(then apply their overrides), diagnose's rerun replays it, and a library that must see what
a stage was configured with (diagnose reading export's body parameters) reads it into its
own pydantic type.
"""

from __future__ import annotations

from typing import Any, Optional, TypeVar

from pydantic import BaseModel, ValidationError

from r2s.io.manifest import Manifest

ModelT = TypeVar("ModelT", bound=BaseModel)


def recorded_values(manifest: Manifest, stage: str, fields: Optional[set[str]] = None
                    ) -> dict[str, Any]:
    """``{key: value}`` recorded for ``stage`` (empty when it never ran), restricted to
    ``fields`` when given."""
    rec = manifest.stages.get(stage)
    values = dict(rec.options) if rec is not None and rec.options else {}
    return values if fields is None else {k: v for k, v in values.items() if k in fields}


def recorded_options(manifest: Manifest, stage: str, options_type: type[ModelT],
                     overrides: Optional[dict[str, Any]] = None) -> ModelT:
    """``options_type`` from the recorded values of ``stage`` (the keys it knows), updated
    by ``overrides``. A record that no longer validates (an option renamed or retyped in a
    newer r2s) is dropped: the defaults plus ``overrides`` are used instead.

    Raises pydantic's ``ValidationError`` when ``overrides`` themselves are invalid.
    """
    overrides = dict(overrides or {})
    recorded = recorded_values(manifest, stage, set(options_type.model_fields))
    try:
        return options_type.model_validate({**recorded, **overrides})
    except ValidationError:
        return options_type.model_validate(overrides)
