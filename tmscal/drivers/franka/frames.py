"""The conversions at the Franka edge: pure numpy, no ``franky`` needed.

libfranka's frames (docs/devices.md, "Franka"): O is the robot base, F the flange, NE the
nominal end effector (the one set in Desk, e.g. the Franka Hand: ``F_T_NE``), EE the end
effector (``NE_T_EE``, set from the client, identity unless set). The controller reports and
commands ``O_T_EE``, the END-EFFECTOR pose, with ``F_T_EE = F_T_NE · NE_T_EE``; tmscal's
robot poses are the FLANGE: base_from_flange = O_T_EE · F_T_EE⁻¹, and the end-effector target
that puts the flange at base_from_flange is base_from_flange · F_T_EE. libfranka works in
metres (4×4, or 16 values column-major); tmscal in mm.

Speed and acceleration caps: franky plans a Cartesian motion with Ruckig over x, y and z
SEPARATELY, each within ``translation_velocity_limit`` · factor (and likewise for the
acceleration and jerk), so the speed of the flange along a diagonal can reach √3 times the
per-axis limit. ``dynamics_factors`` therefore asks for factor = cap / (√3 · limit), so the
Euclidean speed and acceleration stay at or below the caps whatever the direction.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ...geometry import check_pose, invert

__all__ = ["matrix_m", "base_from_flange", "ee_target", "dynamics_factors", "MIN_FACTOR"]

#: the smallest relative dynamics factor asked for (franky accepts (0, 1]); a cap below
#: MIN_FACTOR of the robot's limit is refused rather than rounded up
MIN_FACTOR = 1e-4
_SQRT3 = math.sqrt(3.0)


def matrix_m(value: Any, what: str) -> np.ndarray:
    """A 4×4 float64 pose in metres from a franky ``Affine`` (``.matrix``), a 4×4 array, or
    libfranka's 16 values in column-major order. ``ValueError`` naming ``what`` when it is
    not a finite rigid transform."""
    m = getattr(value, "matrix", value)
    a = np.array(m, dtype=np.float64)
    if a.shape == (16,):
        a = a.reshape((4, 4), order="F")
    if a.shape != (4, 4):
        raise ValueError(f"{what}: expected a 4×4 pose or 16 values, got shape {a.shape}")
    return check_pose(a, what)


def _mm(pose_m: np.ndarray) -> np.ndarray:
    out = pose_m.copy()
    out[:3, 3] *= 1000.0
    return out


def _m(pose_mm: np.ndarray) -> np.ndarray:
    out = np.array(pose_mm, dtype=np.float64)
    out[:3, 3] /= 1000.0
    return out


def base_from_flange(O_T_EE: Any, F_T_EE: Any) -> np.ndarray:
    """base_from_flange (4×4 mm) from the reported end-effector pose ``O_T_EE`` and the
    flange-to-end-effector transform ``F_T_EE`` (both metres, as ``matrix_m`` accepts)."""
    return _mm(matrix_m(O_T_EE, "O_T_EE") @ invert(matrix_m(F_T_EE, "F_T_EE")))


def ee_target(base_from_flange_mm: np.ndarray, F_T_EE: Any) -> np.ndarray:
    """The end-effector pose O_T_EE (4×4, metres) that puts the flange at
    ``base_from_flange_mm`` (4×4 mm), given ``F_T_EE`` (metres)."""
    return _m(check_pose(base_from_flange_mm, "base_from_flange")) @ matrix_m(F_T_EE, "F_T_EE")


def dynamics_factors(speed_mm_s: float, accel_mm_s2: float, velocity_limit_m_s: float,
                     accel_limit_m_s2: float) -> tuple[float, float, float]:
    """(velocity, acceleration, jerk) relative dynamics factors in (0, 1] for a Cartesian
    motion whose flange speed must not exceed ``speed_mm_s`` (mm/s) nor its acceleration
    ``accel_mm_s2`` (mm/s²), given the robot's per-axis translation limits (m/s, m/s²):
    cap / (√3 · limit), at most 1 (the robot's own limits). The jerk factor equals the
    acceleration factor. ``ValueError`` for a non-positive or non-finite value, or a cap
    under ``MIN_FACTOR`` of the limit."""
    vals = {"speed_mm_s": speed_mm_s, "accel_mm_s2": accel_mm_s2,
            "velocity_limit_m_s": velocity_limit_m_s, "accel_limit_m_s2": accel_limit_m_s2}
    for k, v in vals.items():
        if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating) \
                or not (math.isfinite(v) and v > 0):
            raise ValueError(f"dynamics_factors: {k} must be a finite number > 0, got {v!r}")
    fv = min(1.0, speed_mm_s / 1000.0 / (_SQRT3 * velocity_limit_m_s))
    fa = min(1.0, accel_mm_s2 / 1000.0 / (_SQRT3 * accel_limit_m_s2))
    for name, f in (("speed", fv), ("acceleration", fa)):
        if f < MIN_FACTOR:
            raise ValueError(f"dynamics_factors: the {name} cap is below {MIN_FACTOR:g} of the "
                             "robot's limit (franky cannot plan so slow a motion)")
    return fv, fa, fa
