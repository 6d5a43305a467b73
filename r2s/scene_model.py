"""The scene's model extensions kept by ``r2s diagnose --apply``, as pure hooks.

``manifest.model`` holds ``{"effects": {name: params}}``. Stages call:

- :func:`corrected_input` on the loaded ``input/`` (init; texture and evaluate for the
  camera): depth bias, lens distortion, focal length and camera rotation corrected; then,
  whatever the model, an instance that is the table, floor or a wall made background, a
  declared pose that tilts the table beyond any real table levelled, and a segmenter's
  split pieces merged;
- :func:`corrected_state` on a state before they use it (physopt, export): COM shifts,
  friction, a tilted table (and, for a state made before a camera correction was kept,
  the world rotation).

Both are pure (no file I/O) and return new objects; an empty model changes nothing.
A stage that calls one declares the level it applies in ``StageSpec.uses_model``; the
stage machinery hashes :func:`model_part` of those levels among the stage's inputs, so a
changed model makes exactly those stages (and what depends on their outputs) stale.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Iterable, Mapping

import numpy as np

from r2s.diagnose.effects import all_effects, get_effect
from r2s.errors import R2SError
from r2s.geometry.background_instances import background_instances
from r2s.geometry.declared_level import GROSS_TILT_DEG, declared_level, gross_level_correction
from r2s.geometry.mask_fragments import fragment_parents, merge_masks
from r2s.io.input_scene import Camera, InputScene, placeholder_label
from r2s.io.state import SceneState


class UnknownEffectError(R2SError, KeyError):
    """The model names an effect that is not in the catalogue (a one-line CLI error)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def model_effects(model: Mapping[str, Any] | None) -> dict[str, dict]:
    """``{name: params}`` of a manifest model (``{"effects": {...}}``) or of that dict itself."""
    if not model:
        return {}
    effects = model.get("effects", model) if isinstance(model, Mapping) else {}
    return {k: v for k, v in dict(effects).items() if isinstance(v, Mapping)}


def _ordered(model: Mapping[str, Any] | None) -> list[tuple[str, dict]]:
    items = model_effects(model)
    if not items:
        return []
    known = all_effects()
    unknown = sorted(set(items) - set(known))
    if unknown:
        raise UnknownEffectError(f"manifest.json's model has effects this version of r2s "
                                 f"does not know: {', '.join(unknown)} (known: "
                                 f"{', '.join(known)})")
    return [(name, dict(items[name])) for name in known if name in items]


def corrected_input(input_scene: InputScene, model: Mapping[str, Any] | None,
                    merge_fragments: bool = True) -> InputScene:
    """The observation with the model's input-level effects applied (depth, camera), then,
    with ``merge_fragments``, mask ids that are pieces of one object (a segmenter's splits
    and slivers, :mod:`r2s.geometry.mask_fragments`) relabelled as that object, with one
    warning line each."""
    out = input_scene
    for name, params in _ordered(model):
        effect = get_effect(name)
        if effect.level == "input":
            out = effect.apply_to_input(out, params)
    out = levelled(without_background_instances(out))
    return merged_fragments(out) if merge_fragments else out


def without_background_instances(scene: InputScene) -> InputScene:
    """``scene`` with every instance that is the table, floor or a wall
    (:mod:`r2s.geometry.background_instances`) turned into background (mask 0) and its
    :class:`ObjectSpec` dropped, one warning line each; ``scene`` itself when there is none.
    An instance with a shape prior is always an object."""
    cam = scene.camera
    candidates = [o.id for o in scene.objects if o.prior_mesh is None]
    if len(scene.objects) < 2 or not candidates:
        return scene
    found = [b for b in background_instances(scene.masks, scene.depth_m, cam.K,
                                             cam.world_from_camera, scene.ids)
             if b.id in candidates]
    if not found or len(found) >= len(scene.objects):
        return scene
    gone = {b.id for b in found}
    masks = np.where(np.isin(scene.masks, list(gone)), 0, scene.masks).astype(scene.masks.dtype)
    return replace(scene, masks=masks, objects=[o for o in scene.objects if o.id not in gone],
                   warnings=list(scene.warnings) + [b.note() for b in found])


