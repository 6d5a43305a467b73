"""Measuring the residuals on loaded data: prior scale (:mod:`.scale_fit`), PyBullet
rollouts and contacts (:mod:`.physics`), pushes (:mod:`.interaction`), and all groups of a
scene (:mod:`.observe`)."""
