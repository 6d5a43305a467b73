"""r2s: physically consistent digital twins of cluttered tabletops from one RGB-D image.

The package is organised by topic:

- ``r2s.io``: every file read and write (scene directory contract, meshes, JSON).
- ``r2s.geometry``: free functions on numpy arrays (cameras, planes, registration, SDFs).
- ``r2s.sim``: simulators (PyBullet loader and rollout, the differentiable torch simulator).
- ``r2s.metrics``: stability, geometry and rendering metrics.
- ``r2s.stages``: one module per pipeline stage, each with ``run(scene_dir, options, progress)``.
- ``r2s.synth``: the benchmark scene generator.
- ``r2s.cli``: the thin typer front end.
"""

__version__ = "0.1.0"
