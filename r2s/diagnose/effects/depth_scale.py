"""Effect ``depth_scale``: the depth sensor reads ``s`` times the true depth."""

from r2s.diagnose.effects._depth import DepthBiasEffect

EFFECT = DepthBiasEffect("depth_scale", fit_scale=True, fit_offset=False, preference=10)
