"""Rig configs: YAML → validated dataclasses. Every error names the file, the key and what
was expected.

A config describes one rig (see ``configs/*.yaml`` for commented examples)::

    robot:    {driver: ur|denso, host, port, speed_mm_s, accel_mm_s2, options: {...}}
    tracker:  {driver: ndi, port, baud, frame_rate_hz, reply: bx|tx,
               tools: {marker: file.rom, probe: file.rom}}
    plan:     {kind: eq14|sphere, poses, radius_mm, rotation_deg, seed, start}
    sampling: {samples, settle_s, min_share, max_frames_factor, robot_reads}
    safety:   {max_offset_mm, max_rotation_deg, workspace_min_mm, workspace_max_mm,
               max_speed_mm_s, max_accel_mm_s2}
    run:      {retries, reconnect_wait_s}
    mock:     {clock: fast|real, seed, truth: tms|random|{X, Y, Z}, noise: {...},
               tracker: {model, faults: {...}, ...}, robot: {faults: {...}, ...}}

Lengths are mm, angles degrees (``_deg``), speeds mm/s, times seconds. Relative file paths
(ROM files) are resolved against the config file's folder.

Safety rules (docs/safety.md explains them):

* A config with a ``robot`` section must have a ``safety`` section that sets every one of
  max_offset_mm, max_rotation_deg, workspace_min_mm, workspace_max_mm, max_speed_mm_s and
  max_accel_mm_s2; there are no defaults for a robot. The workspace box (robot base frame) is
  required because it is the one limit that does not move with P0.
* ``safety.tool_points_mm`` lists [x, y, z] points in the FLANGE frame (mm: the coil centre,
  points on the coil's rim) that must stay inside the box too. Without it the box bounds the
  flange only, and loading the config logs a warning.
* Every safety number is a finite real (not a bool, string, NaN or ±inf), positive where it is
  a limit, below a plausibility bound (10 m, 180°, 5 m/s, 50 m/s²), and the box's min is below
  its max on every axis. -0.0 is read as 0.
* ``robot.options`` and ``tracker.options`` cannot name an argument that has its own key or
  carries a limit (envelope, speed_mm_s, accel_mm_s2, host, port; port, tools, baud,
  frame_rate_hz, reply).
* ``tracker.port`` is a device path (/dev/ttyUSB0, /dev/pts/3, COM3) or socket://host:port;
  no other pyserial URL scheme (spy://, loop://, rfc2217:// …) is accepted.
* Every key of every mapping is a string; seeds are ≥ 0; the document is at most 1 MB, 32
  levels deep and 100,000 values (YAML aliases counted where used), holds no recursive
  anchors, and is plain JSON data (the resolved config goes into the session header).

Every violation is a ConfigError naming the file, the key and (for ``load_config``) the line,
raised before any device is opened.
"""

from __future__ import annotations

import inspect
import json
import logging
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import ConfigError

__all__ = ["RigConfig", "RobotConfig", "TrackerConfig", "PlanConfig", "SamplingConfig",
           "SafetyConfig", "RunConfig", "MockConfig", "load_config", "parse_config",
           "pose_from_config", "construct", "tracker_port_problem", "ROBOT_RESERVED_OPTIONS",
           "TRACKER_RESERVED_OPTIONS", "SAFETY_KEYS"]

log = logging.getLogger(__name__)

#: robot.options keys that would override a safety or motion argument, or one with its own key
ROBOT_RESERVED_OPTIONS = ("envelope", "speed_mm_s", "accel_mm_s2", "host", "port")
#: tracker.options keys that have their own key in the tracker section
TRACKER_RESERVED_OPTIONS = ("port", "tools", "baud", "frame_rate_hz", "reply")
#: safety keys a config that drives a robot must set (no defaults for a robot)
SAFETY_KEYS = ("max_offset_mm", "max_rotation_deg", "workspace_min_mm", "workspace_max_mm",
               "max_speed_mm_s", "max_accel_mm_s2")
#: plausibility bounds of the safety limits (a larger value is a typo or a unit mistake)
_SAFETY_BOUNDS = {"max_offset_mm": 10_000.0, "max_rotation_deg": 180.0,
                  "max_speed_mm_s": 5_000.0, "max_accel_mm_s2": 50_000.0}
