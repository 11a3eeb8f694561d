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
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import ConfigError

__all__ = ["RigConfig", "RobotConfig", "TrackerConfig", "PlanConfig", "SamplingConfig",
           "SafetyConfig", "RunConfig", "MockConfig", "load_config", "parse_config",
           "pose_from_config", "construct"]


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
    the robot base frame (mm), speed (mm/s) and acceleration (mm/s²) caps."""

    max_offset_mm: float = 200.0
    max_rotation_deg: float = 20.0
    workspace_min_mm: tuple[float, float, float] | None = None
    workspace_max_mm: tuple[float, float, float] | None = None
    max_speed_mm_s: float = 250.0
    max_accel_mm_s2: float = 1500.0


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
    return ConfigError(f"{src}: key '{key}': {msg}")


def _build(cls: type, data: Any, src: str, section: str) -> Any:
    """Build dataclass ``cls`` from a mapping, checking keys and simple types."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise _err(src, section, f"expected a mapping, got {type(data).__name__}")
    names = {f.name: f for f in fields(cls)}
    unknown = sorted(set(data) - set(names))
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


def _coerce(v: Any, typ: Any, src: str, key: str) -> Any:
    t = str(typ)
    if v is None:
        if "None" in t or t in ("Any",):
            return None
        raise _err(src, key, f"must not be empty (expected {t})")
    if t.startswith("int"):
        if isinstance(v, bool) or not isinstance(v, int):
            raise _err(src, key, f"expected an integer, got {v!r}")
        return v
    if t.startswith("float"):
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise _err(src, key, f"expected a number, got {v!r}")
        return float(v)
    if t.startswith("str"):
        if not isinstance(v, str):
            raise _err(src, key, f"expected a string, got {v!r}")
        return v
    if t.startswith("tuple[float, float, float]"):
        if (not isinstance(v, list | tuple) or len(v) != 3
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)):
            raise _err(src, key, f"expected a list of 3 numbers [x, y, z] in mm, got {v!r}")
        return tuple(float(x) for x in v)
    if t.startswith("dict"):
        if not isinstance(v, Mapping):
            raise _err(src, key, f"expected a mapping, got {v!r}")
        return dict(v)
    return v


def _positive(src: str, key: str, value: float, allow_zero: bool = False) -> None:
    if value < 0 or (value == 0 and not allow_zero):
        raise _err(src, key, f"must be {'≥' if allow_zero else '>'} 0, got {value}")


def pose_from_config(value: Any, src: str, key: str) -> np.ndarray:
    """A pose from a config value: a 4×4 list (mm) or {xyz_mm: [..], rpy_deg: [..]} with
    R = Rz·Ry·Rx (DENSO-style fixed axes)."""
    from .geometry import check_pose, matrix_from_denso_p
    if isinstance(value, Mapping):
        try:
            xyz = [float(x) for x in value["xyz_mm"]]
            rpy = [float(x) for x in value.get("rpy_deg", [0, 0, 0])]
            if len(xyz) != 3 or len(rpy) != 3:
                raise ValueError
        except (KeyError, TypeError, ValueError):
            raise _err(src, key, "expected {xyz_mm: [x, y, z], rpy_deg: [rx, ry, rz]}") \
                from None
        return matrix_from_denso_p(xyz + rpy)
    try:
        return check_pose(value, key)
    except (ValueError, TypeError) as e:
        raise _err(src, key, f"expected a rigid 4×4 matrix in mm ({e})") from None


