"""Rig configs: YAML → validated dataclasses. Every error names the file, the key and what
was expected.

A config describes one rig (see ``configs/*.yaml`` for commented examples)::

    robot:    {driver: ur|denso, host, port, speed_mm_s, accel_mm_s2, options: {...}}
    tracker:  {driver: ndi, port, baud, frame_rate_hz, reply: bx|tx,
               tools: {marker: file.rom, probe: file.rom}}
    plan:     {kind: eq14|sphere, poses, radius_mm, rotation_deg, seed, start}
    sampling: {samples, settle_s, min_share, max_frames_factor, robot_reads, settle,
               still_window_s, still_tol_mm, min_samples, sem_mm}
    safety:   {max_offset_mm, max_rotation_deg, workspace_min_mm, workspace_max_mm,
               max_speed_mm_s, max_accel_mm_s2}
    run:      {retries, reconnect_wait_s, warn_skip_share, stop_skip_share, skip_window}
    adaptive: {target_mm, confidence, max_poses, bootstrap, pool, region}
    ft:       {driver: ati|ur_wrench, host (or "robot"), port, counts_per_force,
               counts_per_torque, samples, options: {...}}
    mock:     {clock: fast|real, seed, truth: tms|random|{X, Y, Z}, noise: {...},
               settle: {amplitude_mm, tau_s, freq_hz, rotation_deg},
               kinematics: {arm: ur5e|vs060|… (registered), errors: paper|all|none, seed},
               tracker: {model, faults: {...}, ...}, robot: {faults: {...}, ...},
               ft: {noise_n, noise_nm, faults: {...}, rate_hz, payload_kg, payload_cog_mm}}

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

import json
import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .config_checks import (
    INT_BOUND,
    build,
    check_adaptive,
    check_ft,
    check_kinematics,
    check_mock_ft,
    check_sampling,
    check_tree,
    construct,
    err,
    in_range,
    positive,
    show,
    with_line,
)
from .config_paths import log_wire_path, rom_path, tracker_port_problem
from .config_sections import (  # noqa: F401  (re-exported: the public config names)
    COORD_BOUND_MM,
    MAX_CONFIG_BYTES,
    MAX_TOOL_POINTS,
    ROBOT_RESERVED_OPTIONS,
    SAFETY_BOUNDS,
    SAFETY_KEYS,
    TOOL_BOUND_MM,
    TRACKER_RESERVED_OPTIONS,
    AdaptiveConfig,
    FTConfig,
    MockConfig,
    PlanConfig,
    RigConfig,
    RobotConfig,
    RunConfig,
    SafetyConfig,
    SamplingConfig,
    TrackerConfig,
)
from .errors import ConfigError

__all__ = ["RigConfig", "RobotConfig", "TrackerConfig", "FTConfig", "PlanConfig", "SamplingConfig",
           "SafetyConfig", "RunConfig", "MockConfig", "AdaptiveConfig", "load_config",
           "parse_config", "pose_from_config", "construct", "tracker_port_problem",
           "ROBOT_RESERVED_OPTIONS", "TRACKER_RESERVED_OPTIONS", "SAFETY_KEYS"]

log = logging.getLogger(__name__)

#: robot.options keys that would override a safety or motion argument, or one with its own key
_SECTIONS = {"robot", "tracker", "plan", "sampling", "safety", "run", "mock", "adaptive",
             "ft", "name", "description"}


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
            raise err(src, key, "expected {xyz_mm: [x, y, z], rpy_deg: [rx, ry, rz]}") \
                from None
        return matrix_from_denso_p(xyz + rpy)
    try:
        return check_pose(value, key)
    except (ValueError, TypeError, OverflowError) as e:
        raise err(src, key, f"expected a rigid 4×4 matrix in mm ({e})") from None


def _check_safety(data: Any, src: str, drives_robot: bool) -> SafetyConfig:
    """The safety section: every limit finite, positive, plausible; box ordered; tool points
    finite. A config that drives a robot must set every key of ``SAFETY_KEYS``."""
    raw = data.get("safety")
    if drives_robot:
        if raw is None:
            raise err(src, "safety", "a config that drives a robot needs a safety section "
                      f"({', '.join(SAFETY_KEYS)})")
        if isinstance(raw, Mapping):
            for k in SAFETY_KEYS:
                if raw.get(k) is None:
                    raise err(src, f"safety.{k}", "missing: a config that drives a robot must "
                              f"set every safety limit ({', '.join(SAFETY_KEYS)})")
    safety = build(SafetyConfig, raw, src, "safety")
    for k, bound in SAFETY_BOUNDS.items():
        positive(src, f"safety.{k}", getattr(safety, k), at_most=bound)
    lo, hi = safety.workspace_min_mm, safety.workspace_max_mm
    if (lo is None) != (hi is None):
        raise err(src, "safety.workspace_min_mm", "give both workspace_min_mm and "
                  "workspace_max_mm, or neither")
    if lo is not None and hi is not None:
        for key, xyz in (("safety.workspace_min_mm", lo), ("safety.workspace_max_mm", hi)):
            if not all(abs(c) <= COORD_BOUND_MM for c in xyz):
                raise err(src, key, f"{list(xyz)} mm: every coordinate must be within "
                          f"±{COORD_BOUND_MM:g} mm of the robot base; check the units")
        for axis, a, b in zip("xyz", lo, hi, strict=True):
            if not a < b:
                raise err(src, "safety.workspace_max_mm", f"{axis} {b} must exceed "
                          f"workspace_min_mm {axis} {a}")
    if safety.tool_points_mm is not None:
        if len(safety.tool_points_mm) > MAX_TOOL_POINTS:
            raise err(src, "safety.tool_points_mm", f"at most {MAX_TOOL_POINTS} points")
        for i, q in enumerate(safety.tool_points_mm):
            if not all(abs(c) <= TOOL_BOUND_MM for c in q):
                raise err(src, f"safety.tool_points_mm[{i}]", f"{list(q)} mm: a tool point "
                          f"(flange frame) must be within ±{TOOL_BOUND_MM:g} mm of the "
                          "flange; check the units")
    return safety


def _check_options(options: Mapping[str, Any], reserved: tuple[str, ...], src: str,
                   section: str) -> None:
    for k in options:
        if k in reserved:
            raise err(src, f"{section}.options.{k}", f"'{k}' cannot be set through options: "
                      + ("the envelope comes from the safety section only"
                         if k == "envelope" else f"set {section}.{k} instead"))


def _parse_robot(data: Any, src: str) -> RobotConfig | None:
    """The robot section (None when absent): a registered robot driver, a host, a port in
    0…65535, positive speed and acceleration, no reserved option."""
    if data is None:
        return None
    robot = build(RobotConfig, data, src, "robot")
    _check_driver(src, "robot", robot.driver)
    if not robot.host:
        raise err(src, "robot.host", "must not be empty")
    if robot.port is not None:
        in_range(src, "robot.port", robot.port, 0, 65535)
    positive(src, "robot.speed_mm_s", robot.speed_mm_s)
    positive(src, "robot.accel_mm_s2", robot.accel_mm_s2)
    _check_options(robot.options, ROBOT_RESERVED_OPTIONS, src, "robot")
    return robot


def _check_driver(src: str, kind: str, name: str) -> None:
    """``name`` is a registered driver of ``kind`` (the driver registry is the one list)."""
    from .drivers import registry

    if registry.is_registered(name, kind):  # built-ins need no entry point loaded
        return
    known = registry.driver_names(kind)
    if name not in known:
        raise err(src, f"{kind}.driver", f"expected {registry.alternatives(known)}, got "
                  f"{name!r}")


def _parse_tracker(data: Any, src: str, base_dir: Path | None,
                   check_files: bool = True) -> TrackerConfig | None:
    """The tracker section (None when absent): a registered tracker driver, reply bx or tx,
    an acceptable port, at least one tool with a ROM file (relative paths against
    ``base_dir``; that the files exist is checked unless ``check_files`` is False, as for a
    command that opens only the robot), plausible rate and baud, no reserved option."""
    if data is None:
        return None
    tracker = build(TrackerConfig, data, src, "tracker")
    _check_driver(src, "tracker", tracker.driver)
    if tracker.reply not in ("bx", "tx"):
        raise err(src, "tracker.reply", f"expected 'bx' or 'tx', got {tracker.reply!r}")
    if tracker.port:
        problem = tracker_port_problem(tracker.port)
        if problem:
            raise err(src, "tracker.port", f"{show(tracker.port)}: {problem}")
    if not tracker.tools:
        raise err(src, "tracker.tools", "name at least one tool, e.g. {marker: file.rom}")
    tracker.tools = {name: rom_path(rom, src, name, base_dir, check_files)
                     for name, rom in tracker.tools.items()}
    positive(src, "tracker.frame_rate_hz", tracker.frame_rate_hz, at_most=10_000)
    positive(src, "tracker.baud", tracker.baud)
    _check_options(tracker.options, TRACKER_RESERVED_OPTIONS, src, "tracker")
    if tracker.log_wire is not None:
        tracker.log_wire = log_wire_path(tracker, src, base_dir)
    return tracker


def _parse_plan(data: Any, src: str) -> PlanConfig:
    """The plan section: kind, pose count, ranges, seed, and start ("current" or a pose)."""
    plan = build(PlanConfig, data, src, "plan")
    if plan.kind not in ("eq14", "sphere"):
        raise err(src, "plan.kind", f"expected 'eq14' or 'sphere', got {plan.kind!r}")
    in_range(src, "plan.poses", plan.poses, 1, 100_000)
    positive(src, "plan.radius_mm", plan.radius_mm, allow_zero=True, at_most=COORD_BOUND_MM)
    positive(src, "plan.rotation_deg", plan.rotation_deg, allow_zero=True, at_most=180.0)
    in_range(src, "plan.seed", plan.seed, 0, INT_BOUND - 1)
    if isinstance(plan.start, str):
        if plan.start != "current":
            raise err(src, "plan.start", f"expected 'current' or a pose, got {plan.start!r}")
    else:
        plan.start = pose_from_config(plan.start, src, "plan.start")
        if not np.all(np.abs(plan.start[:3, 3]) <= COORD_BOUND_MM):
            raise err(src, "plan.start", f"position must be within ±{COORD_BOUND_MM:g} mm")
    return plan


def _parse_sampling(data: Any, src: str) -> SamplingConfig:
    """The sampling section: counts, settling, usable share, frame budget, samples by need."""
    sampling = build(SamplingConfig, data, src, "sampling")
    check_sampling(sampling, src)
    return sampling


def _parse_run(data: Any, src: str) -> RunConfig:
    """The run section: reconnect attempts and the wait between them; the skip shares that
    warn and stop (in [0, 1], warn ≤ stop) and the window they are counted over (poses)."""
    run = build(RunConfig, data, src, "run")
    in_range(src, "run.retries", run.retries, 0, 1000)
    positive(src, "run.reconnect_wait_s", run.reconnect_wait_s, allow_zero=True,
             at_most=3600.0)
    in_range(src, "run.skip_window", run.skip_window, 1, 100_000)
    for key in ("warn_skip_share", "stop_skip_share"):
        v = getattr(run, key)
        if not 0 <= v <= 1:
            raise err(src, f"run.{key}", f"must be in [0, 1], got {v}")
    if run.warn_skip_share > run.stop_skip_share:
        raise err(src, "run.warn_skip_share", f"{run.warn_skip_share} is above "
                  f"run.stop_skip_share {run.stop_skip_share}: the warning must come first")
    return run


def _parse_mock(data: Any, src: str) -> MockConfig | None:
    """The mock section (None when absent): clock, seed, truth, settle (checked by building
    ``sim.Settle``), per-device faults and the tracker's measurement volume."""
    if data is None:
        return None
    mock = build(MockConfig, data, src, "mock")
    if mock.clock not in ("fast", "real"):
        raise err(src, "mock.clock", f"expected 'fast' or 'real', got {mock.clock!r}")
    in_range(src, "mock.seed", mock.seed, 0, INT_BOUND - 1)
    if isinstance(mock.truth, Mapping):
        extra = sorted(set(mock.truth) - {"X", "Y", "Z"})
        if extra:
            raise err(src, f"mock.truth.{extra[0]}", "expected X, Y and Z only")
        mock.truth = {k: pose_from_config(v, src, f"mock.truth.{k}")
                      for k, v in mock.truth.items()}
        if "X" not in mock.truth or "Z" not in mock.truth:
            raise err(src, "mock.truth", "explicit truth needs at least X and Z")
    elif mock.truth not in ("tms", "random"):
        raise err(src, "mock.truth", f"expected 'tms', 'random' or {{X, Y, Z}}, "
                  f"got {show(mock.truth)}")
    mock.kinematics = check_kinematics(mock.kinematics, src, mock.seed)
    if mock.settle is not None:
        from .sim.rig import Settle
        construct(Settle, f"{src}: key 'mock.settle'", **mock.settle)
    check_mock_ft(mock.ft, src)
    for dev in ("tracker", "robot"):
        faults = getattr(mock, dev).get("faults")
        if faults is not None and not isinstance(faults, Mapping):
            raise err(src, f"mock.{dev}.faults", f"expected a mapping of fault settings, "
                      f"got {show(faults)}")
        vol = getattr(mock, dev).get("volume", "default")
        if dev == "tracker" and not (vol is None or vol == "default" or isinstance(vol, Mapping)):
            raise err(src, "mock.tracker.volume", f"expected 'default', null or a mapping, "
                      f"got {show(vol)}")
    return mock


