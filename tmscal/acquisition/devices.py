"""Drivers from a rig config, through the one driver registry (``tmscal.drivers.registry``):
the spec of the configured driver names its class and default port; nothing here names a brand.

Poses and speeds pass through unchanged: mm, mm/s, base_from_flange. Every robot built here
carries the config's safety envelope (caps, workspace box, tool points) and the config's
speed and acceleration; ``robot.options`` / ``tracker.options`` can never override an
argument that has its own key or carries a limit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import (
    ROBOT_RESERVED_OPTIONS,
    TRACKER_RESERVED_OPTIONS,
    RigConfig,
    construct,
    tracker_port_problem,
)
from ..config_checks import FT_RESERVED_OPTIONS
from ..config_paths import check_rom_exists
from ..drivers.base import ConfigError, Envelope, ForceTorque, Robot, SafetyError, Tracker
from ..drivers.registry import get_spec

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
    for k in r.options:
        if k in ROBOT_RESERVED_OPTIONS:
            raise ConfigError(f"{cfg.path}: key 'robot.options.{k}': '{k}' cannot be set "
                              "through options")
    cfg_env = envelope_for(cfg, None)
    if envelope is None:
        envelope = cfg_env
    else:
        weak = _looser(envelope, cfg_env)
        if weak is not None:
            raise SafetyError(f"{cfg.path}: the robot's envelope is looser than the config's "
                              f"safety section ({weak}); nothing was opened")
    spec = get_spec(r.driver, "robot")
    _check_spec_options(cfg, "robot", r.options, spec.options)
    kw: dict[str, Any] = dict(r.options)
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
    """The configured tracker driver (not yet opened). ``port`` overrides the config's; it
    must be a device path or socket://host:port like ``tracker.port``."""
    if cfg.tracker is None:
        raise ConfigError(f"{cfg.path}: key 'tracker': this command needs a tracker section")
    t = cfg.tracker
    p = port or t.port
    if not p:
        raise ConfigError(f"{cfg.path}: key 'tracker.port': no port given (a device such as "
                          "/dev/ttyUSB0, a pty path, or socket://host:port)")
    problem = tracker_port_problem(p)
    if problem:
        raise ConfigError(f"{cfg.path}: key 'tracker.port': {p!r}: {problem}")
    for name, rom in t.tools.items():  # checked here too: a config may be loaded without it
        check_rom_exists(str(cfg.path), name, rom)
    for k in t.options:
        if k in TRACKER_RESERVED_OPTIONS:
            raise ConfigError(f"{cfg.path}: key 'tracker.options.{k}': '{k}' cannot be set "
                              f"through options; set tracker.{k} instead")
    spec = get_spec(t.driver, "tracker")
    _check_spec_options(cfg, "tracker", t.options, spec.options)
    kw: dict[str, Any] = dict(t.options)
    kw.update(port=p, tools=t.tools, baud=t.baud, frame_rate_hz=t.frame_rate_hz, reply=t.reply)
    if t.log_wire is not None:  # only drivers that record the wire take it
        kw["log_wire"] = t.log_wire
    return construct(spec.load(), f"{cfg.path}: key 'tracker.options'", **kw)


def make_ft(cfg: RigConfig, host: str | None = None, port: int | None = None) -> ForceTorque:
    """The configured force-torque sensor driver (not yet opened). ``host``/``port`` override
    the config's. ``ft.host`` "robot" (or none given) is the robot's address, for a driver
    that reads a sensor in the arm (``on_robot``, e.g. ``ur_wrench``); any other driver needs
    its own address. The calibration's counts per unit go to a driver that takes them; one
    that requires them (the Net F/T) without them in the config is a ConfigError naming the
    key, before anything opens."""
    import inspect

    if cfg.ft is None:
        raise ConfigError(f"{cfg.path}: key 'ft': this command needs a force-torque sensor "
                          "section (ft: {driver, host, ...}; docs/devices.md)")
    f = cfg.ft
    spec = get_spec(f.driver, "ft")
    cls = spec.load()
    for k in f.options:
        if k in FT_RESERVED_OPTIONS:
            raise ConfigError(f"{cfg.path}: key 'ft.options.{k}': '{k}' cannot be set through "
                              f"options; set ft.{k} instead")
    _check_spec_options(cfg, "ft", f.options, spec.options)
    where = host or f.host
    if where in (None, "robot"):
        if not getattr(cls, "on_robot", False):
            raise ConfigError(f"{cfg.path}: key 'ft.host': driver {f.driver!r} needs the "
                              "sensor's own address ('robot' is for a sensor in the arm)")
        if cfg.robot is None:
            raise ConfigError(f"{cfg.path}: key 'ft.host': {where or 'no host'!s} means the "
                              "robot's address, but the config has no robot section")
        where = cfg.robot.host
    kw: dict[str, Any] = dict(f.options)
    kw["host"] = where
    params = inspect.signature(cls).parameters
    for key in ("counts_per_force", "counts_per_torque"):
        value = getattr(f, key)
        if value is not None:
            kw[key] = value
        elif key in params and params[key].default is inspect.Parameter.empty:
            raise ConfigError(f"{cfg.path}: key 'ft.{key}': driver {f.driver!r} needs the "
                              "sensor calibration's counts per unit (its web page or "
                              "netftapi2.xml: cfgcpf per N, cfgcpt per N·m); there is no "
                              "default")
    if spec.default_port is not None:
        kw["port"] = port or f.port or spec.default_port
    return construct(cls, f"{cfg.path}: key 'ft.options'", **kw)


def _check_spec_options(cfg: RigConfig, kind: str, options: dict[str, Any],
                        accepted: tuple[str, ...] | None) -> None:
    """Refuse an option the driver's spec does not list (None: the constructor decides)."""
    if accepted is None:
        return
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise ConfigError(f"{cfg.path}: key '{kind}.options.{unknown[0]}': unknown option; "
                          f"expected one of: {', '.join(sorted(accepted))}")
