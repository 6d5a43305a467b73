"""r2s.lazy_imports: open3d without its Dash/Plotly drawing module until it is used."""

import subprocess
import sys

CHILD = """
import sys
import numpy as np
import r2s
import open3d as o3d
print('dash' in sys.modules, 'plotly' in sys.modules)
pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.eye(3)))
fig = o3d.visualization.get_plotly_fig([pc])
print('dash' in sys.modules, type(fig).__module__, len(fig.data[0].x))
"""


def test_open3d_drawing_is_imported_only_when_called():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         check=True).stdout.split("\n")
    assert out[0] == "False False"
    # the real function ran: a plotly figure holding the three points
    assert out[1] == "True plotly.graph_objs._figure 3"


STAGES_CHILD = """
import sys
import r2s.runner.pipeline
print('scipy.stats' in sys.modules)
"""


def test_the_stages_do_not_import_scipy_stats():
    """scipy.stats costs about a second per process; only diagnose's noise bars use it,
    and they import it when they run (tests/test_diagnose_loop.py checks their values)."""
    out = subprocess.run([sys.executable, "-c", STAGES_CHILD], capture_output=True,
                         text=True, check=True).stdout.split("\n")
    assert out[0] == "False"