_COORD_BOUND_MM = 10_000.0   # |workspace coordinate| (mm, base frame)
_TOOL_BOUND_MM = 2_000.0     # |tool point coordinate| (mm, flange frame)
_MAX_TOOL_POINTS = 64
_MAX_BYTES = 1_000_000
_MAX_DEPTH = 32
_MAX_VALUES = 100_000
_INT_BOUND = 2**63


@dataclass
class RobotConfig:
    """Robot driver and motion settings. Speeds mm/s, accelerations mm/s²."""

    driver: str
    host: str = "127.0.0.1"
    port: int | None = None
    speed_mm_s: float = 100.0
    accel_mm_s2: float = 500.0
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class TrackerConfig:
    """Tracker driver, port (device path, pty, or socket://host:port) and tools
    (our name → ROM file path, absolute, or None for a tool already loaded)."""

    driver: str = "ndi"
    port: str = ""
    baud: int = 115200
    frame_rate_hz: float = 60.0
    reply: str = "bx"
    tools: dict[str, str | None] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class PlanConfig:
    """Pose plan around P0: Eq. 14 (±radius_mm per axis, ±rotation_deg per axis) or a sphere
    of radius_mm. ``start`` is "current" (the flange pose when the run starts) or a 4×4 mm."""

    kind: str = "eq14"
    poses: int = 500
    radius_mm: float = 100.0
    rotation_deg: float = 10.0
    seed: int = 1
    start: Any = "current"


@dataclass
class SamplingConfig:
    """Samples per pose (distinct tracker frames), settle time after each move (s), the
    share of frames with every body usable below which a pose is retried then skipped, and
    how many of those frames also read the robot's flange pose (spread evenly)."""

    samples: int = 100
    settle_s: float = 1.0
    min_share: float = 0.8
    max_frames_factor: float = 3.0
    robot_reads: int = 10


@dataclass
class SafetyConfig:
    """The safety envelope: offset from P0 (mm), rotation from P0 (deg), workspace box in
    the robot base frame (mm), speed (mm/s) and acceleration (mm/s²) caps, and tool points
    ([x, y, z] mm in the FLANGE frame) that must stay inside the box as well as the flange.
    The defaults apply only to configs without a robot; a robot config sets every limit."""

    max_offset_mm: float = 200.0
    max_rotation_deg: float = 20.0
    workspace_min_mm: tuple[float, float, float] | None = None
    workspace_max_mm: tuple[float, float, float] | None = None
    max_speed_mm_s: float = 250.0
    max_accel_mm_s2: float = 1500.0
    tool_points_mm: list[tuple[float, float, float]] | None = None


@dataclass
class RunConfig:
    """Device-fault handling: reconnect attempts per fault, wait between them (s)."""

    retries: int = 3
    reconnect_wait_s: float = 1.0


@dataclass
class MockConfig:
    """The mock rig: clock ("fast" or "real"), RNG seed, truth ("tms" built-in rig,
    "random" seed-000 truth, or explicit {X, Y, Z} 4×4 mm), noise (``sim.Noise`` fields),
    per-device options and faults."""

    clock: str = "fast"
    seed: int = 0
    truth: Any = "tms"
    noise: dict[str, float] = field(default_factory=dict)
    tracker: dict[str, Any] = field(default_factory=dict)
    robot: dict[str, Any] = field(default_factory=dict)


@dataclass
class RigConfig:
    """A whole rig config, as loaded from ``path``."""

    path: Path | None
    robot: RobotConfig | None
    tracker: TrackerConfig | None
    plan: PlanConfig
    sampling: SamplingConfig
    safety: SafetyConfig
    run: RunConfig
    mock: MockConfig | None
    raw: dict[str, Any]

    @property
    def bodies(self) -> list[str]:
        """The tracker tool names of the config (e.g. ["marker", "probe"])."""
        return list(self.tracker.tools) if self.tracker else []


_SECTIONS = {"robot", "tracker", "plan", "sampling", "safety", "run", "mock", "name",
             "description"}


def _err(src: str, key: str, msg: str) -> ConfigError:
    if not key.isprintable():  # one line, whatever the key holds
        key = key.encode("unicode_escape").decode("ascii")
    return ConfigError(f"{src}: key '{key}': {' '.join(msg.splitlines())}")


