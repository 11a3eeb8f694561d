"""Rig configs: YAML → validated dataclasses. Every error names the file, the key and what
was expected.

A config describes one rig (see ``configs/*.yaml`` for commented examples)::

    robot:    {driver: ur|denso|franka, host, port, speed_mm_s, accel_mm_s2, [arm, urdf_base,
               urdf_flange], options: {...}}
    tracker:  {driver: ndi|igtl, tools: {marker: ..., probe: ...}, frame_rate_hz,
               options: {...}, + the driver's keys (ndi: port, baud, reply, log_wire, the
               tools' ROM files; igtl: host, port, timeout_s, the tools' TRANSFORM names)}
    plan:     {kind: eq14|sphere|joints, poses, radius_mm, rotation_deg, seed, start,
               joints only: arm, span_deg, pool}
    sampling: {samples, settle_s, min_share, max_frames_factor, robot_reads, settle,
               still_window_s, still_tol_mm, min_samples, sem_mm}
    safety:   {max_offset_mm, max_rotation_deg, workspace_min_mm, workspace_max_mm,
               max_speed_mm_s, max_accel_mm_s2}
    run:      {retries, reconnect_wait_s, warn_skip_share, stop_skip_share, skip_window}
    adaptive: {target_mm, confidence, max_poses, bootstrap, pool, region}
    ft:       {driver: ati|ur_wrench, host (or "robot"), port, samples, options: {...},
               + the driver's keys (ati: counts_per_force, counts_per_torque)}
    mock:     {clock: fast|real, seed, truth: tms|random|{X, Y, Z}, noise: {...},
               settle: {amplitude_mm, tau_s, freq_hz, rotation_deg},
               kinematics: {arm: ur5e|vs060|… (registered),
                            errors: paper|all|none|realistic, seed},
               tracker: {model, faults: {...}, ...}, robot: {faults: {...}, ...},
               ft: {noise_n, noise_nm, faults: {...}, rate_hz, payload_kg, payload_cog_mm}}

Lengths are mm, angles degrees (``_deg``), speeds mm/s, times seconds. Relative file paths
(ROM files) are resolved against the config file's folder.

The package, by concern: ``values`` (checks of single values and the whole document, line
numbers), ``sections`` (the dataclasses), ``devices`` (the generic robot, tracker and ft
keys) and ``settings`` (the protocol by which each driver reads its own keys and options,
docs/devices.md "Adding a driver"), ``safety``, ``plan``, ``run`` (sampling, run, adaptive),
``mock``, and ``loader`` (``load_config``, ``parse_config``).

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
* ``robot.options``, ``tracker.options`` and ``ft.options`` cannot name an argument that has
  its own key or carries a limit (robot: envelope, speed_mm_s, accel_mm_s2, host, port;
  tracker: tools, frame_rate_hz; ft: host, port, samples; and the driver's own keys), and
  name only options the driver declares, of the declared type and range.
* An NDI ``tracker.port`` is a device path (/dev/ttyUSB0, /dev/pts/3, COM3) or
  socket://host:port; no other pyserial URL scheme (spy://, loop://, rfc2217:// …) is
  accepted.
* Every key of every mapping is a string; seeds are ≥ 0; the document is at most 1 MB, 32
  levels deep and 100,000 values (YAML aliases counted where used), holds no recursive
  anchors, and is plain JSON data (the resolved config goes into the session header).

Every violation is a ConfigError naming the file, the key and (for ``load_config``) the line,
raised before any device is opened.
"""

from __future__ import annotations

from .devices import GENERIC_KEYS, RESERVED_OPTIONS, reserved_options, settings_class
from .loader import load_config, parse_config
from .plan import pose_from_config
from .run import SETTLE_MODES
from .safety import SAFETY_BOUNDS, SAFETY_KEYS
from .sections import (
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
from .settings import DriverSettings, FTSettings, Option, RobotSettings, TrackerSettings
from .values import MAX_CONFIG_BYTES, construct

__all__ = ["RigConfig", "RobotConfig", "TrackerConfig", "FTConfig", "PlanConfig",
           "SamplingConfig", "SafetyConfig", "RunConfig", "MockConfig",
           "load_config", "parse_config", "pose_from_config", "construct", "DriverSettings",
           "TrackerSettings", "RobotSettings", "FTSettings", "Option", "GENERIC_KEYS",
           "RESERVED_OPTIONS", "reserved_options", "settings_class", "SAFETY_KEYS",
           "SAFETY_BOUNDS", "SETTLE_MODES", "MAX_CONFIG_BYTES"]
