"""The sections of a rig config as dataclasses, with the limits the parser enforces on them.
:mod:`tmscal.config` parses YAML into these (docs/configs.md lists every key). Units as the
field names say: mm, mm/s, mm/s², deg, s, Hz, N, N·m.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROBOT_RESERVED_OPTIONS = ("envelope", "speed_mm_s", "accel_mm_s2", "host", "port")
#: tracker.options keys that have their own key in the tracker section
TRACKER_RESERVED_OPTIONS = ("port", "tools", "baud", "frame_rate_hz", "reply", "log_wire")
#: safety keys a config that drives a robot must set (no defaults for a robot)
SAFETY_KEYS = ("max_offset_mm", "max_rotation_deg", "workspace_min_mm", "workspace_max_mm",
               "max_speed_mm_s", "max_accel_mm_s2")
#: plausibility bounds of the safety limits (a larger value is a typo or a unit mistake)
SAFETY_BOUNDS = {"max_offset_mm": 10_000.0, "max_rotation_deg": 180.0,
                  "max_speed_mm_s": 5_000.0, "max_accel_mm_s2": 50_000.0}
COORD_BOUND_MM = 10_000.0   # |workspace coordinate| (mm, base frame)
TOOL_BOUND_MM = 2_000.0     # |tool point coordinate| (mm, flange frame)
MAX_TOOL_POINTS = 64
MAX_CONFIG_BYTES = 1_000_000


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
    (our name → ROM file path, absolute, or None for a tool already loaded). ``log_wire``:
    a new file (absolute once parsed) that records the serial traffic (docs/devices.md);
    ``options`` go to the driver (NDI: ``reset_timeout_s``, ``init_timeout_s`` …)."""

    driver: str = "ndi"
    port: str = ""
    baud: int = 115200
    frame_rate_hz: float = 60.0
    reply: str = "bx"
    tools: dict[str, str | None] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    log_wire: str | None = None


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
    """Samples per pose (distinct tracker frames; the cap when ``sem_mm`` is set), settling
    after each move (``settle`` "still": until every body is still over ``still_window_s``
    within ``still_tol_mm`` (None: from the tracker's noise), at most ``settle_s`` s;
    "fixed": ``settle_s`` s), the share of frames with every body usable below which a pose
    is retried then skipped, how many of those frames also read the robot's flange pose
    (spread evenly), and samples by need: stop when every body's standard error of the mean
    position is ≤ ``sem_mm`` (mm; None: always ``samples``), after at least ``min_samples``.
    ``tmscal.acquisition.sample`` documents the rules."""

    samples: int = 100
    settle_s: float = 1.0
    min_share: float = 0.8
    max_frames_factor: float = 3.0
    robot_reads: int = 10
    settle: str = "still"
    still_window_s: float = 0.2
    still_tol_mm: float | None = None
    min_samples: int = 10
    sem_mm: float | None = None


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
    """Device-fault handling: reconnect attempts per fault, wait between them (s). Skipped
    poses: over the last ``skip_window`` poses of a run, a share of skipped poses above
    ``warn_skip_share`` warns once (naming the reason), above ``stop_skip_share`` stops the
    run resumably (``AcquisitionStopped``). Shares are of the window's full length."""

    retries: int = 3
    reconnect_wait_s: float = 1.0
    warn_skip_share: float = 0.10
    stop_skip_share: float = 0.5
    skip_window: int = 20


@dataclass
class MockConfig:
    """The mock rig: clock ("fast" or "real"), RNG seed, truth ("tms" built-in rig,
    "random" truth as in Wang et al. 2018, or explicit {X, Y, Z} 4×4 mm), noise
    (``sim.Noise`` fields), settle (``sim.Settle`` fields: the coil's damped oscillation
    after each move; None: no oscillation), per-device options and faults, and kinematics
    ({arm: a registered arm, errors: paper|all|none, seed}: the mock robot moves a serial arm
    whose true parameters differ from its controller's nominal ones; None: no arm model;
    docs/selfcal.md)."""

    clock: str = "fast"
    seed: int = 0
    truth: Any = "tms"
    noise: dict[str, float] = field(default_factory=dict)
    settle: dict[str, float] | None = None
    tracker: dict[str, Any] = field(default_factory=dict)
    robot: dict[str, Any] = field(default_factory=dict)
    kinematics: dict[str, Any] | None = None
    ft: dict[str, Any] = field(default_factory=dict)


@dataclass
class FTConfig:
    """A force-torque sensor (kinematic self-calibration, docs/selfcal.md): ``driver`` (a
    registered "ft" driver: ``ati`` the ATI Net F/T, ``ur_wrench`` the UR e-Series' built-in
    sensor), ``host`` (its address; "robot" or None: the robot's, for a sensor in the arm),
    ``port`` (None: the driver's default, UDP 49152 for the Net F/T), the sensor
    calibration's ``counts_per_force`` (counts per N) and ``counts_per_torque`` (counts per
    N·m; the Net F/T needs both, there is no default), ``samples`` averaged per reading, and
    driver ``options`` (docs/devices.md)."""

    driver: str
    host: str | None = None
    port: int | None = None
    counts_per_force: float | None = None
    counts_per_torque: float | None = None
    samples: int = 100
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class AdaptiveConfig:
    """Adaptive acquisition (``tmscal acquire --adaptive``, docs/adaptive.md): stop when the
    predicted coil-placement error (mm) at ``confidence`` is ≤ ``target_mm``, or after
    ``max_poses``; ``bootstrap`` spread poses first (None: the fewest that make the problem
    well posed, plus one); the candidates are the config's plan with ``pool`` poses, of which
    the first ``region`` are where the rig will place the coil (the prediction's region)."""

    target_mm: float = 0.05
    confidence: float = 0.95
    max_poses: int = 40
    bootstrap: int | None = None
    pool: int = 1000
    region: int = 200


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
    adaptive: AdaptiveConfig = field(default_factory=AdaptiveConfig)
    ft: FTConfig | None = None

    @property
    def bodies(self) -> list[str]:
        """The tracker tool names of the config (e.g. ["marker", "probe"])."""
        return list(self.tracker.tools) if self.tracker else []