def levelled(scene: InputScene, limit_deg: float = GROSS_TILT_DEG) -> InputScene:
    """``scene`` in a world turned about the camera centre so that its table is level, with
    one warning line, when the declared pose tilts the table by more than ``limit_deg``
    (:mod:`r2s.geometry.declared_level`); otherwise ``scene`` itself. The turn is applied
    as a kept ``camera_rotation`` would be (camera and the priors' poses)."""
    cam = scene.camera
    level = declared_level(scene.depth_m, scene.masks, cam.K, cam.world_from_camera,
                           [o.id for o in scene.objects])
    correction = gross_level_correction(level, cam.world_from_camera[:3, 3], limit_deg)
    if correction is None:
        return scene
    out = get_effect("camera_rotation").apply_to_input(
        scene, {"world_correction": correction.tolist()})
    note = (f"camera.json: world_from_camera tilts the table by {level.tilt_deg:.1f} deg from "
            f"level (more than {limit_deg:g} deg: a table cannot be that steep, so the "
            "declared camera pose is taken to be wrong); the scene is reconstructed in the "
            "world turned about the camera centre to level the table, gravity perpendicular "
            "to it")
    return replace(out, warnings=list(out.warnings) + [note])


def declared_labels(scene: InputScene) -> dict[int, str]:
    """id -> the label objects.json gives it (ids without one are left out: their label is
    the placeholder, :func:`r2s.io.input_scene.placeholder_label`)."""
    return {o.id: o.label for o in scene.objects
            if o.declared and o.label != placeholder_label(o.id)}


def merged_fragments(scene: InputScene) -> InputScene:
    """``scene`` with every fragment id's mask pixels given to the object it is part of
    and its :class:`ObjectSpec` dropped (ids with a shape prior are never fragments; a
    declared id is kept over an undeclared one; two ids whose objects.json labels differ
    are two objects)."""
    protected = [o.id for o in scene.objects if o.prior_mesh is not None]
    declared = [o.id for o in scene.objects if o.declared]
    parents = fragment_parents(scene.masks, scene.depth_m, scene.rgb, protected, declared,
                               K=scene.camera.K, labels=declared_labels(scene))
    parents = {f: p for f, p in parents.items()
               if f in scene.ids and p[0] in scene.ids}
    if not parents:
        return scene
    notes = [f"masks.png: instance {f} is taken as part of instance {p} ({why}); "
             f"reconstructed as one object, id {p}" for f, (p, why) in sorted(parents.items())]
    return replace(scene, masks=merge_masks(scene.masks, parents),
                   objects=[o for o in scene.objects if o.id not in parents],
                   warnings=list(scene.warnings) + notes,
                   merged_ids={**scene.merged_ids, **{f: p for f, (p, _) in parents.items()}})


def corrected_camera(camera: Camera, model: Mapping[str, Any] | None) -> Camera:
    """The declared camera with the model's input-level effects applied (its rotation)."""
    out = camera
    for name, params in _ordered(model):
        effect = get_effect(name)
        if effect.level == "input":
            out = effect.apply_to_camera(out, params)
    return out


def corrected_state(state: SceneState, model: Mapping[str, Any] | None,
                    include_input_effects: bool = False) -> SceneState:
    """The state with the model's state-level effects applied (COM, friction, table).

    State-level effects set values (a COM, a friction, the table normal), so applying them
    to a state that already carries them changes nothing: physopt applies them to its
    source and export again to whatever state it exports, and the exported scene carries
    the model's values even where physopt moved them.

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


def model_part(model: Mapping[str, Any] | None, levels: Iterable[str]) -> dict[str, dict]:
    """``{name: params}`` of the model's effects of ``levels`` ("input", "state"); an
    effect this version does not know counts for every level (its stage then fails loudly
    rather than silently ignoring it)."""
    levels = set(levels)
    items = model_effects(model)
    if not items or not levels:
        return {}
    known = all_effects()
    return {k: dict(v) for k, v in sorted(items.items())
            if k not in known or known[k].level in levels}


def with_effect(model: Mapping[str, Any] | None, name: str, params: dict) -> dict:
    """A new model dict with ``name`` added (composed with an earlier fit of the same effect)."""
    new = dict(model or {})
    effects = dict(model_effects(model))
    effect = get_effect(name)
    effects[name] = effect.compose(dict(effects[name]), params) if name in effects else params
    new["effects"] = effects
    return new
