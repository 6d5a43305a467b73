"""Derive a scene declared in its camera's frame: ``world_from_camera`` = identity.

What a user who does not know the camera's extrinsics gives. ``SRC``'s ``input/`` is
copied to ``DST`` with camera.json's pose replaced by the identity and every prior's
``world_from_prior`` re-expressed in the camera frame (so the input stays consistent);
``gt/`` is left out, since it lives in the true world (compare the observation metrics of
``r2s evaluate``: stability, silhouette IoU, UCD, free space).

Usage::

    python scripts/camera_frame_scene.py bench/s_A/scene_02_prior /tmp/camera_frame
    r2s run /tmp/camera_frame --skip texture
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    args = ap.parse_args()
    if args.dst.exists():
        shutil.rmtree(args.dst)
    shutil.copytree(args.src / "input", args.dst / "input")
    camera_path = args.dst / "input" / "camera.json"
    camera = json.loads(camera_path.read_text())
    camera_from_world = np.linalg.inv(np.asarray(camera["world_from_camera"], dtype=float))
    camera["world_from_camera"] = np.eye(4).tolist()
    camera_path.write_text(json.dumps(camera, indent=1))
    objects_path = args.dst / "input" / "objects.json"
    if objects_path.is_file():
        objects = json.loads(objects_path.read_text())
        for obj in objects.get("objects", []):
            if "world_from_prior" in obj:
                obj["world_from_prior"] = (camera_from_world
                                           @ np.asarray(obj["world_from_prior"])).tolist()
        objects_path.write_text(json.dumps(objects, indent=1))
    print(f"{args.dst}: input/ declared in the camera frame (world_from_camera = identity)")


if __name__ == "__main__":
    main()
