"""Derive a scene in which the segmenter missed an object: its mask pixels set to 0.

Segmentation networks miss objects (small, transparent, unusual ones). ``SRC``'s
``input/`` and ``gt/`` are copied to ``DST`` with instance ``--id`` removed from
masks.png and objects.json; gt/scene.json drops it too (the reconstruction is not asked
for it), while its depth stays in the image, as a missed object's would.

Usage::

    python scripts/unmask_instance.py bench/s_A/scene_02_noprior /tmp/missed --id 1
    r2s run /tmp/missed --skip texture
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image


def unmask(src: Path, dst: Path, obj_id: int) -> int:
    """Write the derived scene; returns how many pixels the instance had."""
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    shutil.copytree(src / "input", dst / "input")
    masks = np.array(Image.open(src / "input" / "masks.png"))
    area = int((masks == obj_id).sum())
    masks[masks == obj_id] = 0
    Image.fromarray(masks).save(dst / "input" / "masks.png")
    objects = dst / "input" / "objects.json"
    if objects.is_file():
        data = json.loads(objects.read_text())
        data["objects"] = [o for o in data.get("objects", []) if o["id"] != obj_id]
        objects.write_text(json.dumps(data, indent=1))
    if (src / "gt").is_dir():
        shutil.copytree(src / "gt", dst / "gt")
        gt = json.loads((dst / "gt" / "scene.json").read_text())
        gt["objects"] = [o for o in gt["objects"] if o["id"] != obj_id]
        (dst / "gt" / "scene.json").write_text(json.dumps(gt, indent=1))
    return area


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("--id", type=int, required=True, help="instance id to unmask")
    args = ap.parse_args()
    area = unmask(args.src, args.dst, args.id)
    print(f"{args.dst}: instance {args.id} ({area} px) unmasked")


if __name__ == "__main__":
    main()