def _show(v: Any, limit: int = 60) -> str:
    """A short repr of a config value for messages (never raises, never huge)."""
    try:
        r = repr(v)
    except (ValueError, RecursionError):  # an int beyond the str-digits limit, deep nesting
        r = f"<{type(v).__name__}>"
    return r if len(r) <= limit else r[:limit - 1] + "…"


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _check_tree(data: Any, src: str) -> None:
    """The whole document is plain JSON-like data: string keys, finite floats, int64 ints,
    at most ``_MAX_DEPTH`` deep and ``_MAX_VALUES`` values (aliases counted each time they are
    used), no recursive anchors. Raises ConfigError naming the first offending key."""
    count = 0
    on_path: set[int] = set()

    def walk(v: Any, path: str, depth: int) -> None:
        nonlocal count
        count += 1
        if count > _MAX_VALUES:
            raise _err(src, path or "(top level)", f"the document holds more than "
                       f"{_MAX_VALUES:,} values (YAML aliases expanded); a rig config is far "
                       "smaller")
        if depth > _MAX_DEPTH:
            raise _err(src, path, f"nested more than {_MAX_DEPTH} levels deep")
        if isinstance(v, Mapping | list | tuple):
            if id(v) in on_path:
                raise _err(src, path, "refers to itself (a recursive YAML anchor and alias)")
            on_path.add(id(v))
            if isinstance(v, Mapping):
                for k, x in v.items():
                    if not isinstance(k, str):
                        raise _err(src, _join(path, _show(k)), f"every key must be a string, "
                                   f"got {type(k).__name__} {_show(k)} (quote it)")
                    walk(x, _join(path, k), depth + 1)
            else:
                for i, x in enumerate(v):
                    walk(x, f"{path}[{i}]", depth + 1)
            on_path.discard(id(v))
        elif v is None or isinstance(v, bool | str):
            return
        elif isinstance(v, int):
            if not -_INT_BOUND <= v < _INT_BOUND:
                raise _err(src, path, "integer out of range (|value| ≥ 2**63)")
        elif isinstance(v, float):
            if not math.isfinite(v):
                raise _err(src, path, f"{v!r} is not a finite number")
        else:
            raise _err(src, path, f"unsupported value {_show(v)} of type {type(v).__name__}; "
                       "expected a number, string, list or mapping (quote text)")

    walk(data, "", 0)


def _build(cls: type, data: Any, src: str, section: str) -> Any:
    """Build dataclass ``cls`` from a mapping, checking keys and simple types."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise _err(src, section, f"expected a mapping, got {type(data).__name__}")
    names = {f.name: f for f in fields(cls)}
    for k in data:
        if not isinstance(k, str):
            raise _err(src, f"{section}.{_show(k)}", "every key must be a string (quote it)")
    unknown = sorted(k for k in data if k not in names)
    if unknown:
        raise _err(src, f"{section}.{unknown[0]}",
                   f"unknown key; expected one of: {', '.join(sorted(names))}")
    kwargs: dict[str, Any] = {}
    for k, v in data.items():
        f = names[k]
        kwargs[k] = _coerce(v, f.type, src, f"{section}.{k}")
    try:
        return cls(**kwargs)
    except TypeError as e:
        raise _err(src, section, str(e)) from None


def _number(v: Any, src: str, key: str, what: str = "a number") -> float:
    """A finite real from a config value (bool, str, NaN, ±inf, overflow refused; -0.0 → 0)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise _err(src, key, f"expected {what}, got {_show(v)}")
    try:
        x = float(v)
    except OverflowError:
        raise _err(src, key, f"expected {what}, got a number too large for a float") from None
    if not math.isfinite(x):
        raise _err(src, key, f"expected {what}, got {_show(v)}")
    return x + 0.0  # -0.0 → 0.0


def _coerce(v: Any, typ: Any, src: str, key: str) -> Any:
    t = str(typ)
    if v is None:
        if "None" in t or t in ("Any",):
            return None
        raise _err(src, key, f"must not be empty (expected {t})")
    if t.startswith("int"):
        if isinstance(v, bool) or not isinstance(v, int):
            raise _err(src, key, f"expected an integer, got {_show(v)}")
        if not -_INT_BOUND <= v < _INT_BOUND:
            raise _err(src, key, "integer out of range (|value| ≥ 2**63)")
        return v
    if t.startswith("float"):
        return _number(v, src, key)
    if t.startswith("str"):
        if not isinstance(v, str):
            raise _err(src, key, f"expected a string, got {_show(v)}")
        return v
    if t.startswith("tuple[float, float, float]"):
        return _xyz(v, src, key)
    if t.startswith("list[tuple[float, float, float]]"):
        if not isinstance(v, list | tuple) or not v:
            raise _err(src, key, f"expected a list of [x, y, z] points in mm, got {_show(v)}")
        return [_xyz(p, src, f"{key}[{i}]") for i, p in enumerate(v)]
    if t.startswith("dict"):
        if not isinstance(v, Mapping):
            raise _err(src, key, f"expected a mapping, got {_show(v)}")
        for k in v:
            if not isinstance(k, str):
                raise _err(src, f"{key}.{_show(k)}", "every key must be a string (quote it)")
        return dict(v)
    return v


