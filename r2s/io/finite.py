"""Find non-finite numbers (NaN, inf) in parsed JSON-like data.

Python's JSON reader accepts ``NaN`` and ``Infinity``; a state or export holding one would
otherwise travel silently into a simulation. :func:`first_non_finite` names the first such
number by its path, e.g. ``objects[1].world_from_object[0][3]``.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np


def first_non_finite(data: Any, where: str = "") -> Optional[str]:
    """Path of the first NaN/inf number in ``data`` (dicts, lists, floats, arrays), or None."""
    if isinstance(data, (float, np.floating)):
        return None if math.isfinite(float(data)) else (where or "value")
    if isinstance(data, np.ndarray):
        if data.dtype.kind in "fc" and not np.all(np.isfinite(data)):
            idx = np.argwhere(~np.isfinite(data))[0]
            return where + "".join(f"[{int(i)}]" for i in idx)
        return None
    if isinstance(data, dict):
        for key, value in data.items():
            found = first_non_finite(value, f"{where}.{key}" if where else str(key))
            if found:
                return found
    elif isinstance(data, (list, tuple)):
        for k, value in enumerate(data):
            found = first_non_finite(value, f"{where}[{k}]")
            if found:
                return found
    return None
