"""``r2s view``: look at a scene directory in the browser (built on viser).

:mod:`r2s.viewer.scene_data` reads the files (no viser), :mod:`r2s.viewer.playback`
re-simulates export/ for the rollout player, :mod:`r2s.viewer.server` builds the viser
scene and its controls, :mod:`r2s.viewer.browser` takes screenshots with headless Chromium.
"""
