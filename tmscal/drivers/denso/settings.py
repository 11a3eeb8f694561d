"""The DENSO driver's config (``robot: {driver: denso, ...}``): no keys beside the generic
ones (the controller is ``robot.host``/``robot.port``, b-CAP 5007 by default); the
``robot.options`` of ``DensoRobot`` with their types and ranges (docs/configs.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from ...config.settings import Option, RobotSettings

__all__ = ["DensoSettings"]


@dataclass(frozen=True)
class DensoSettings(RobotSettings):
    """``DensoRobot``'s options: the arm's linear speed (mm/s) and acceleration (mm/s²) at
    100 % (``max_linear_*``, which convert mm/s into SPEED and ACCEL percentages), the
    ExtSpeed percentage, the CAO provider, machine and robot object, the reply timeout (s),
    the b-CAP watchdog (ms; null: off), the figure code (−1: the controller chooses),
    ``manual_reset`` (COBOTTA: ManualReset after ClearError at open) and ``halt_timeout_s``
    (each wait of the halt connection, s)."""

    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "max_linear_speed_mm_s": Option(float, above=0, hi=100_000),
        "max_linear_accel_mm_s2": Option(float, above=0, hi=1_000_000),
        "ext_speed_percent": Option(float, lo=0.01, hi=100),
        "provider": Option(str),
        "machine": Option(str),
        "robot_name": Option(str),
        "timeout_s": Option(float, above=0, hi=3600),
        "watchdog_ms": Option(int, lo=0, hi=3_600_000, null=True),
        "fig": Option(int, lo=-1),
        "manual_reset": Option(bool),
        "halt_timeout_s": Option(float, above=0, hi=3600),
    }
