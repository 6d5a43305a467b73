"""Name -> stage table. Modules are imported lazily so ``r2s --help`` stays fast."""

from __future__ import annotations

import importlib

from r2s.runner.base import StageSpec

STAGE_MODULES: dict[str, str] = {
    "init": "r2s.stages.init",
    "graph": "r2s.stages.graph",
    "geomopt": "r2s.stages.geomopt",
    "physopt": "r2s.stages.physopt",
    "texture": "r2s.stages.texture",
    "export": "r2s.stages.export",
    "evaluate": "r2s.stages.evaluate",
    "diagnose": "r2s.stages.diagnose",
}

PIPELINE: tuple[str, ...] = ("init", "graph", "geomopt", "physopt", "texture", "export", "evaluate")
"""What ``r2s run`` drives, in order."""


def get_stage(name: str) -> StageSpec:
    return importlib.import_module(STAGE_MODULES[name]).STAGE
