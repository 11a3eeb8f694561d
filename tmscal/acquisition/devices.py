"""Drivers from a rig config, through the one driver registry (``tmscal.registry``): the
spec of the configured driver names its class and default port, and the driver's settings
(``cfg.<kind>.settings``) give its own constructor arguments; nothing here names a brand.

Poses and speeds pass through unchanged: mm, mm/s, base_from_flange. Every robot built here
carries the config's safety envelope (caps, workspace box, tool points) and the config's
speed and acceleration; ``robot.options`` / ``tracker.options`` / ``ft.options`` can never
override an argument that has its own key or carries a limit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import RigConfig, construct, reserved_options
from ..drivers.base import ConfigError, Envelope, ForceTorque, Robot, SafetyError, Tracker
from ..registry import get_spec

__all__ = ["envelope_for", "make_robot", "make_tracker", "make_ft"]


def envelope_for(cfg: RigConfig, p0: np.ndarray | None) -> Envelope:
    """The safety envelope of the config around P0 (base_from_flange, mm); with ``p0`` None
    the offset and rotation limits are not checked (P0 unknown), everything else is."""
    s = cfg.safety
    return Envelope(center=p0, max_offset_mm=s.max_offset_mm,
                    max_rotation_deg=s.max_rotation_deg, box_min_mm=s.workspace_min_mm,
                    box_max_mm=s.workspace_max_mm, max_speed_mm_s=s.max_speed_mm_s,
                    max_accel_mm_s2=s.max_accel_mm_s2, tool_points_mm=s.tool_points_mm)


def _looser(env: Envelope, cfg_env: Envelope) -> str | None:
    """The first limit of the config's envelope that ``env`` does not enforce at least as
    strictly, or None."""
    for k in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s", "max_accel_mm_s2"):
        mine, theirs = getattr(env, k), getattr(cfg_env, k)
        if theirs is not None and (mine is None or not mine <= theirs):
            if k in ("max_offset_mm", "max_rotation_deg") and env.center is None:
                continue  # not checked until P0 is known, in either envelope
            return k
    if cfg_env.box_min_mm is not None:
        if env.box_min_mm is None or env.box_max_mm is None or cfg_env.box_max_mm is None:
            return "workspace box"
        if not (np.all(np.asarray(env.box_min_mm) >= cfg_env.box_min_mm)
                and np.all(np.asarray(env.box_max_mm) <= cfg_env.box_max_mm)):
            return "workspace box"
    if cfg_env.tool_points_mm is not None and (
            env.tool_points_mm is None
            or not np.array_equal(env.tool_points_mm, cfg_env.tool_points_mm)):
        return "tool_points_mm"
    return None


def make_robot(cfg: RigConfig, envelope: Envelope | None = None,
               host: str | None = None, port: int | None = None) -> Robot:
    """The configured robot driver (not yet opened). ``host``/``port`` override the config.

    ``envelope`` defaults to the config's (``envelope_for(cfg, None)``: caps and box, no P0
    yet); one that is given must be at least as strict as the config's, else SafetyError.
    ``robot.options`` naming envelope, speed_mm_s, accel_mm_s2, host or port raise
    ConfigError (the config parser refuses them first)."""
    if cfg.robot is None:
        raise ConfigError(f"{cfg.path}: key 'robot': this command needs a robot section")
    r = cfg.robot
    kw = _options(cfg, "robot", r.options, r.settings)
    cfg_env = envelope_for(cfg, None)
    if envelope is None:
        envelope = cfg_env
    else:
        weak = _looser(envelope, cfg_env)
        if weak is not None:
            raise SafetyError(f"{cfg.path}: the robot's envelope is looser than the config's "
                              f"safety section ({weak}); nothing was opened")
    spec = get_spec(r.driver, "robot")
    if r.settings is not None:  # the driver's own keys (none for the built-in robots)
        kw.update(r.settings.kwargs())
    # the safety and motion arguments come last: nothing in options can override them
    kw.update(host=host or r.host, envelope=envelope, speed_mm_s=r.speed_mm_s,
              accel_mm_s2=r.accel_mm_s2)
    if spec.default_port is not None:  # a driver without one takes no port (UR: fixed ports)
        kw["port"] = port or r.port or spec.default_port
    robot = construct(spec.load(), f"{cfg.path}: key 'robot.options'", **kw)
    if (robot.envelope is not envelope or robot.speed_mm_s != r.speed_mm_s
            or robot.accel_mm_s2 != r.accel_mm_s2):
        raise SafetyError(f"{cfg.path}: driver {r.driver!r} did not take the config's envelope, "
                          "speed and acceleration; nothing was opened")
    return robot


def make_tracker(cfg: RigConfig, port: str | None = None) -> Tracker:
    """The configured tracker driver (not yet opened). ``port`` overrides where the tracker
    is (the driver's address, e.g. an NDI tracker's device path or socket://host:port),
    checked as the config's is (``settings.with_address``)."""
    if cfg.tracker is None:
        raise ConfigError(f"{cfg.path}: key 'tracker': this command needs a tracker section")
    t = cfg.tracker
    settings = t.settings.with_address(port) if port else t.settings
    kw = _options(cfg, "tracker", t.options, settings)
    kw.update(settings.kwargs())
    kw["frame_rate_hz"] = t.frame_rate_hz
    spec = get_spec(t.driver, "tracker")
    return construct(spec.load(), f"{cfg.path}: key 'tracker.options'", **kw)


def make_ft(cfg: RigConfig, host: str | None = None, port: int | None = None) -> ForceTorque:
    """The configured force-torque sensor driver (not yet opened). ``host``/``port`` override
    the config's. ``ft.host`` "robot" (or none given) is the robot's address, for a driver
    that reads a sensor in the arm (``on_robot``, e.g. ``ur_wrench``); any other driver needs
    its own address. The driver's settings give its own arguments (the Net F/T: the
    calibration's counts per unit, which the config parser requires)."""
    if cfg.ft is None:
        raise ConfigError(f"{cfg.path}: key 'ft': this command needs a force-torque sensor "
                          "section (ft: {driver, host, ...}; docs/devices.md)")
    f = cfg.ft
    spec = get_spec(f.driver, "ft")
    cls = spec.load()
    kw = _options(cfg, "ft", f.options, f.settings)
    where = host or f.host
    if where in (None, "robot"):
        if not getattr(cls, "on_robot", False):
            raise ConfigError(f"{cfg.path}: key 'ft.host': driver {f.driver!r} needs the "
                              "sensor's own address ('robot' is for a sensor in the arm)")
        if cfg.robot is None:
            raise ConfigError(f"{cfg.path}: key 'ft.host': {where or 'no host'!s} means the "
                              "robot's address, but the config has no robot section")
        where = cfg.robot.host
    if f.settings is not None:
        kw.update(f.settings.kwargs())
    kw["host"] = where
    if spec.default_port is not None:
        kw["port"] = port or f.port or spec.default_port
    return construct(cls, f"{cfg.path}: key 'ft.options'", **kw)


def _options(cfg: RigConfig, kind: str, options: dict[str, Any],
             settings: Any) -> dict[str, Any]:
    """A copy of ``<kind>.options``, refusing (again: the parser does first) a name that is
    a generic argument or one of the driver's own keys."""
    for k in options:
        if k in reserved_options(kind, settings):
            raise ConfigError(f"{cfg.path}: key '{kind}.options.{k}': '{k}' cannot be set "
                              f"through options; set {kind}.{k} instead")
    return dict(options)
