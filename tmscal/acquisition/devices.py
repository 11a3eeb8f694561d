"""Drivers from a rig config, through the one driver registry (``tmscal.registry``): the
spec of the configured driver names its class and default port, and the driver's settings
(``cfg.<kind>.settings``) give its own constructor arguments; nothing here names a brand.
``Devices`` holds the devices of a run (the robot and a tracker or a force-torque sensor; a
tracker run whose config also has an ``ft`` section opens that sensor too, and records each
pose's wrench beside the tracker samples) and opens them again after a fault.

Poses and speeds pass through unchanged: mm, mm/s, base_from_flange. Every robot built here
carries the config's safety envelope (caps, workspace box, tool points) and the config's
speed and acceleration; ``robot.options`` / ``tracker.options`` / ``ft.options`` can never
override an argument that has its own key or carries a limit.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import RigConfig, construct, reserved_options
from ..drivers.base import ConfigError, Envelope, ForceTorque, Robot, SafetyError, Tracker
from ..errors import CalibrationError
from ..registry import get_spec

__all__ = ["envelope_for", "make_robot", "make_tracker", "make_ft", "Devices", "Endpoints",
           "arm_definition",
           "SENSORS"]

log = logging.getLogger(__name__)

#: the device a run uses beside the robot: an optical tracker or a force-torque sensor
SENSORS = ("tracker", "ft")


def envelope_for(cfg: RigConfig, p0: np.ndarray | None) -> Envelope:
    """The safety envelope of the config around P0 (base_from_flange, mm); with ``p0`` None
    the offset and rotation limits are not checked (P0 unknown), everything else is."""
    s = cfg.safety
    return Envelope(center=p0, max_offset_mm=s.max_offset_mm,
                    max_rotation_deg=s.max_rotation_deg, box_min_mm=s.workspace_min_mm,
                    box_max_mm=s.workspace_max_mm, max_speed_mm_s=s.max_speed_mm_s,
                    max_accel_mm_s2=s.max_accel_mm_s2,
                    tool_points_mm=None if s.tool_points_mm is None
                    else np.asarray(s.tool_points_mm, dtype=np.float64))


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
@dataclass(frozen=True)
class Endpoints:
    """Device addresses given on the command line, over the config's: the tracker's port
    (a device path or socket://host:port), the robot's host and port, the force-torque
    sensor's host and port. None keeps the config's."""

    tracker_port: str | None = None
    robot_host: str | None = None
    robot_port: int | None = None
    ft_host: str | None = None
    ft_port: int | None = None

    @property
    def ft_address(self) -> str | None:
        """``ft_host`` as HOST[:PORT] (as ``--ft-host`` takes it), or None."""
        if self.ft_host is None:
            return None
        return self.ft_host + (f":{self.ft_port}" if self.ft_port else "")


def arm_definition(cfg: RigConfig, identity: dict[str, Any]) -> dict[str, Any]:
    """The definition record (docs/kinematics.md, "Arm files") of the config's ``robot.arm``,
    for the session header's ``devices.robot.arm_definition``. ConfigError naming the key
    when it names no arm, its file is not an arm, or the controller reports another
    registered arm (``identity["arm"]``; a file of as many joints refines the reported
    model)."""
    from ..calib.kinematics.arms import ARMS
    from ..formats.armdef import resolve_arm

    robot = cfg.robot
    assert robot is not None and robot.arm is not None
    where = f"{cfg.path}: key 'robot.arm'"
    try:
        d = resolve_arm(robot.arm, where, robot.urdf_base, robot.urdf_flange)
    except CalibrationError as e:
        raise ConfigError(f"{where}: {e}") from None
    reported = identity.get("arm")
    if isinstance(reported, str) and reported in ARMS:
        if d.kind == "registry" and d.name != reported:
            raise ConfigError(f"{where}: {d.name!r}, but the controller reports a "
                              f"{reported!r} (devices.robot.arm)")
        if d.arm.n_joints != ARMS[reported].arm.n_joints:
            raise ConfigError(f"{where}: {d.describe()} has {d.arm.n_joints} joints; the "
                              f"controller reports a {reported} ({ARMS[reported].arm.n_joints})")
    return d.record()


class Devices:
    """The devices of a run: the robot and the ``sensor`` beside it ("tracker" or "ft", a
    force-torque sensor), built from the config and ``endpoints``; a tracker run whose config
    also has an ``ft`` section opens that force-torque sensor as well (``wrench`` True: each
    pose records its wrench, docs/kinematics.md, "Wrench rows"). ``open(envelope)`` opens
    them, the robot carrying ``envelope``; ``close`` closes them (best effort), stopping the
    robot first when asked; a reconnect is ``close`` then ``open``."""

    def __init__(self, cfg: RigConfig, sensor: str, endpoints: Endpoints | None = None) -> None:
        if sensor not in SENSORS:
            raise ValueError(f"sensor must be one of {SENSORS}, got {sensor!r}")
        self.cfg = cfg
        self.sensor = sensor
        self.endpoints = endpoints or Endpoints()
        self.robot: Robot | None = None
        self.tracker: Tracker | None = None
        self.ft: ForceTorque | None = None
        #: a tracker run that also reads the config's force-torque sensor at every pose
        self.wrench = sensor == "tracker" and cfg.ft is not None

    def open(self, envelope: Envelope | None = None) -> None:
        """Open the robot (with ``envelope``: at least as strict as the config's) and the
        sensor."""
        ep = self.endpoints
        self.robot = make_robot(self.cfg, envelope, ep.robot_host, ep.robot_port)
        self.robot.open()
        if self.sensor == "tracker":
            self.tracker = make_tracker(self.cfg, ep.tracker_port)
            self.tracker.open()
            if not self.wrench:
                return
        ft_host = ep.ft_host
        on_robot = self.cfg.ft is not None and self.cfg.ft.host in (None, "robot")
        if ft_host is None and on_robot and ep.robot_host:
            ft_host = ep.robot_host  # a sensor in the arm follows --robot-host
        self.ft = make_ft(self.cfg, ft_host, ep.ft_port)
        self.ft.open()

    def close(self, stop_robot: bool = False) -> None:
        """Stop the robot (``stop_robot``), close it, close the sensor; a failure is logged
        and the next step still runs."""
        steps: list[tuple[str, Any]] = []
        if self.robot is not None:
            steps += [("stopping the robot", stop_robot and self.robot.stop),
                      ("closing the robot", self.robot.close)]
        sensor = self.tracker if self.sensor == "tracker" else self.ft
        if sensor is not None:
            steps.append((f"closing the {_NAMES[self.sensor]}", sensor.close))
        if self.wrench and self.ft is not None:
            steps.append((f"closing the {_NAMES['ft']}", self.ft.close))
        for what, step in steps:
            try:
                if step:
                    step()
            except Exception:  # best effort on the way out
                log.warning("%s failed", what, exc_info=True)

    @property
    def bodies(self) -> list[str]:
        """The session's bodies: the tracker's tool names, or ["ft"]."""
        if self.sensor == "tracker":
            assert self.tracker is not None
            return list(self.tracker.tools)
        return ["ft"]

    def identities(self) -> dict[str, Any]:
        """{"robot": identity, "tracker" or "ft": identity} for the session header (a
        tracker run with a force-torque sensor: "ft" as well)."""
        assert self.robot is not None
        sensor = self.tracker if self.sensor == "tracker" else self.ft
        assert sensor is not None
        out = {"robot": self.robot.identity(), self.sensor: sensor.identity()}
        if self.wrench and self.ft is not None:
            out["ft"] = self.ft.identity()
        if getattr(self.cfg.robot, "arm", None) is not None:
            out["robot"] = {**(out["robot"] or {}),
                            "arm_definition": arm_definition(self.cfg, out["robot"] or {})}
        return out

    def joints(self) -> np.ndarray:
        """The robot's joint angles (rad); ConfigError naming ``robot.driver`` when its
        driver does not report them."""
        assert self.robot is not None
        try:
            return np.asarray(self.robot.joint_positions(), dtype=float)
        except NotImplementedError as e:
            raise ConfigError(f"{self.cfg.path}: key 'robot.driver': {e}; self-calibration "
                              "needs the joint angles") from None


_NAMES = {"tracker": "tracker", "ft": "force-torque sensor"}
