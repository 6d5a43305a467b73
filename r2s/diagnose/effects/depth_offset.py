"""Effect ``depth_offset``: the depth sensor reads the true depth plus a constant ``o``."""

from r2s.diagnose.effects._depth import DepthBiasEffect

EFFECT = DepthBiasEffect("depth_offset", fit_scale=False, fit_offset=True, preference=10)
