"""Validation primitives of session lines, shared by the records (pose and header lines) and
the truth of simulated sessions: the reason a line fails (``BadLine``), rigid 4×4 mm matrices,
bounded lists of numbers. No file I/O."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: sanity bounds: a translation beyond 10 km is corruption
_MAX_TRANS_MM = 1e7
_RIGID_TOL = 1e-4


class BadLine(Exception):
    """A line fails validation; the message is the reason without file and line."""


_NUMBER_TYPES = frozenset((int, float))
_EYE3 = np.eye(3)


def is_number(x: Any) -> bool:
    return type(x) in _NUMBER_TYPES  # not bool, not str


def parse_matrix(value: Any, name: str) -> np.ndarray | None:
    """A 4×4 rigid transform (mm) from a JSON value, or None for null."""
    if value is None:
        return None
    if not (type(value) is list and len(value) == 4
            and all(type(r) is list and len(r) == 4 for r in value)):
        raise BadLine(f"field '{name}': expected a 4×4 matrix (4 rows of 4 numbers)")
    if not all(_NUMBER_TYPES.issuperset(map(type, r)) for r in value):
        raise BadLine(f"field '{name}': entries must be numbers")
    try:
        M = np.array(value, dtype=np.float64)
    except (OverflowError, ValueError, TypeError):
        raise BadLine(f"field '{name}': a number is out of range") from None
    if not np.isfinite(M).all():
        raise BadLine(f"field '{name}': contains NaN or infinity")
    r3 = M[3]
    if abs(r3[0]) > 1e-9 or abs(r3[1]) > 1e-9 or abs(r3[2]) > 1e-9 or abs(r3[3] - 1) > 1e-9:
        raise BadLine(f"field '{name}': last row {r3.tolist()} is not [0, 0, 0, 1]")
    A = np.abs(M[:3])
    if A[:, 3].max() > _MAX_TRANS_MM:
        raise BadLine(f"field '{name}': translation beyond {_MAX_TRANS_MM:.0e} mm")
    R = M[:3, :3]
    # entries of a rotation are within [-1, 1]; checking first keeps the products finite
    if A[:, :3].max() > 1 + 1e-3 or np.abs(R @ R.T - _EYE3).max() > _RIGID_TOL:
        raise BadLine(f"field '{name}': not a rigid transform (rotation block not orthonormal)")
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    if abs(a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) - 1) > _RIGID_TOL:
        raise BadLine(f"field '{name}': not a rigid transform (a reflection, det ≠ 1)")
    return M



#: at most this many joint angles per pose (DENSO's CurJnt carries up to 32 axes)
MAX_JOINTS = 32
#: a joint angle beyond ±1000 rad, a force or torque beyond 10⁶ N or N·m is corruption
MAX_JOINT_RAD = 1e3
MAX_WRENCH = 1e6


def parse_numbers(value: Any, name: str, what: str, n: int, bound: float, exact: bool = False,
             nonneg: bool = False) -> list[float] | None:
    """An optional list of finite numbers (None for an absent field or null): exactly ``n``
    with ``exact``, else 1 to ``n``; each of magnitude below ``bound`` (and ≥ 0 with
    ``nonneg``)."""
    if value is None:
        return None
    count = f"{n}" if exact else f"1 to {n}"
    if not (type(value) is list and (len(value) == n if exact else 1 <= len(value) <= n)
            and all(is_number(x) for x in value)):
        raise BadLine(f"field '{name}': expected a list of {count} numbers ({what})")
    out = []
    for x in value:
        try:
            f = float(x)
        except OverflowError:
            f = math.inf
        if not (math.isfinite(f) and abs(f) < bound) or (nonneg and f < 0):
            raise BadLine(f"field '{name}': {str(x)[:40]} is out of range (a finite number"
                       f"{' ≥ 0' if nonneg else ''} of magnitude below {bound:g})")
        out.append(f)
    return out

