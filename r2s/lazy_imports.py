"""Start-up: keep third-party imports that r2s never uses out of every process.

``import open3d`` imports ``open3d.visualization.draw_plotly``, which imports Dash, Flask
and Plotly (about 0.6 s of CPU per process, measured with ``python -X importtime``), only
for three notebook drawing functions r2s does not call. :func:`defer_open3d_plotly`
registers a stand-in for that one module before open3d is imported: its three functions
import the real module on their first call and hand over to it, so a caller that does
use them gets the same functions, only later. Standard library only.
"""

from __future__ import annotations

import importlib.util
import sys
import types

OPEN3D_PLOTLY = "open3d.visualization.draw_plotly"
PLOTLY_FUNCTIONS = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")
"""What ``open3d.visualization`` imports from :data:`OPEN3D_PLOTLY`."""


def _load_real() -> types.ModuleType:
    """Execute the real ``draw_plotly`` module and put it in ``sys.modules``."""
    spec = importlib.util.find_spec("open3d.visualization")
    assert spec is not None and spec.submodule_search_locations
    real_spec = importlib.util.spec_from_file_location(
        OPEN3D_PLOTLY, f"{list(spec.submodule_search_locations)[0]}/draw_plotly.py")
    assert real_spec is not None and real_spec.loader is not None
    module = importlib.util.module_from_spec(real_spec)
    sys.modules[OPEN3D_PLOTLY] = module
    real_spec.loader.exec_module(module)
    return module


def _forwarder(name: str):
    def call(*args, **kwargs):
        module = sys.modules.get(OPEN3D_PLOTLY)
        if module is None or getattr(module, "__r2s_stand_in__", False):
            module = _load_real()
        return getattr(module, name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"open3d.visualization.{name}, imported on its first call (r2s start-up)."
    return call


def defer_open3d_plotly() -> None:
    """Register the stand-in unless open3d (or the module itself) is already imported."""
    if "open3d" in sys.modules or OPEN3D_PLOTLY in sys.modules:
        return
    stand_in = types.ModuleType(OPEN3D_PLOTLY, "Stand-in: see r2s.lazy_imports.")
    stand_in.__r2s_stand_in__ = True
    for name in PLOTLY_FUNCTIONS:
        setattr(stand_in, name, _forwarder(name))
    sys.modules[OPEN3D_PLOTLY] = stand_in