def _xyz(v: Any, src: str, key: str) -> tuple[float, float, float]:
    msg = f"expected a list of 3 finite numbers [x, y, z] in mm, got {_show(v)}"
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise _err(src, key, msg)
    x, y, z = (_number(c, src, key, "a list of 3 finite numbers [x, y, z] in mm") for c in v)
    return (x, y, z)


def _positive(src: str, key: str, value: float, allow_zero: bool = False,
              at_most: float | None = None) -> None:
    if not (value > 0 or (allow_zero and value == 0)):
        raise _err(src, key, f"must be {'≥' if allow_zero else '>'} 0, got {value}")
    if at_most is not None and not value <= at_most:
        raise _err(src, key, f"{value} is implausibly large (at most {at_most:g}); check the "
                   "units")


def _in_range(src: str, key: str, value: int, lo: int, hi: int) -> None:
    if not lo <= value <= hi:
        raise _err(src, key, f"must be in {lo}…{hi}, got {value}")


def tracker_port_problem(port: str) -> str | None:
    """Why ``port`` is not an acceptable tracker port, or None when it is: a device path
    (``/dev/ttyUSB0``, ``/dev/pts/3``, ``COM3``; no URL scheme) or ``socket://host:port``.
    Every other pyserial URL scheme (spy://, loop://, rfc2217://, hwgrep://, alt:// …) is
    refused: some of them open or write files named in the URL."""
    if not isinstance(port, str) or not port.strip():
        return "expected a device path or socket://host:port"
    if "\0" in port or any(c in port for c in "\r\n"):
        return "contains a control character"
    if "://" not in port:
        return None
    scheme, _, rest = port.partition("://")
    if scheme.lower() != "socket":
        return (f"URL scheme {scheme!r} is not allowed; use a device path (e.g. /dev/ttyUSB0) "
                "or socket://host:port")
    m = re.fullmatch(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):([0-9]{1,5})", rest)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        return "expected socket://host:port (port 1…65535, no path, query or options)"
    return None


def pose_from_config(value: Any, src: str, key: str) -> np.ndarray:
    """A pose from a config value: a 4×4 list (mm) or {xyz_mm: [..], rpy_deg: [..]} with
    R = Rz·Ry·Rx (DENSO-style fixed axes)."""
    from .geometry import check_pose, matrix_from_denso_p
    if isinstance(value, Mapping):
        try:
            if set(value) - {"xyz_mm", "rpy_deg"}:
                raise ValueError
            xyz = [float(x) for x in value["xyz_mm"]]
            rpy = [float(x) for x in value.get("rpy_deg", [0, 0, 0])]
            if len(xyz) != 3 or len(rpy) != 3 or not all(map(math.isfinite, xyz + rpy)):
                raise ValueError
        except (KeyError, TypeError, ValueError, OverflowError):
            raise _err(src, key, "expected {xyz_mm: [x, y, z], rpy_deg: [rx, ry, rz]}") \
                from None
        return matrix_from_denso_p(xyz + rpy)
    try:
        return check_pose(value, key)
    except (ValueError, TypeError, OverflowError) as e:
        raise _err(src, key, f"expected a rigid 4×4 matrix in mm ({e})") from None


