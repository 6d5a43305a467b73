"""``r2s diagnose``: trace the residuals of a reconstruction to effects the model lacks.

- :mod:`r2s.diagnose.data`: the measured residuals with their structure;
- :mod:`r2s.diagnose.measure`: measuring them on a scene (depth, registration, support,
  PyBullet rollout, observed push);
- :mod:`r2s.diagnose.effects`: the catalogue of candidate effects, one module each;
- :mod:`r2s.diagnose.ranking`: BIC ranking against "no effect";
- :mod:`r2s.scene_model`: the hooks other stages call to use the kept effects;
- :mod:`r2s.runner.rerun`: the before/after comparison on a copy of the scene.
"""
