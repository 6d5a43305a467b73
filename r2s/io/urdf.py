"""One URDF per exported object (a single link, convex collision pieces, explicit inertia)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence
from xml.sax.saxutils import quoteattr

import numpy as np


def urdf_text(name: str, visual_mesh_rel: str, collision_meshes_rel: Sequence[str],
              mass_kg: float, com_in_object: Sequence[float], inertia_about_com: np.ndarray,
              friction: float, restitution: float = 0.0) -> str:
    """URDF XML for one rigid object whose link frame is the object frame.

    Paths are relative to the URDF file. ``inertia_about_com`` is (3, 3) in the object frame.
    """
    i = np.asarray(inertia_about_com, dtype=float)
    com = " ".join(f"{float(x):.9g}" for x in com_in_object)
    lines = [
        '<?xml version="1.0"?>',
        f"<robot name={quoteattr(name)}>",
        f"  <link name={quoteattr(name + '_link')}>",
        "    <contact>",
        f'      <lateral_friction value="{friction:.6g}"/>',
        f'      <restitution value="{restitution:.6g}"/>',
        "    </contact>",
        "    <inertial>",
        f'      <origin xyz="{com}" rpy="0 0 0"/>',
        f'      <mass value="{mass_kg:.9g}"/>',
        f'      <inertia ixx="{i[0, 0]:.9g}" ixy="{i[0, 1]:.9g}" ixz="{i[0, 2]:.9g}" '
        f'iyy="{i[1, 1]:.9g}" iyz="{i[1, 2]:.9g}" izz="{i[2, 2]:.9g}"/>',
        "    </inertial>",
        "    <visual>",
        '      <origin xyz="0 0 0" rpy="0 0 0"/>',
        f"      <geometry><mesh filename={quoteattr(visual_mesh_rel)}/></geometry>",
        "    </visual>",
    ]
    for rel in collision_meshes_rel:
        lines += [
            "    <collision>",
            '      <origin xyz="0 0 0" rpy="0 0 0"/>',
            f"      <geometry><mesh filename={quoteattr(rel)}/></geometry>",
            "    </collision>",
        ]
    lines += ["  </link>", "</robot>", ""]
    return "\n".join(lines)


def relative(path: Path, start: Path) -> str:
    import os

    return os.path.relpath(path, start)
