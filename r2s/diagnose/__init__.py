"""``r2s diagnose``: trace the residuals of a reconstruction to effects the model lacks.

- :mod:`r2s.diagnose.data`: the measured residuals with their structure;
- :mod:`r2s.diagnose.measure`: measuring them on a scene (depth, registration, support,
  PyBullet rollout, observed push);
- :mod:`r2s.diagnose.effects`: the catalogue of candidate effects, one module each;
- :mod:`r2s.diagnose.ranking`: BIC ranking against "no effect";

Elsewhere, because they are not diagnose's to own: the hooks stages call to use the kept
effects are :mod:`r2s.scene_model`; the before/after rerun of the pipeline on a copy of the
scene is the runner's (:mod:`r2s.runner.rerun`).
"""
