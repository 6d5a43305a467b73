"""The runner: the only package that runs stages.

- :mod:`r2s.runner.base`: the stage machinery (options, context, staleness, atomic run);
- :mod:`r2s.runner.registry`: stage name -> stage module, and the order ``r2s run`` drives;
- :mod:`r2s.runner.pipeline`: ``r2s run`` and ``r2s <stage>``;
- :mod:`r2s.runner.rerun`: diagnose's before/after, the pipeline rerun on a copy of a scene.

What a library may read about a scene's runs (the manifest file, which state is the latest
current one, a stage's recorded options) lives in :mod:`r2s.io` instead, so that reading
never needs the runner.
"""
