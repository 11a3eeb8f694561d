"""Trapezoidal velocity profiles: how long a straight move takes under a speed cap and an
acceleration cap, and how far along it is at a given time. One place for the motion model
that the mock robots move by and that adaptive acquisition plans robot time with.

A move of length ``d`` (mm for a linear move, degrees for a rotation) accelerates at ``a``
up to ``v`` (or less, when ``d`` is too short to reach it: a triangular profile), cruises,
and decelerates at ``a`` to rest. Units: mm, mm/s, mm/s² (or deg, deg/s, deg/s²); s.

A Cartesian move that translates and rotates takes the longer of its translation and
rotation profiles; both parts are then run on that duration (the slower part sets the time,
as on a UR controller's ``movel`` and a DENSO ``MOVE L``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Trapezoid", "move_duration", "trapezoid_duration"]


def _check(name: str, value: float) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    return v


@dataclass(frozen=True)
class Trapezoid:
    """A rest-to-rest profile over ``distance`` (≥ 0) with speed cap ``speed`` and
    acceleration cap ``accel`` (both > 0). ``duration`` in s; ``fraction(t)`` the share of
    the distance covered at time t after the start (0…1, monotone)."""

    distance: float
    speed: float
    accel: float

    def __post_init__(self) -> None:
        d = float(self.distance)
        if not (math.isfinite(d) and d >= 0):
            raise ValueError(f"distance must be finite and ≥ 0, got {self.distance!r}")
        _check("speed", self.speed)
        _check("accel", self.accel)

    @property
    def peak_speed(self) -> float:
        """The highest speed reached: the cap, or √(d·a) on a triangular profile."""
        return min(self.speed, math.sqrt(self.distance * self.accel))

    @property
    def ramp_s(self) -> float:
        """Time to accelerate to the peak speed (s); deceleration takes as long."""
        return self.peak_speed / self.accel

    @property
    def duration(self) -> float:
        """Time from rest to rest (s): 2·ramp + cruise."""
        if self.distance == 0:
            return 0.0
        vp = self.peak_speed
        cruise = (self.distance - vp * vp / self.accel) / vp
        return 2.0 * self.ramp_s + max(cruise, 0.0)

    def position(self, t: float) -> float:
        """Distance covered at time ``t`` (s) after the start, clamped to [0, distance]."""
        if self.distance == 0 or t >= self.duration:
            return self.distance
        if t <= 0:
            return 0.0
        vp, tr, T = self.peak_speed, self.ramp_s, self.duration
        if t < tr:
            return 0.5 * self.accel * t * t
        if t <= T - tr:
            return 0.5 * vp * tr + vp * (t - tr)
        left = T - t
        return self.distance - 0.5 * self.accel * left * left

    def fraction(self, t: float) -> float:
        """Share of the distance covered at time ``t`` (0…1)."""
        return 1.0 if self.distance == 0 else min(1.0, self.position(t) / self.distance)


def trapezoid_duration(distance: float, speed: float, accel: float) -> float:
    """Seconds a rest-to-rest move of ``distance`` takes at speed cap ``speed`` and
    acceleration cap ``accel`` (consistent units, e.g. mm, mm/s, mm/s²)."""
    return Trapezoid(abs(float(distance)), speed, accel).duration


def move_duration(start: np.ndarray, target: np.ndarray, speed_mm_s: float,
                  accel_mm_s2: float, rot_speed_deg_s: float | None = None,
                  rot_accel_deg_s2: float | None = None) -> float:
    """Seconds a straight Cartesian move from ``start`` to ``target`` (base_from_flange 4×4,
    mm) takes: the longer of the translation profile (``speed_mm_s``, ``accel_mm_s2``) and,
    when rotation caps are given, the rotation profile (geodesic angle in degrees at
    ``rot_speed_deg_s``, ``rot_accel_deg_s2``)."""
    start = np.asarray(start, dtype=float)
    target = np.asarray(target, dtype=float)
    d = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
    t = trapezoid_duration(d, speed_mm_s, accel_mm_s2)
    if rot_speed_deg_s is not None and rot_accel_deg_s2 is not None:
        R = start[:3, :3].T @ target[:3, :3]
        ang = math.degrees(math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0))))
        t = max(t, trapezoid_duration(ang, rot_speed_deg_s, rot_accel_deg_s2))
    return t
