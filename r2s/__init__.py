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
- ``r2s.cli``: the thin typer front end.

Imports run one way: no library package imports the runner, a stage or the CLI
(docs/architecture.md; checked by tests/test_import_layers.py).
"""

__version__ = "0.1.0"
