"""The catalogue of candidate effects: every module here that defines ``EFFECT``.

Adding an effect is adding one module (``r2s/diagnose/effects/<name>.py`` with an
:class:`r2s.diagnose.effects.base.Effect` instance named ``EFFECT``); modules whose name
starts with ``_`` and ``base`` are helpers.
"""

from __future__ import annotations

import importlib
import pkgutil
from functools import lru_cache

from r2s.diagnose.effects.base import Effect, EffectFit


@lru_cache(maxsize=1)
def _catalogue() -> dict[str, Effect]:
    out: dict[str, Effect] = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_") or info.name == "base":
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        effect = getattr(module, "EFFECT", None)
        if isinstance(effect, Effect):
            out[effect.name] = effect
    return dict(sorted(out.items(), key=lambda kv: (kv[1].preference, kv[0])))


def all_effects() -> dict[str, Effect]:
    """Name -> effect, in preference order."""
    return dict(_catalogue())


def get_effect(name: str) -> Effect:
    cat = _catalogue()
    if name not in cat:
        raise KeyError(f"unknown effect '{name}'; known: {', '.join(cat)}")
    return cat[name]


__all__ = ["Effect", "EffectFit", "all_effects", "get_effect"]