def _check_safety(data: Any, src: str, drives_robot: bool) -> SafetyConfig:
    """The safety section: every limit finite, positive, plausible; box ordered; tool points
    finite. A config that drives a robot must set every key of ``SAFETY_KEYS``."""
    raw = data.get("safety")
    if drives_robot:
        if raw is None:
            raise _err(src, "safety", "a config that drives a robot needs a safety section "
                       f"({', '.join(SAFETY_KEYS)})")
        if isinstance(raw, Mapping):
            for k in SAFETY_KEYS:
                if raw.get(k) is None:
                    raise _err(src, f"safety.{k}", "missing: a config that drives a robot must "
                               f"set every safety limit ({', '.join(SAFETY_KEYS)})")
    safety = _build(SafetyConfig, raw, src, "safety")
    for k, bound in _SAFETY_BOUNDS.items():
        _positive(src, f"safety.{k}", getattr(safety, k), at_most=bound)
    lo, hi = safety.workspace_min_mm, safety.workspace_max_mm
    if (lo is None) != (hi is None):
        raise _err(src, "safety.workspace_min_mm", "give both workspace_min_mm and "
                   "workspace_max_mm, or neither")
    if lo is not None and hi is not None:
        for key, xyz in (("safety.workspace_min_mm", lo), ("safety.workspace_max_mm", hi)):
            if not all(abs(c) <= _COORD_BOUND_MM for c in xyz):
                raise _err(src, key, f"{list(xyz)} mm: every coordinate must be within "
                           f"±{_COORD_BOUND_MM:g} mm of the robot base; check the units")
        for axis, a, b in zip("xyz", lo, hi, strict=True):
            if not a < b:
                raise _err(src, "safety.workspace_max_mm", f"{axis} {b} must exceed "
                           f"workspace_min_mm {axis} {a}")
    if safety.tool_points_mm is not None:
        if len(safety.tool_points_mm) > _MAX_TOOL_POINTS:
            raise _err(src, "safety.tool_points_mm", f"at most {_MAX_TOOL_POINTS} points")
        for i, q in enumerate(safety.tool_points_mm):
            if not all(abs(c) <= _TOOL_BOUND_MM for c in q):
                raise _err(src, f"safety.tool_points_mm[{i}]", f"{list(q)} mm: a tool point "
                           f"(flange frame) must be within ±{_TOOL_BOUND_MM:g} mm of the "
                           "flange; check the units")
    return safety


def _check_options(options: Mapping[str, Any], reserved: tuple[str, ...], src: str,
                   section: str) -> None:
    for k in options:
        if k in reserved:
            raise _err(src, f"{section}.options.{k}", f"'{k}' cannot be set through options: "
                       + ("the envelope comes from the safety section only"
                          if k == "envelope" else f"set {section}.{k} instead"))


