"""Effect ``depth_bias``: depth scale and offset together, ``z_obs = s z + o`` (2 parameters)."""

from r2s.diagnose.effects._depth import DepthBiasEffect

EFFECT = DepthBiasEffect("depth_bias", fit_scale=True, fit_offset=True, preference=12)
