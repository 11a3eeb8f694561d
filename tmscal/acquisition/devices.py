"""Drivers from a rig config, through the one driver registry (drivers/base.DRIVERS).

Poses and speeds pass through unchanged: mm, mm/s, base_from_flange.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import RigConfig, construct
from ..drivers.base import ConfigError, Envelope, Robot, Tracker, driver_class

__all__ = ["envelope_for", "make_robot", "make_tracker"]


def envelope_for(cfg: RigConfig, p0: np.ndarray | None) -> Envelope:
    """The safety envelope of the config around P0 (base_from_flange, mm)."""
    s = cfg.safety
    return Envelope(center=p0, max_offset_mm=s.max_offset_mm,
                    max_rotation_deg=s.max_rotation_deg, box_min_mm=s.workspace_min_mm,
                    box_max_mm=s.workspace_max_mm, max_speed_mm_s=s.max_speed_mm_s,
                    max_accel_mm_s2=s.max_accel_mm_s2)


def make_robot(cfg: RigConfig, envelope: Envelope | None = None,
               host: str | None = None, port: int | None = None) -> Robot:
    """The configured robot driver (not yet opened). ``host``/``port`` override the config."""
    if cfg.robot is None:
        raise ConfigError(f"{cfg.path}: key 'robot': this command needs a robot section")
    r = cfg.robot
    cls = driver_class(r.driver)
    kw: dict[str, Any] = dict(host=host or r.host, envelope=envelope,
                              speed_mm_s=r.speed_mm_s, accel_mm_s2=r.accel_mm_s2)
    if r.driver == "denso":
        kw["port"] = port or r.port or 5007
    kw.update(r.options)
    return construct(cls, f"{cfg.path}: key 'robot.options'", **kw)


def make_tracker(cfg: RigConfig, port: str | None = None) -> Tracker:
    """The configured tracker driver (not yet opened). ``port`` overrides the config's."""
    if cfg.tracker is None:
        raise ConfigError(f"{cfg.path}: key 'tracker': this command needs a tracker section")
    t = cfg.tracker
    p = port or t.port
    if not p:
        raise ConfigError(f"{cfg.path}: key 'tracker.port': no port given (a device such as "
                          "/dev/ttyUSB0, a pty path, or socket://host:port)")
    cls = driver_class(t.driver)
    kw: dict[str, Any] = dict(port=p, tools=t.tools, baud=t.baud,
                              frame_rate_hz=t.frame_rate_hz, reply=t.reply)
    kw.update(t.options)
    return construct(cls, f"{cfg.path}: key 'tracker.options'", **kw)
