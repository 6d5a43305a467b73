"""``r2s diagnose``: trace the residuals of a reconstruction to effects the model lacks.

The library has three roles, one subpackage each, plus the report:

- measurement, :mod:`r2s.diagnose.measure`: the only code that reads a scene directory
  (:mod:`.measure.scene_dir`) or runs PyBullet; it fills the containers of
  :mod:`r2s.diagnose.data` (residuals with their structure) and the ground-truth errors;
- statistics, :mod:`r2s.diagnose.stats`: residual blocks and their noise levels, the BIC
  ranking, the noise-only bar against false alarms, the camera-or-table prior, the generic
  test of a residual for structure and the keep-or-revert rule of one loop step (pure
  functions of the containers);
- effects, :mod:`r2s.diagnose.effects`: the catalogue, one module per effect (fit,
  predicted residual, how it changes the model);
- reporting: :mod:`r2s.diagnose.report` (report.json / report.md) and
  :mod:`r2s.diagnose.plots` (residuals.png, structure.png).

Elsewhere, because they are not diagnose's to own: the hooks stages call to use the kept
effects are :mod:`r2s.scene_model`; the loop that applies an effect and reruns the stages
on a copy of the scene is the runner's (:mod:`r2s.runner.diagnose_loop`, with
:mod:`r2s.runner.rerun`).
"""