def parse_config(data: Any, src: str = "<config>", base_dir: Path | None = None) -> RigConfig:
    """Validate a config mapping (as loaded from YAML) into a ``RigConfig``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{src}: expected a YAML mapping at the top level")
    unknown = sorted(set(data) - _SECTIONS)
    if unknown:
        raise _err(src, unknown[0], f"unknown section; expected: {', '.join(sorted(_SECTIONS))}")
    robot = None
    if data.get("robot") is not None:
        robot = _build(RobotConfig, data["robot"], src, "robot")
        if robot.driver not in ("ur", "denso"):
            raise _err(src, "robot.driver", f"expected 'ur' or 'denso', got {robot.driver!r}")
        _positive(src, "robot.speed_mm_s", robot.speed_mm_s)
        _positive(src, "robot.accel_mm_s2", robot.accel_mm_s2)
    tracker = None
    if data.get("tracker") is not None:
        tracker = _build(TrackerConfig, data["tracker"], src, "tracker")
        if tracker.driver != "ndi":
            raise _err(src, "tracker.driver", f"expected 'ndi', got {tracker.driver!r}")
        if tracker.reply not in ("bx", "tx"):
            raise _err(src, "tracker.reply", f"expected 'bx' or 'tx', got {tracker.reply!r}")
        if not tracker.tools:
            raise _err(src, "tracker.tools", "name at least one tool, e.g. {marker: file.rom}")
        tools: dict[str, str | None] = {}
        for name, rom in tracker.tools.items():
            if rom is None:
                tools[str(name)] = None
                continue
            if not isinstance(rom, str):
                raise _err(src, f"tracker.tools.{name}", f"expected a ROM file path, got {rom!r}")
            p = Path(rom)
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            if not p.is_file():
                raise _err(src, f"tracker.tools.{name}", f"ROM file not found: {p}")
            tools[str(name)] = str(p)
        tracker.tools = tools
        _positive(src, "tracker.frame_rate_hz", tracker.frame_rate_hz)
    plan = _build(PlanConfig, data.get("plan"), src, "plan")
    if plan.kind not in ("eq14", "sphere"):
        raise _err(src, "plan.kind", f"expected 'eq14' or 'sphere', got {plan.kind!r}")
    if plan.poses < 1:
        raise _err(src, "plan.poses", f"must be ≥ 1, got {plan.poses}")
    _positive(src, "plan.radius_mm", plan.radius_mm, allow_zero=True)
    _positive(src, "plan.rotation_deg", plan.rotation_deg, allow_zero=True)
    if plan.start != "current":
        plan.start = pose_from_config(plan.start, src, "plan.start")
    sampling = _build(SamplingConfig, data.get("sampling"), src, "sampling")
    if sampling.samples < 1:
        raise _err(src, "sampling.samples", f"must be ≥ 1, got {sampling.samples}")
    _positive(src, "sampling.settle_s", sampling.settle_s, allow_zero=True)
    if sampling.robot_reads < 1:
        raise _err(src, "sampling.robot_reads", f"must be ≥ 1, got {sampling.robot_reads}")
    if not 0 < sampling.min_share <= 1:
        raise _err(src, "sampling.min_share", f"must be in (0, 1], got {sampling.min_share}")
    safety = _build(SafetyConfig, data.get("safety"), src, "safety")
    for k in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s", "max_accel_mm_s2"):
        _positive(src, f"safety.{k}", getattr(safety, k))
    if (safety.workspace_min_mm is None) != (safety.workspace_max_mm is None):
        raise _err(src, "safety.workspace_min_mm", "give both workspace_min_mm and "
                   "workspace_max_mm, or neither")
    if safety.workspace_min_mm is not None and any(
            a >= b for a, b in zip(safety.workspace_min_mm, safety.workspace_max_mm or ())):
        raise _err(src, "safety.workspace_max_mm", "each entry must exceed workspace_min_mm")
    run = _build(RunConfig, data.get("run"), src, "run")
    mock = None
    if data.get("mock") is not None:
        mock = _build(MockConfig, data["mock"], src, "mock")
        if mock.clock not in ("fast", "real"):
            raise _err(src, "mock.clock", f"expected 'fast' or 'real', got {mock.clock!r}")
        if isinstance(mock.truth, Mapping):
            mock.truth = {k: pose_from_config(v, src, f"mock.truth.{k}")
                          for k, v in mock.truth.items()}
            if "X" not in mock.truth or "Z" not in mock.truth:
                raise _err(src, "mock.truth", "explicit truth needs at least X and Z")
        elif mock.truth not in ("tms", "random"):
            raise _err(src, "mock.truth", f"expected 'tms', 'random' or {{X, Y, Z}}, "
                       f"got {mock.truth!r}")
    if robot is not None and robot.speed_mm_s > safety.max_speed_mm_s:
        raise _err(src, "robot.speed_mm_s", f"{robot.speed_mm_s} mm/s exceeds "
                   f"safety.max_speed_mm_s {safety.max_speed_mm_s}")
    if robot is not None and robot.accel_mm_s2 > safety.max_accel_mm_s2:
        raise _err(src, "robot.accel_mm_s2", f"{robot.accel_mm_s2} mm/s² exceeds "
                   f"safety.max_accel_mm_s2 {safety.max_accel_mm_s2}")
    return RigConfig(path=None, robot=robot, tracker=tracker, plan=plan, sampling=sampling,
                     safety=safety, run=run, mock=mock, raw=dict(data))


def load_config(path: str | os.PathLike[str]) -> RigConfig:
    """Load and validate a YAML rig config. Raises ConfigError naming the file and key."""
    p = Path(path)
    try:
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
    cfg = parse_config(data, str(p), p.parent)
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
