"""Plain JSON / YAML types from numpy values: the one converter every layer uses (the session
writer, the solve results, the exports, ``--json`` output).

``plain`` turns arrays and numpy scalars inside dicts, lists and tuples into lists, ints and
floats (keys into strings); ``json_safe`` also turns NaN and infinities into None, for strict
JSON; ``json_default`` is the same conversion as ``json.dumps``' ``default`` hook. Units are
whatever the values carry (mm, degrees, s); nothing is converted.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["plain", "json_safe", "json_default"]


def plain(v: Any) -> Any:
    """Arrays and numpy scalars inside dicts and lists as plain JSON / YAML types."""
    if isinstance(v, dict):
        return {str(k): plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return plain(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    return v


def json_safe(obj: Any) -> Any:
    """``obj`` as :func:`plain` gives it, with every NaN or infinity as None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def json_default(o: Any) -> Any:
    """``json.dumps``' ``default``: numpy arrays and scalars as plain lists and numbers;
    TypeError naming the type for anything else."""
    if isinstance(o, (np.ndarray, np.generic)):
        return plain(o)
    raise TypeError(f"{type(o).__name__!r} is not JSON-serialisable")