def _check_top_level(data: Any, src: str) -> None:
    """A mapping of plain data with known sections; name and description are strings."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{src}: expected a YAML mapping at the top level")
    check_tree(data, src)
    unknown = sorted(k for k in data if k not in _SECTIONS)
    if unknown:
        raise err(src, unknown[0], f"unknown section; expected: {', '.join(sorted(_SECTIONS))}")
    for k in ("name", "description"):
        if data.get(k) is not None and not isinstance(data[k], str):
            raise err(src, k, f"expected a string, got {show(data[k])}")


def _check_robot_caps(robot: RobotConfig | None, safety: SafetyConfig, src: str) -> None:
    """The robot's configured speed and acceleration are within the safety caps."""
    if robot is not None and robot.speed_mm_s > safety.max_speed_mm_s:
        raise err(src, "robot.speed_mm_s", f"{robot.speed_mm_s} mm/s exceeds "
                  f"safety.max_speed_mm_s {safety.max_speed_mm_s}")
    if robot is not None and robot.accel_mm_s2 > safety.max_accel_mm_s2:
        raise err(src, "robot.accel_mm_s2", f"{robot.accel_mm_s2} mm/s² exceeds "
                  f"safety.max_accel_mm_s2 {safety.max_accel_mm_s2}")


def parse_config(data: Any, src: str = "<config>", base_dir: Path | None = None,
                 check_files: bool = True) -> RigConfig:
    """Validate a config mapping (as loaded from YAML) into a ``RigConfig``. Raises
    ConfigError naming ``src`` and the key (see the module docstring for the rules).
    ``check_files=False`` skips the check that the tools' ROM files exist (``tmscal robot``
    needs only the robot; ``make_tracker`` checks them before a tracker opens)."""
    _check_top_level(data, src)
    robot = _parse_robot(data.get("robot"), src)
    tracker = _parse_tracker(data.get("tracker"), src, base_dir, check_files)
    plan = _parse_plan(data.get("plan"), src)
    sampling = _parse_sampling(data.get("sampling"), src)
    safety = _check_safety(data, src, robot is not None)
    run = _parse_run(data.get("run"), src)
    mock = _parse_mock(data.get("mock"), src)
    adaptive = check_adaptive(build(AdaptiveConfig, data.get("adaptive"), src, "adaptive"), src)
    ft = None
    if data.get("ft") is not None:
        ft = build(FTConfig, data["ft"], src, "ft")
        _check_driver(src, "ft", ft.driver)
        check_ft(ft, src)
    _check_robot_caps(robot, safety, src)
    try:  # the resolved config goes into the session header as JSON
        json.dumps(data, allow_nan=False)
    except (TypeError, ValueError, OverflowError, RecursionError) as e:
        raise ConfigError(f"{src}: the config is not plain data ({e})") from None
    if robot is not None and safety.tool_points_mm is None:
        log.warning("%s: key 'safety.tool_points_mm' is not set: the workspace box bounds the "
                    "robot FLANGE only, not the coil hanging below it. List points of the coil "
                    "(flange frame, mm) so the box bounds them too.", src)
    return RigConfig(path=None, robot=robot, tracker=tracker, plan=plan, sampling=sampling,
                     safety=safety, run=run, mock=mock, raw=dict(data), adaptive=adaptive,
                     ft=ft)


def load_config(path: str | os.PathLike[str], *, check_files: bool = True) -> RigConfig:
    """Load and validate a YAML rig config. Raises ConfigError naming the file, the line and
    the key; nothing is opened or written. ``check_files=False``: see ``parse_config``."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_CONFIG_BYTES:
            raise ConfigError(f"{p}: the config is larger than {MAX_CONFIG_BYTES:,} bytes")
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
        raise ConfigError(f"{p}: invalid YAML ({show(str(e), 120)})") from None
    try:
        cfg = parse_config(data, str(p), p.parent, check_files)
    except ConfigError as e:
        raise with_line(e, str(p), text) from None
    cfg.path = p
    return cfg
