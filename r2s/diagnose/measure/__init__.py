"""Measuring the residuals: reading a scene directory and everything it needs
(:mod:`.scene_dir`), the ground-truth errors (:mod:`.gt_errors`), prior scale
(:mod:`.scale_fit`), PyBullet rollouts and contacts (:mod:`.physics`), pushes
(:mod:`.interaction`), and all residual groups from loaded data (:mod:`.observe`)."""
