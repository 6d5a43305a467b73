"""``r2s synth``: benchmark scenes with ground truth.

Real object meshes (YCB, pybullet_data) are dropped into clutter in PyBullet, checked to be
at rest, rendered to RGB-D + instance masks with PyBullet's software renderer, corrupted
with a depth-sensor noise model, and written as ``input/`` (what r2s sees) and ``gt/``
(what it should recover), with imperfect shape priors in ``input/priors/``.

Modules: :mod:`~r2s.synth.meshprep` (repair, decimate), :mod:`~r2s.synth.catalog` (the
curated objects), :mod:`~r2s.synth.appearance` (colours and textures),
:mod:`~r2s.synth.physics` (drop, settle, verify), :mod:`~r2s.synth.camera`,
:mod:`~r2s.synth.render`, :mod:`~r2s.synth.depth_noise`, :mod:`~r2s.synth.priors`,
:mod:`~r2s.synth.effects` and :mod:`~r2s.synth.generate` (the driver).
"""