def parse_config(data: Any, src: str = "<config>", base_dir: Path | None = None) -> RigConfig:
    """Validate a config mapping (as loaded from YAML) into a ``RigConfig``. Raises
    ConfigError naming ``src`` and the key (see the module docstring for the rules)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{src}: expected a YAML mapping at the top level")
    _check_tree(data, src)
    unknown = sorted(k for k in data if k not in _SECTIONS)
    if unknown:
        raise _err(src, unknown[0], f"unknown section; expected: {', '.join(sorted(_SECTIONS))}")
    for k in ("name", "description"):
        if data.get(k) is not None and not isinstance(data[k], str):
            raise _err(src, k, f"expected a string, got {_show(data[k])}")
    robot = None
    if data.get("robot") is not None:
        robot = _build(RobotConfig, data["robot"], src, "robot")
        if robot.driver not in ("ur", "denso"):
            raise _err(src, "robot.driver", f"expected 'ur' or 'denso', got {robot.driver!r}")
        if not robot.host:
            raise _err(src, "robot.host", "must not be empty")
        if robot.port is not None:
            _in_range(src, "robot.port", robot.port, 0, 65535)
        _positive(src, "robot.speed_mm_s", robot.speed_mm_s)
        _positive(src, "robot.accel_mm_s2", robot.accel_mm_s2)
        _check_options(robot.options, ROBOT_RESERVED_OPTIONS, src, "robot")
    tracker = None
    if data.get("tracker") is not None:
        tracker = _build(TrackerConfig, data["tracker"], src, "tracker")
        if tracker.driver != "ndi":
            raise _err(src, "tracker.driver", f"expected 'ndi', got {tracker.driver!r}")
        if tracker.reply not in ("bx", "tx"):
            raise _err(src, "tracker.reply", f"expected 'bx' or 'tx', got {tracker.reply!r}")
        if tracker.port:
            problem = tracker_port_problem(tracker.port)
            if problem:
                raise _err(src, "tracker.port", f"{_show(tracker.port)}: {problem}")
        if not tracker.tools:
            raise _err(src, "tracker.tools", "name at least one tool, e.g. {marker: file.rom}")
        tools: dict[str, str | None] = {}
        for name, rom in tracker.tools.items():
            if rom is None:
                tools[name] = None
                continue
            if not isinstance(rom, str) or not rom or "\0" in rom:
                raise _err(src, f"tracker.tools.{name}", f"expected a ROM file path, got "
                           f"{_show(rom)}")
            p = Path(rom)
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            if not p.is_file():
                raise _err(src, f"tracker.tools.{name}", f"ROM file not found: {p}")
            tools[name] = str(p)
        tracker.tools = tools
        _positive(src, "tracker.frame_rate_hz", tracker.frame_rate_hz, at_most=10_000)
        _positive(src, "tracker.baud", tracker.baud)
        _check_options(tracker.options, TRACKER_RESERVED_OPTIONS, src, "tracker")
    plan = _build(PlanConfig, data.get("plan"), src, "plan")
    if plan.kind not in ("eq14", "sphere"):
        raise _err(src, "plan.kind", f"expected 'eq14' or 'sphere', got {plan.kind!r}")
    _in_range(src, "plan.poses", plan.poses, 1, 100_000)
    _positive(src, "plan.radius_mm", plan.radius_mm, allow_zero=True, at_most=_COORD_BOUND_MM)
    _positive(src, "plan.rotation_deg", plan.rotation_deg, allow_zero=True, at_most=180.0)
    _in_range(src, "plan.seed", plan.seed, 0, _INT_BOUND - 1)
    if isinstance(plan.start, str):
        if plan.start != "current":
            raise _err(src, "plan.start", f"expected 'current' or a pose, got {plan.start!r}")
    else:
        plan.start = pose_from_config(plan.start, src, "plan.start")
        if not np.all(np.abs(plan.start[:3, 3]) <= _COORD_BOUND_MM):
            raise _err(src, "plan.start", f"position must be within ±{_COORD_BOUND_MM:g} mm")
    sampling = _build(SamplingConfig, data.get("sampling"), src, "sampling")
    _in_range(src, "sampling.samples", sampling.samples, 1, 1_000_000)
    _positive(src, "sampling.settle_s", sampling.settle_s, allow_zero=True, at_most=3600.0)
    _in_range(src, "sampling.robot_reads", sampling.robot_reads, 1, 1_000_000)
    if not 0 < sampling.min_share <= 1:
        raise _err(src, "sampling.min_share", f"must be in (0, 1], got {sampling.min_share}")
    _positive(src, "sampling.max_frames_factor", sampling.max_frames_factor, at_most=1000.0)
    safety = _check_safety(data, src, robot is not None)
    run = _build(RunConfig, data.get("run"), src, "run")
    _in_range(src, "run.retries", run.retries, 0, 1000)
    _positive(src, "run.reconnect_wait_s", run.reconnect_wait_s, allow_zero=True,
              at_most=3600.0)
    mock = None
    if data.get("mock") is not None:
        mock = _build(MockConfig, data["mock"], src, "mock")
        if mock.clock not in ("fast", "real"):
            raise _err(src, "mock.clock", f"expected 'fast' or 'real', got {mock.clock!r}")
        _in_range(src, "mock.seed", mock.seed, 0, _INT_BOUND - 1)
        if isinstance(mock.truth, Mapping):
            extra = sorted(set(mock.truth) - {"X", "Y", "Z"})
            if extra:
                raise _err(src, f"mock.truth.{extra[0]}", "expected X, Y and Z only")
            mock.truth = {k: pose_from_config(v, src, f"mock.truth.{k}")
                          for k, v in mock.truth.items()}
            if "X" not in mock.truth or "Z" not in mock.truth:
                raise _err(src, "mock.truth", "explicit truth needs at least X and Z")
        elif mock.truth not in ("tms", "random"):
            raise _err(src, "mock.truth", f"expected 'tms', 'random' or {{X, Y, Z}}, "
                       f"got {_show(mock.truth)}")
        for dev in ("tracker", "robot"):
            faults = getattr(mock, dev).get("faults")
            if faults is not None and not isinstance(faults, Mapping):
                raise _err(src, f"mock.{dev}.faults", f"expected a mapping of fault settings, "
                           f"got {_show(faults)}")
            vol = getattr(mock, dev).get("volume", "default")
            if dev == "tracker" and not (vol is None or vol == "default"
                                         or isinstance(vol, Mapping)):
                raise _err(src, "mock.tracker.volume", f"expected 'default', null or a "
                           f"mapping, got {_show(vol)}")
    if robot is not None and robot.speed_mm_s > safety.max_speed_mm_s:
        raise _err(src, "robot.speed_mm_s", f"{robot.speed_mm_s} mm/s exceeds "
                   f"safety.max_speed_mm_s {safety.max_speed_mm_s}")
    if robot is not None and robot.accel_mm_s2 > safety.max_accel_mm_s2:
        raise _err(src, "robot.accel_mm_s2", f"{robot.accel_mm_s2} mm/s² exceeds "
                   f"safety.max_accel_mm_s2 {safety.max_accel_mm_s2}")
    try:  # the resolved config goes into the session header as JSON
        json.dumps(data, allow_nan=False)
    except (TypeError, ValueError, OverflowError, RecursionError) as e:
        raise ConfigError(f"{src}: the config is not plain data ({e})") from None
    if robot is not None and safety.tool_points_mm is None:
        log.warning("%s: key 'safety.tool_points_mm' is not set: the workspace box bounds the "
                    "robot FLANGE only, not the coil hanging below it. List points of the coil "
                    "(flange frame, mm) so the box bounds them too.", src)
    return RigConfig(path=None, robot=robot, tracker=tracker, plan=plan, sampling=sampling,
                     safety=safety, run=run, mock=mock, raw=dict(data))


def _key_lines(text: str) -> dict[str, int]:
    """Dotted key path → 1-based line of the key, from the YAML node tree (best effort)."""
    out: dict[str, int] = {}
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except (yaml.YAMLError, RecursionError, ValueError):
        return out
    seen: set[int] = set()

    def walk(node: Any, path: str, depth: int) -> None:
        if depth > _MAX_DEPTH or id(node) in seen or len(out) > _MAX_VALUES:
            return
        seen.add(id(node))
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode):
                    key = _join(path, str(k.value))
                    out.setdefault(key, k.start_mark.line + 1)
                    walk(v, key, depth + 1)
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                key = f"{path}[{i}]"
                out.setdefault(key, v.start_mark.line + 1)
                walk(v, key, depth + 1)

    if root is not None:
        walk(root, "", 0)
    return out


def _with_line(e: ConfigError, src: str, text: str) -> ConfigError:
    """``e`` with ", line N" after the file name when its key is found in the YAML."""
    msg = str(e)
    m = re.match(re.escape(src) + r": key '([^']*)'", msg)
    if m is None:
        return e
    lines = _key_lines(text)
    key = m.group(1)
    while key and key not in lines:  # the nearest enclosing key that is in the file
        cut = max(key.rfind("."), key.rfind("["))
        key = key[:cut] if cut > 0 else ""
    if not key:
        return e
    return ConfigError(f"{src}, line {lines[key]}{msg[len(src):]}")


def load_config(path: str | os.PathLike[str]) -> RigConfig:
    """Load and validate a YAML rig config. Raises ConfigError naming the file, the line and
    the key; nothing is opened or written."""
    p = Path(path)
    try:
        if p.stat().st_size > _MAX_BYTES:
            raise ConfigError(f"{p}: the config is larger than {_MAX_BYTES:,} bytes")
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{p}: cannot read config ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a UTF-8 text file") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}{where}: invalid YAML ({getattr(e, 'problem', e)})") from None
    except RecursionError:
        raise ConfigError(f"{p}: invalid YAML (nested too deeply)") from None
    except (ValueError, OverflowError, TypeError) as e:  # e.g. an int beyond the digit limit
        raise ConfigError(f"{p}: invalid YAML ({_show(str(e), 120)})") from None
    try:
        cfg = parse_config(data, str(p), p.parent)
    except ConfigError as e:
        raise _with_line(e, str(p), text) from None
    cfg.path = p
    return cfg


def construct(cls: Any, where: str, *args: Any, **options: Any) -> Any:
    """``cls(*args, **options)`` for options taken from a config: an option the class does
    not accept, or a value it rejects, raises ConfigError naming ``where`` and the option."""
    params = inspect.signature(cls).parameters
    if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
        unknown = sorted(set(options) - set(params))
        if unknown:
            accepted = sorted(k for k, p in params.items()
                              if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD))
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} for {cls.__name__}; "
                              f"expected one of: {', '.join(accepted)}")
    try:
        return cls(*args, **options)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from None
