"""The UR drivers' config: ``robot: {driver: ur, ...}`` and the e-Series' built-in
force-torque sensor ``ft: {driver: ur_wrench, ...}``. Neither owns a key beside the generic
ones (ur_rtde's ports are fixed, so ``port`` is unused); their options with types and ranges
(docs/configs.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from ...config.settings import FTSettings, Option, RobotSettings

__all__ = ["URSettings", "URWrenchSettings"]


@dataclass(frozen=True)
class URSettings(RobotSettings):
    """``URRobot``'s options: ``upload_script`` (true: ur_rtde uploads its control script;
    false: the External Control URCap runs it), ``frequency_hz`` (RTDE rate, Hz; null: the
    controller's), ``timeout_s`` (the longest move or wait, s) and ``ur_cap_port`` (the
    URCap's script port)."""

    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "upload_script": Option(
            bool, default=True,
            help="true: ur_rtde uploads its control script; false: a program on the "
                 "controller already runs it (the External Control URCap, `docs/devices.md`)"),
        "frequency_hz": Option(float, above=0, hi=500, null=True, default=None, unit="Hz",
                               default_text="null: the controller's", help="RTDE data rate"),
        "timeout_s": Option(float, above=0, hi=3600, default=30.0, unit="s",
                            help="the longest a move or a wait for controller data may take"),
        "ur_cap_port": Option(
            int, lo=1, hi=65535, default=50002,
            help="the port of ur_rtde's script sender for the URCap (with "
                 "`upload_script: false`)"),
    }


@dataclass(frozen=True)
class URWrenchSettings(FTSettings):
    """``URWrench``'s options: ``kind`` ("raw": ft_raw_wrench in the flange frame; "tcp":
    actual_TCP_force in the base frame), ``frequency_hz`` (RTDE rate, Hz; null: the
    controller's) and ``timeout_s`` (the longest wait for a new reading, s)."""

    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "kind": Option(str, choices=("raw", "tcp"), default="raw",
                       help="`raw`: ft_raw_wrench, flange frame; `tcp`: actual_TCP_force, "
                            "base frame"),
        "frequency_hz": Option(float, above=0, hi=500, null=True, default=None, unit="Hz",
                               default_text="null: the controller's", help="RTDE data rate"),
        "timeout_s": Option(float, above=0, hi=3600, default=2.0, unit="s",
                            help="the longest wait for a new reading"),
    }
