"""The sections of a rig config as dataclasses. :mod:`tmscal.config` parses YAML into these
(docs/configs.md lists every key). Units as the field names say: mm, mm/s, mm/s², deg, s, Hz,
N, N·m. The device sections (robot, tracker, ft) hold the generic keys; what a driver owns is
in their ``settings`` (:mod:`tmscal.config.settings`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from ..calib.prediction import AdaptiveSettings
    from .settings import DriverSettings, TrackerSettings

__all__ = ["RobotConfig", "TrackerConfig", "FTConfig", "PlanConfig", "SamplingConfig",
           "SafetyConfig", "RunConfig", "MockConfig", "RigConfig"]


@dataclass
class RobotConfig:
    """The robot section: a registered robot ``driver``, the controller's ``host`` and
    ``port`` (None: the driver's default), the motion's speed (mm/s) and acceleration
    (mm/s²), the driver ``options`` as its settings class checked them, ``settings``
    (the driver's own keys; set by the parser), and ``arm``: the arm the session records
    (a registry name, a shipped arm file's name, or the path of a URDF or arm file, relative
    paths against the config's folder; docs/kinematics.md, "Arm files"; None: the one the
    driver reports), with a URDF's chain links ``urdf_base`` and ``urdf_flange``."""

    driver: str
    host: str = "127.0.0.1"
    port: int | None = None
    speed_mm_s: float = 100.0
    accel_mm_s2: float = 500.0
    options: dict[str, Any] = field(default_factory=dict)
    settings: DriverSettings | None = None
    arm: str | None = None
    urdf_base: str | None = None
    urdf_flange: str | None = None


@dataclass
class TrackerConfig:
    """The tracker section: a registered tracker ``driver``, its ``settings`` (the driver's
    own keys and the tools' values: NDI ``port``, ``baud``, ``reply``, ``log_wire`` and the
    ROM files, absolute), the frame rate (Hz) and the driver ``options`` as its settings
    class checked them."""

    driver: str
    settings: TrackerSettings
    frame_rate_hz: float = 60.0
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def tools(self) -> dict[str, Any]:
        """Tool name (our name, e.g. "marker") → the value the driver knows it by (NDI: the
        ROM file, absolute, or None for a tool already loaded)."""
        return self.settings.tools


@dataclass
class PlanConfig:
    """Pose plan around P0: Eq. 14 (±radius_mm per axis, ±rotation_deg per axis), a sphere
    of radius_mm, or ``joints``: joint configurations of the arm (``arm``, a registered name;
    default the one the robot driver reports) within ±``span_deg`` (default 30) of its joints
    at P0, ``pool`` candidates (default 4000), spread out, their flange within radius_mm and
    rotation_deg of P0 and inside the safety envelope (docs/kinematics.md). ``start`` is
    "current" (the flange pose when the run starts) or a 4×4 mm."""

    kind: str = "eq14"
    poses: int = 500
    radius_mm: float = 100.0
    rotation_deg: float = 10.0
    seed: int = 1
    start: Any = "current"
    arm: str | None = None
    span_deg: float | None = None
    pool: int | None = None


@dataclass
class SamplingConfig:
    """Samples per pose (distinct tracker frames; the cap when ``sem_mm`` is set), settling
    after each move (``settle`` "still": until every body is still over ``still_window_s``
    within ``still_tol_mm`` (None: from the tracker's noise), at most ``settle_s`` s;
    "fixed": ``settle_s`` s), the share of frames with every body usable below which a pose
    is retried then skipped, how many of those frames also read the robot's flange pose
    (spread evenly), and samples by need: stop when every body's standard error of the mean
    position is ≤ ``sem_mm`` (mm; None: always ``samples``), after at least ``min_samples``.
    ``tmscal.acquisition.sample`` documents the rules.

    The one declaration of the sampling settings: the config's section, a run's settings
    (``tmscal.acquisition.settings.SamplingSettings`` adds where they came from) and
    ``sample_pose``'s argument; ``tmscal.config.run.check_sampling`` is the one check of
    their ranges."""

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

    #: what a session header records (``max_frames_factor`` bounds a read, not the data)
    HEADER_KEYS: ClassVar[tuple[str, ...]] = (
        "samples", "settle_s", "min_share", "robot_reads", "settle", "still_window_s",
        "still_tol_mm", "min_samples", "sem_mm")

    def to_header(self) -> dict[str, Any]:
        """The settings a session header records (docs/session-format.md)."""
        return {k: getattr(self, k) for k in self.HEADER_KEYS}

    def values(self) -> dict[str, Any]:
        """Every field's value by name."""
        return {f.name: getattr(self, f.name) for f in fields(SamplingConfig)}


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
    ({arm: a registered arm, errors: paper|all|none|realistic, seed}: the mock robot moves a
    serial arm whose true parameters differ from its controller's nominal ones; None: no arm
    model; docs/selfcal.md, docs/kinematics.md), changes ({move: {"mm": (3,) mm, "deg": (3,)
    rotation vector in degrees}}, move one of tracker, marker, coil, coil_centre: applied to
    the truth when the rig is built) and events ([{"at_s": s, "move", "mm", "deg"}]: the same
    changes at a time of the rig's clock), both as ``tmscal.sim.changes`` defines them
    (docs/configs.md)."""

    clock: str = "fast"
    seed: int = 0
    truth: Any = "tms"
    noise: dict[str, float] = field(default_factory=dict)
    settle: dict[str, float] | None = None
    tracker: dict[str, Any] = field(default_factory=dict)
    robot: dict[str, Any] = field(default_factory=dict)
    kinematics: dict[str, Any] | None = None
    ft: dict[str, Any] = field(default_factory=dict)
    changes: dict[str, Any] | None = field(default_factory=dict)
    events: list[dict[str, Any]] | None = field(default_factory=list)


@dataclass
class FTConfig:
    """A force-torque sensor (kinematic self-calibration, docs/selfcal.md): ``driver`` (a
    registered "ft" driver: ``ati`` the ATI Net F/T, ``ur_wrench`` the UR e-Series' built-in
    sensor), ``host`` (its address; "robot" or None: the robot's, for a sensor in the arm),
    ``port`` (None: the driver's default, UDP 49152 for the Net F/T), ``samples`` averaged
    per reading, driver ``options`` and ``settings`` (the driver's own keys: the Net F/T's
    counts per N and per N·m; set by the parser; docs/devices.md)."""

    driver: str
    host: str | None = None
    port: int | None = None
    samples: int = 100
    options: dict[str, Any] = field(default_factory=dict)
    settings: DriverSettings | None = None


def _default_adaptive() -> AdaptiveSettings:
    from ..calib.prediction import AdaptiveSettings  # numerics: imported when a config is built

    return AdaptiveSettings()


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
    adaptive: AdaptiveSettings = field(default_factory=_default_adaptive)
    ft: FTConfig | None = None

    @property
    def bodies(self) -> list[str]:
        """The tracker tool names of the config (e.g. ["marker", "probe"])."""
        return list(self.tracker.tools) if self.tracker else []
