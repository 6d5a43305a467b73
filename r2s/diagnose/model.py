"""The scene's model extensions kept by ``r2s diagnose --apply``, as pure hooks.

``manifest.model`` holds ``{"effects": {name: params}}``. Stages call:

- :func:`corrected_input` on the loaded ``input/`` (init): depth bias and camera rotation
  corrected;
- :func:`corrected_state` on a state before they use it (physopt, export): COM shifts,
  friction, a tilted table (and, for a state made before a camera correction was kept,
  the world rotation).

Both are pure (no file I/O) and return new objects; an empty model changes nothing.
"""

from __future__ import annotations

from typing import Any, Mapping

from r2s.diagnose.effects import all_effects, get_effect
from r2s.io.input_scene import InputScene
from r2s.io.state import SceneState


def model_effects(model: Mapping[str, Any] | None) -> dict[str, dict]:
    """``{name: params}`` of a manifest model (``{"effects": {...}}``) or of that dict itself."""
    if not model:
        return {}
    effects = model.get("effects", model) if isinstance(model, Mapping) else {}
    return {k: v for k, v in dict(effects).items() if isinstance(v, Mapping)}


def _ordered(model: Mapping[str, Any] | None) -> list[tuple[str, dict]]:
    known = all_effects()
    items = model_effects(model)
    unknown = sorted(set(items) - set(known))
    if unknown:
        raise KeyError(f"model has unknown effects: {', '.join(unknown)}")
    return [(name, dict(items[name])) for name in known if name in items]


def corrected_input(input_scene: InputScene, model: Mapping[str, Any] | None) -> InputScene:
    """The observation with the model's input-level effects applied (depth, camera)."""
    out = input_scene
    for name, params in _ordered(model):
        effect = get_effect(name)
        if effect.level == "input":
            out = effect.apply_to_input(out, params)
    return out


def corrected_state(state: SceneState, model: Mapping[str, Any] | None,
                    include_input_effects: bool = False) -> SceneState:
    """The state with the model's state-level effects applied (COM, friction, table).

    ``include_input_effects`` also applies input-level effects that can act on a state
    (the camera rotation moves the whole state); use it only for a state that was built
    from the uncorrected input.
    """
    out = state
    for name, params in _ordered(model):
        effect = get_effect(name)
        if effect.level == "state" or include_input_effects:
            out = effect.apply_to_state(out, params)
    return out


def with_effect(model: Mapping[str, Any] | None, name: str, params: dict) -> dict:
    """A new model dict with ``name`` added (composed with an earlier fit of the same effect)."""
    new = dict(model or {})
    effects = dict(model_effects(model))
    effect = get_effect(name)
    effects[name] = effect.compose(dict(effects[name]), params) if name in effects else params
    new["effects"] = effects
    return new


def without_levels(model: Mapping[str, Any] | None, level: str) -> dict:
    """A new model dict without the effects of one level ("input" or "state")."""
    new = dict(model or {})
    new["effects"] = {k: v for k, v in model_effects(model).items()
                      if get_effect(k).level != level}
    return new
