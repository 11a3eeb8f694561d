"""The safety envelope: the limits a robot's flange and tool points must respect, and the checks
of one pose (``Envelope.violations`` / ``check_pose``) and of one commanded speed and
acceleration (``check_speed``). Where a whole move goes between two poses is checked in
:mod:`tmscal.safety.paths`; how fast its tool points go, in :mod:`tmscal.safety.laws`.

Frames and units: poses are base_from_flange 4×4 in mm; the workspace box is in the robot base
frame (mm); tool points are in the FLANGE frame (mm); speeds mm/s, accelerations mm/s².
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import SafetyError
from ..geometry import angle_between, check_pose

__all__ = ["Envelope", "positive_finite"]

#: comparisons against a limit accept this much (mm, degrees, mm/s) of rounding
LIMIT_TOL = 1e-9


def _limit(name: str, value: Any) -> float | None:
    """A positive finite limit (or None); anything else raises ValueError naming it."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"Envelope.{name}: expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        raise ValueError(f"Envelope.{name}: {value!r} is too large") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"Envelope.{name}: expected a finite number > 0, got {value!r}")
    return v


def _points(name: str, value: Any, k: int | None = None) -> np.ndarray:
    """A (k, 3) finite float array, read-only; anything else raises ValueError naming it."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as e:
        raise ValueError(f"Envelope.{name}: expected [x, y, z] points in mm ({e})") from None
    if a.ndim == 1 and k == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3 or (k is not None and a.shape[0] != k):
        raise ValueError(f"Envelope.{name}: expected [x, y, z] points in mm, got shape "
                         f"{a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"Envelope.{name}: every coordinate must be finite, got "
                         f"{a.tolist()}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Envelope:
    """Safety envelope for robot motion. Poses are base_from_flange, mm.

    ``center`` (P0, base_from_flange 4×4 mm) with ``max_offset_mm`` (distance of the flange
    origin from P0) and ``max_rotation_deg`` (rotation angle away from P0, degrees);
    ``box_min_mm``/``box_max_mm`` a workspace box in the robot base frame (mm) that the flange
    origin and every one of ``tool_points_mm`` (k×3 points in the FLANGE frame, mm: the coil
    centre, points on the coil's rim) must stay inside; ``max_speed_mm_s`` and
    ``max_accel_mm_s2`` caps.

    Any limit left None is not checked. Limits that are given are validated when the envelope
    is built (ValueError for NaN, ±inf, non-positive caps, a box with min ≥ max on an axis),
    and ``violations`` fails closed: a comparison that cannot be made counts as a violation.

    This class checks ONE pose; ``Robot.move_to`` checks the whole way between two poses
    (:func:`tmscal.safety.plan_move`, docs/safety.md) and holds the speed and acceleration
    caps for every tool point, not only the flange.
    """

    center: np.ndarray | None = None
    max_offset_mm: float | None = None
    max_rotation_deg: float | None = None
    box_min_mm: tuple[float, float, float] | None = None
    box_max_mm: tuple[float, float, float] | None = None
    max_speed_mm_s: float | None = None
    max_accel_mm_s2: float | None = None
    tool_points_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        put = object.__setattr__
        for name in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s", "max_accel_mm_s2"):
            put(self, name, _limit(name, getattr(self, name)))
        if self.center is not None:
            c = np.array(self.center, dtype=np.float64)
            if c.shape != (4, 4) or not np.isfinite(c).all():
                raise ValueError(f"Envelope.center: expected a finite 4×4 pose (mm), got shape "
                                 f"{c.shape}")
            c.setflags(write=False)
            put(self, "center", c)
        if (self.box_min_mm is None) != (self.box_max_mm is None):
            raise ValueError("Envelope: give both box_min_mm and box_max_mm, or neither")
        if self.box_min_mm is not None:
            lo = _points("box_min_mm", self.box_min_mm, 1)[0]
            hi = _points("box_max_mm", self.box_max_mm, 1)[0]
            if not (lo < hi).all():
                raise ValueError(f"Envelope: box_min_mm {lo.tolist()} must be below box_max_mm "
                                 f"{hi.tolist()} on every axis")
            put(self, "box_min_mm", tuple(float(x) for x in lo))
            put(self, "box_max_mm", tuple(float(x) for x in hi))
        if self.tool_points_mm is not None:
            put(self, "tool_points_mm", _points("tool_points_mm", self.tool_points_mm))

    @property
    def has_box(self) -> bool:
        """True when a workspace box is set."""
        return self.box_min_mm is not None and self.box_max_mm is not None

    def checked_points(self) -> tuple[np.ndarray, list[str]]:
        """The points whose place the box bounds, in the FLANGE frame (k+1, 3) mm: the flange
        origin first, then every tool point; and their names for messages."""
        pts = [np.zeros(3)]
        names = ["flange origin"]
        if self.tool_points_mm is not None:
            for i, q in enumerate(self.tool_points_mm):
                pts.append(np.asarray(q, dtype=np.float64))
                names.append(f"tool point {i} {np.round(q, 1).tolist()} (flange frame)")
        return np.array(pts, dtype=np.float64), names

    def violations(self, pose: np.ndarray) -> list[str]:
        """Every limit this base_from_flange pose (mm) breaks, as readable strings. A pose that
        is not a finite rigid 4×4 is one violation; a NaN comparison is a violation."""
        try:
            p = check_pose(pose, "pose")
        except (ValueError, TypeError) as e:
            return [f"pose is not a finite rigid 4×4 matrix ({e})"]
        out: list[str] = []
        t = p[:3, 3]
        if self.center is not None:
            c = self.center
            if self.max_offset_mm is not None:
                d = float(np.linalg.norm(t - c[:3, 3]))
                if not d <= self.max_offset_mm + LIMIT_TOL:
                    out.append(f"offset from P0 {d:.1f} mm > max_offset_mm {self.max_offset_mm}")
            if self.max_rotation_deg is not None:
                ang = float(np.degrees(angle_between(c, p)))
                if not ang <= self.max_rotation_deg + LIMIT_TOL:
                    out.append(f"rotation from P0 {ang:.2f}° > max_rotation_deg "
                               f"{self.max_rotation_deg}")
        if self.box_min_mm is not None and self.box_max_mm is not None:
            lo = np.asarray(self.box_min_mm, dtype=np.float64)
            hi = np.asarray(self.box_max_mm, dtype=np.float64)
            pts = [("flange origin", t)]
            if self.tool_points_mm is not None:
                base = self.tool_points_mm @ p[:3, :3].T + t
                pts += [(f"tool point {i} {np.round(q, 1).tolist()} (flange frame)", b)
                        for i, (q, b) in enumerate(zip(self.tool_points_mm, base))]
            for what, b in pts:
                if not (np.all(b >= lo - LIMIT_TOL) and np.all(b <= hi + LIMIT_TOL)):
                    out.append(f"{what} at {np.round(b, 1).tolist()} mm outside workspace box "
                               f"{lo.tolist()}..{hi.tolist()}")
        return out

    def check_pose(self, pose: np.ndarray, what: str = "pose") -> None:
        """Raise ``SafetyError`` naming the pose and the limits it breaks."""
        v = self.violations(pose)
        if v:
            raise SafetyError(f"{what} refused: " + "; ".join(v))

    def check_speed(self, speed_mm_s: float, accel_mm_s2: float | None = None) -> None:
        """Raise ``SafetyError`` if a speed (mm/s) or acceleration (mm/s²) is not a positive
        finite number or exceeds its cap."""
        if not positive_finite(speed_mm_s):
            raise SafetyError(f"speed {speed_mm_s!r} mm/s is not a positive finite number")
        cap = self.max_speed_mm_s
        if cap is not None and not speed_mm_s <= cap + LIMIT_TOL:
            raise SafetyError(f"speed {speed_mm_s} mm/s > max_speed_mm_s {self.max_speed_mm_s}")
        if accel_mm_s2 is None:
            return
        if not positive_finite(accel_mm_s2):
            raise SafetyError(f"acceleration {accel_mm_s2!r} mm/s² is not a positive finite "
                              "number")
        cap = self.max_accel_mm_s2
        if cap is not None and not accel_mm_s2 <= cap + LIMIT_TOL:
            raise SafetyError(f"acceleration {accel_mm_s2} mm/s² > max_accel_mm_s2 "
                              f"{self.max_accel_mm_s2}")


def positive_finite(x: Any) -> bool:
    """True for a real number (not bool) that is finite and > 0."""
    if isinstance(x, bool) or not isinstance(x, int | float | np.integer | np.floating):
        return False
    try:
        return math.isfinite(float(x)) and float(x) > 0
    except OverflowError:
        return False

