"""The Franka driver's config (``robot: {driver: franka, ...}``): no keys beside the generic
ones (libfranka's ports are fixed, so ``port`` is unused); ``FrankaRobot``'s options with
their types and ranges (docs/configs.md, docs/devices.md "Franka")."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from ...config.settings import Option, RobotSettings

__all__ = ["FrankaSettings"]


@dataclass(frozen=True)
class FrankaSettings(RobotSettings):
    """``FrankaRobot``'s options: ``auto_recover`` (true: recover from a reflex, logged;
    false: a reflex is a RobotFault), ``realtime`` (true: franky's RealtimeConfig.Enforce,
    which needs a real-time kernel) and ``timeout_s`` (the longest one move may take, s)."""

    OPTIONS: ClassVar[Mapping[str, Option]] = {
        "auto_recover": Option(
            bool, default=False,
            help="true: recover from a reflex with `recover_from_errors()` (logged); false: "
                 "a reflex is a RobotFault naming its errors"),
        "realtime": Option(
            bool, default=False,
            help="true: franky's `RealtimeConfig.Enforce`, which needs a real-time kernel "
                 "and real-time priority"),
        "timeout_s": Option(float, above=0, hi=3600, default=60.0, unit="s",
                            help="the longest one move may take"),
    }
