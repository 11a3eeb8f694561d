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
        "max_linear_speed_mm_s": Option(
            float, above=0, hi=100_000, default=1000.0, unit="mm/s",
            help="the arm's linear speed at SPEED 100 %, from its data sheet; converts mm/s "
                 "into the controller's percentage. A value that is too low makes the arm "
                 "faster than configured (`docs/safety.md`)"),
        "max_linear_accel_mm_s2": Option(
            float, above=0, hi=1_000_000, default=20000.0, unit="mm/s²",
            help="the arm's linear acceleration at ACCEL 100 %, likewise"),
        "ext_speed_percent": Option(float, lo=0.01, hi=100, default=100.0, unit="%",
                                    help="the ExtSpeed sent at open"),
        "provider": Option(str, default="CaoProv.DENSO.VRC",
                           help="the CAO provider (RC9: `CaoProv.DENSO.VRC9`)"),
        "machine": Option(str, default="localhost", help="the provider's machine argument"),
        "robot_name": Option(str, default="Arm", help="the robot object"),
        "timeout_s": Option(float, above=0, hi=3600, default=30.0, unit="s",
                            help="the longest wait for any reply, a move included"),
        "watchdog_ms": Option(int, lo=0, hi=3_600_000, null=True, default=400, unit="ms",
                              help="the b-CAP watchdog of Service_Start; null turns it off"),
        "fig": Option(int, lo=-1, default=-1,
                      help="the figure code sent with every pose (-1: the controller "
                           "chooses)"),
        "manual_reset": Option(bool, default=False,
                               help="also send ManualReset after ClearError at open (a "
                                    "COBOTTA's safety-state reset)"),
        "halt_timeout_s": Option(
            float, above=0, hi=3600, default=5.0, unit="s",
            help="the bound on each wait of the halt connection (`docs/devices.md`, \"Halt "
                 "over a second connection\")"),
    }
