"""A second judge: roll ``export/scene.xml`` out in MuJoCo and record the same trajectory
as the PyBullet rollout, so stability can be compared between engines.

MuJoCo reports each free body's frame pose (``xpos``, ``xquat``): with the body placed at
``world_from_object`` that frame is the object frame. Velocities are MuJoCo's own
(``mj_objectVelocity`` at the COM, world frame).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from r2s.errors import StageError
from r2s.io.scene_json import read_export_scene
from r2s.sim.rollout import Trajectory
from r2s.io.paths import EXPORT_MJCF_FILE, EXPORT_SCENE_FILE


def mujoco_rollout(export_dir: Path, duration_s: float = 3.0, record_hz: float = 60.0
                   ) -> Trajectory:
    """Simulate ``export_dir/scene.xml`` under gravity; objects in scene.json order."""
    try:
        import mujoco
    except ImportError:
        raise StageError("engine=mujoco needs the 'mujoco' package (pip install mujoco)") from None
    export_dir = Path(export_dir)
    xml = export_dir / EXPORT_MJCF_FILE
    if not xml.is_file():
        raise StageError(f"{xml} is missing; rerun 'r2s export' to write the MJCF scene")
    scene = read_export_scene(export_dir / EXPORT_SCENE_FILE)
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    ids = np.array([o.id for o in scene.objects])
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"object_{i}") for i in ids]
    com = np.array([o.com_in_object for o in scene.objects], dtype=float)
    steps_per_record = max(1, int(round(1.0 / (record_hz * model.opt.timestep))))
    n_records = int(round(duration_s / (steps_per_record * model.opt.timestep))) + 1
    poses = np.zeros((n_records, len(ids), 4, 4))
    lin = np.zeros((n_records, len(ids), 3))
    ang = np.zeros((n_records, len(ids), 3))
    times = np.zeros(n_records)
    vel6 = np.zeros(6)
    mujoco.mj_forward(model, data)
    for r in range(n_records):
        if r > 0:
            for _ in range(steps_per_record):
                mujoco.mj_step(model, data)
        times[r] = data.time
        for n, b in enumerate(bodies):
            poses[r, n] = np.eye(4)
            poses[r, n, :3, :3] = data.xmat[b].reshape(3, 3)
            poses[r, n, :3, 3] = data.xpos[b]
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel6, 0)
            ang[r, n], lin[r, n] = vel6[:3], vel6[3:]
    # mj_objectVelocity gives the velocity at the body's COM (xipos) in world axes
    return Trajectory(ids=ids, times_s=times - times[0], world_from_object=poses,
                      linear_velocity_mps=lin, angular_velocity_radps=ang, com_in_object=com)
