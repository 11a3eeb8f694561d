"""The ``safety`` section: the motion envelope a config that drives a robot must set in full
(docs/safety.md explains each rule), and the robot's speed and acceleration within its caps.

Every limit is a finite real (not a bool, string, NaN or ±inf), positive, below a
plausibility bound (10 m, 180°, 5 m/s, 50 m/s²: a larger value is a typo or a unit mistake);
the workspace box (robot base frame, mm) is ordered on every axis; tool points ([x, y, z] mm in
the FLANGE frame) are few and near the flange. -0.0 is read as 0.

Units sanity (values written in metres by mistake; each refused in one short line naming the
likely cause): tool points that all lie within ``TOOL_UNITS_MM`` of the flange on every axis
(a TMS coil hangs ~100 mm below it), a box whose every coordinate is below ``BOX_UNITS_MM``
in magnitude, speeds and accelerations (``robot.speed_mm_s``, ``robot.accel_mm_s2``,
``safety.max_speed_mm_s``, ``safety.max_accel_mm_s2``) below ``MIN_MOTION`` (1 mm/s, 1 mm/s²).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from .sections import RobotConfig, SafetyConfig
from .values import build, err, positive

__all__ = ["SAFETY_KEYS", "SAFETY_BOUNDS", "COORD_BOUND_MM", "TOOL_BOUND_MM",
           "MAX_TOOL_POINTS", "TOOL_UNITS_MM", "BOX_UNITS_MM", "MIN_MOTION", "parse_safety",
           "check_robot_caps", "check_motion_units", "warn_without_tool_points"]

log = logging.getLogger(__name__)

#: safety keys a config that drives a robot must set (no defaults for a robot)
SAFETY_KEYS = ("max_offset_mm", "max_rotation_deg", "workspace_min_mm", "workspace_max_mm",
               "max_speed_mm_s", "max_accel_mm_s2")
#: plausibility bounds of the safety limits (a larger value is a typo or a unit mistake)
SAFETY_BOUNDS = {"max_offset_mm": 10_000.0, "max_rotation_deg": 180.0,
                 "max_speed_mm_s": 5_000.0, "max_accel_mm_s2": 50_000.0}
COORD_BOUND_MM = 10_000.0   # |workspace coordinate| (mm, base frame)
TOOL_BOUND_MM = 2_000.0     # |tool point coordinate| (mm, flange frame)
MAX_TOOL_POINTS = 64
#: tool points that all lie within this (mm, every axis) of the flange look like metres
TOOL_UNITS_MM = 5.0
#: a box whose every coordinate is below this in magnitude (mm) looks like metres
BOX_UNITS_MM = 10.0
#: a speed (mm/s) or acceleration (mm/s²) below this looks like m/s or m/s²
MIN_MOTION = 1.0
#: the keys below ``MIN_MOTION`` and their units
_MOTION_UNITS = {"speed_mm_s": ("mm/s", "m/s"), "accel_mm_s2": ("mm/s²", "m/s²"),
                 "max_speed_mm_s": ("mm/s", "m/s"), "max_accel_mm_s2": ("mm/s²", "m/s²")}


def parse_safety(data: Any, src: str, drives_robot: bool) -> SafetyConfig:
    """The safety section of the config mapping ``data``: every limit finite, positive,
    plausible; box ordered; tool points finite. A config that drives a robot must set every
    key of ``SAFETY_KEYS``."""
    raw = data.get("safety")
    if drives_robot:
        if raw is None:
            raise err(src, "safety", "a config that drives a robot needs a safety section "
                      f"({', '.join(SAFETY_KEYS)})")
        if isinstance(raw, Mapping):
            for k in SAFETY_KEYS:
                if raw.get(k) is None:
                    raise err(src, f"safety.{k}", "missing: a config that drives a robot must "
                              f"set every safety limit ({', '.join(SAFETY_KEYS)})")
    safety = build(SafetyConfig, raw, src, "safety")
    for k, bound in SAFETY_BOUNDS.items():
        positive(src, f"safety.{k}", getattr(safety, k), at_most=bound)
        if k in _MOTION_UNITS:
            check_motion_units(src, f"safety.{k}", getattr(safety, k))
    _check_box(safety, src)
    if safety.tool_points_mm is not None:
        if len(safety.tool_points_mm) > MAX_TOOL_POINTS:
            raise err(src, "safety.tool_points_mm", f"at most {MAX_TOOL_POINTS} points")
        for i, q in enumerate(safety.tool_points_mm):
            if not all(abs(c) <= TOOL_BOUND_MM for c in q):
                raise err(src, f"safety.tool_points_mm[{i}]", f"{list(q)} mm: a tool point "
                          f"(flange frame) must be within ±{TOOL_BOUND_MM:g} mm of the "
                          "flange; check the units")
        if all(abs(c) < TOOL_UNITS_MM for q in safety.tool_points_mm for c in q):
            raise err(src, "safety.tool_points_mm", f"every point is within {TOOL_UNITS_MM:g} "
                      "mm of the flange: these look like metres; give mm (a coil is ~100 mm "
                      "below the flange)")
    return safety


def check_motion_units(src: str, key: str, value: float) -> None:
    """A speed (mm/s) or acceleration (mm/s²) ``key`` below ``MIN_MOTION`` looks like one in
    m/s or m/s²: ConfigError naming the key, the likely cause and the value in mm."""
    unit, si = _MOTION_UNITS[key.rpartition(".")[2]]
    if value < MIN_MOTION:
        raise err(src, key, f"{value:g} {unit} is below {MIN_MOTION:g} {unit}: this looks like "
                  f"{si}; give {unit} ({value:g} {si} = {value * 1000:g} {unit})")


def _check_box(safety: SafetyConfig, src: str) -> None:
    """Both corners or neither; coordinates within ±``COORD_BOUND_MM``; min < max per axis."""
    lo, hi = safety.workspace_min_mm, safety.workspace_max_mm
    if (lo is None) != (hi is None):
        raise err(src, "safety.workspace_min_mm", "give both workspace_min_mm and "
                  "workspace_max_mm, or neither")
    if lo is None or hi is None:
        return
    for key, xyz in (("safety.workspace_min_mm", lo), ("safety.workspace_max_mm", hi)):
        if not all(abs(c) <= COORD_BOUND_MM for c in xyz):
            raise err(src, key, f"{list(xyz)} mm: every coordinate must be within "
                      f"±{COORD_BOUND_MM:g} mm of the robot base; check the units")
    if all(abs(c) < BOX_UNITS_MM for c in (*lo, *hi)):
        raise err(src, "safety.workspace_min_mm", f"every coordinate of the box is below "
                  f"{BOX_UNITS_MM:g}: these look like metres; give mm ({_xyz(lo)} m = "
                  f"{_xyz(c * 1000 for c in lo)} mm)")
    for axis, a, b in zip("xyz", lo, hi, strict=True):
        if not a < b:
            raise err(src, "safety.workspace_max_mm", f"{axis} {b} must exceed "
                      f"workspace_min_mm {axis} {a}")


def _xyz(values: Any) -> str:
    return "[" + ", ".join(f"{c:.6g}" for c in values) + "]"


def check_robot_caps(robot: RobotConfig | None, safety: SafetyConfig, src: str) -> None:
    """The robot's configured speed (mm/s) and acceleration (mm/s²) are within the safety
    caps, and neither looks like one in m/s or m/s² (``check_motion_units``)."""
    if robot is not None:
        check_motion_units(src, "robot.speed_mm_s", robot.speed_mm_s)
        check_motion_units(src, "robot.accel_mm_s2", robot.accel_mm_s2)
    if robot is not None and robot.speed_mm_s > safety.max_speed_mm_s:
        raise err(src, "robot.speed_mm_s", f"{robot.speed_mm_s} mm/s exceeds "
                  f"safety.max_speed_mm_s {safety.max_speed_mm_s}")
    if robot is not None and robot.accel_mm_s2 > safety.max_accel_mm_s2:
        raise err(src, "robot.accel_mm_s2", f"{robot.accel_mm_s2} mm/s² exceeds "
                  f"safety.max_accel_mm_s2 {safety.max_accel_mm_s2}")


def warn_without_tool_points(robot: RobotConfig | None, safety: SafetyConfig,
                             src: str) -> None:
    """Log a warning when a robot config's box bounds the flange only (no tool points)."""
    if robot is not None and safety.tool_points_mm is None:
        log.warning("%s: key 'safety.tool_points_mm' is not set: the workspace box bounds the "
                    "robot FLANGE only, not the coil hanging below it. List points of the coil "
                    "(flange frame, mm) so the box bounds them too.", src)
