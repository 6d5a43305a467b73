"""r2s: physically consistent digital twins of cluttered tabletops from one RGB-D image.

The package is organised by topic:

- ``r2s.io``: every file read and write (scene directory contract, meshes, JSON).
- ``r2s.geometry``: free functions on numpy arrays (cameras, planes, registration, SDFs).
- ``r2s.sim``: simulators (PyBullet loader and rollout, the differentiable torch simulator).
- ``r2s.metrics``: stability, geometry and rendering metrics.
- ``r2s.graph``, ``r2s.geomopt``, ``r2s.physopt``, ``r2s.texture``, ``r2s.interaction``,
  ``r2s.diagnose``: the algorithms of their stages and commands, on loaded data.
- ``r2s.scene_model``: the effects kept by ``r2s diagnose --set apply=true``, as hooks.
- ``r2s.stages``: one thin module per pipeline stage (``STAGE = StageSpec(...)``).
- ``r2s.runner``: the only package that runs stages (pipeline, staleness, manifest record).
- ``r2s.synth``: the benchmark scene generator.
- ``r2s.cli``: the thin typer front end (help and usage errors in ``r2s.cli_help``, what it
  prints in ``r2s.cli_output``).
- ``r2s.api``: the Python API (docs/api.md); its names are attributes of ``r2s`` itself,
  imported on first use so that ``import r2s`` stays light::

      import r2s
      result = r2s.run("scene", stages=["init", "graph"])
      scene = r2s.load_export("scene")

Imports run one way: no library package imports the runner, a stage or the CLI
(docs/architecture.md; checked by tests/test_import_layers.py).
"""

__version__ = "0.1.0"

_API = ("run", "run_stage", "load_export", "RunResult", "StageRun", "ExportScene",
        "ExportObject", "STAGES")
"""Names of :mod:`r2s.api` that ``r2s`` itself offers. The per-stage functions stay in
``r2s.api`` (``r2s.api.graph``): ``r2s.graph`` is the graph library package."""


def __getattr__(name: str):
    """``r2s.run`` etc.: :mod:`r2s.api`'s names, imported when first asked for."""
    import importlib

    if name == "api":
        return importlib.import_module("r2s.api")
    if name in _API:
        return getattr(importlib.import_module("r2s.api"), name)
    raise AttributeError(f"module 'r2s' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_API) + ["api"])
