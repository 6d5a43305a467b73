"""An MJCF (MuJoCo) version of ``export/``: ``export/scene.xml``.

Each object is a free body whose geoms are the exported convex pieces (MuJoCo takes the
convex hull of every mesh geom, so pieces map one to one), with the exported mass, COM,
inertia and friction; the support is a plane with its friction. MuJoCo combines two geoms'
sliding friction with ``max`` where PyBullet multiplies; the written value for each object
is the product with the support's value, so that an object on the table sees the same
coefficient in both engines.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from r2s.io.atomic import atomic_write_text
from r2s.io.paths import EXPORT_MJCF_FILE


def _vec(v: Sequence[float]) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def mjcf_text(scene: dict, inertias: dict[int, np.ndarray]) -> str:
    """MJCF XML for an export scene dict (as written to scene.json).

    ``inertias``: object id -> (3, 3) inertia about the COM in the object frame.
    Mesh paths stay relative to ``export/``, where scene.xml is written.
    """
    support = scene["support"]
    normal = np.asarray(support["normal"], dtype=float)
    normal /= np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normal)
    if np.linalg.norm(axis) < 1e-12:
        plane_quat = [1.0, 0.0, 0.0, 0.0] if normal[2] > 0 else [0.0, 1.0, 0.0, 0.0]
    else:
        angle = np.arccos(np.clip(normal @ z, -1, 1))
        x, y, zq, w = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_quat()
        plane_quat = [w, x, y, zq]
    mu_support = float(support.get("friction", 0.8))
    assets, bodies = [], []
    for obj in scene["objects"]:
        oid = int(obj["id"])
        pose = np.asarray(obj["world_from_object"], dtype=float)
        x, y, zq, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
        inertia = np.asarray(inertias[oid], dtype=float)
        evals, evecs = np.linalg.eigh(inertia)
        if np.linalg.det(evecs) < 0:
            evecs[:, 0] *= -1
        ix, iy, iz, iw = Rotation.from_matrix(evecs).as_quat()
        mu = float(obj["friction"]) * mu_support
        geoms = []
        for k, rel in enumerate(obj["collision_meshes"]):
            name = f"m{oid}_{k}"
            assets.append(f"    <mesh name={quoteattr(name)} file={quoteattr(rel)}/>")
            geoms.append(f"      <geom type=\"mesh\" mesh={quoteattr(name)} "
                         f"friction=\"{mu:.6g} 0.005 0.0001\" condim=\"4\"/>")
        bodies.append("\n".join([
            f"    <body name=\"object_{oid}\" pos=\"{_vec(pose[:3, 3])}\" "
            f"quat=\"{_vec([w, x, y, zq])}\">",
            "      <freejoint/>",
            f"      <inertial pos=\"{_vec(obj['com_in_object'])}\" quat=\"{_vec([iw, ix, iy, iz])}\" "
            f"mass=\"{float(obj['mass_kg']):.9g}\" diaginertia=\"{_vec(np.maximum(evals, 1e-9))}\"/>",
            *geoms,
            "    </body>",
        ]))
    return "\n".join([
        '<mujoco model="r2s-scene">',
        '  <compiler angle="radian" meshdir="."/>',
        f'  <option timestep="{1.0 / 240.0:.9g}" gravity="{_vec(scene["gravity"])}" cone="elliptic"/>',
        "  <asset>",
        *assets,
        "  </asset>",
        "  <worldbody>",
        f'    <geom name="support" type="plane" size="5 5 0.1" pos="{_vec(support["point"])}" '
        f'quat="{_vec(plane_quat)}" friction="{mu_support:.6g} 0.005 0.0001" condim="4"/>',
        *bodies,
        "  </worldbody>",
        "</mujoco>",
        "",
    ])


def write_mjcf(export_dir: Path, scene: dict, inertias: dict[int, np.ndarray]) -> Path:
    path = Path(export_dir) / EXPORT_MJCF_FILE
    atomic_write_text(path, mjcf_text(scene, inertias))
    return path
