"""Device contracts shared by every driver: ``Tracker``, ``Robot``, ``TrackerFrame``, the
driver registry, and (re-exported) the typed errors.

A driver subclasses ``Tracker`` or ``Robot`` and fills the private hooks (``_open``,
``_close``, ``_read`` / ``_flange_pose``, ``_move_to``, ``_stop``); the base class owns the
public behaviour: the context-manager lifecycle (``close()`` is safe twice and after a failed
``open()``), and, for robots, the safety check that runs before every motion is sent.

Frames and units: tracker poses are ``tracker_from_<tool>`` 4×4 in mm; robot poses are
``base_from_flange`` 4×4 in mm; speeds are mm/s.
"""

from __future__ import annotations

import importlib
import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import (  # noqa: F401  (re-exported: the contract's error types)
    ConfigError,
    ConnectionLost,
    DeviceError,
    DeviceTimeout,
    ProtocolError,
    RobotFault,
    SafetyError,
    SessionError,
    TmscalError,
)

log = logging.getLogger(__name__)

Pose = np.ndarray


# --- tracker ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class ToolState:
    """One tool in one tracker frame.

    ``pose`` is tracker_from_tool, 4×4 float64 in mm, or None when the tool is missing.
    ``error_mm`` is the tracker's RMS fit error (mm) or None. ``port_status`` is the raw
    device status word where the device has one.
    """

    pose: np.ndarray | None
    missing: bool = False
    out_of_volume: bool = False
    partially_out_of_volume: bool = False
    error_mm: float | None = None
    port_status: int = 0

    @property
    def usable(self) -> bool:
        """True when the pose is present and the tool is fully inside the volume."""
        return (self.pose is not None and not self.missing and not self.out_of_volume
                and not self.partially_out_of_volume)


@dataclass(frozen=True)
class TrackerFrame:
    """One tracker reading: the device frame number, the host time (``time.monotonic()``,
    seconds) at which the reply arrived, one ``ToolState`` per configured tool name, and the
    device's system status word."""

    frame: int
    host_time: float
    tools: Mapping[str, ToolState]
    system_status: int = 0

    def pose(self, tool: str) -> np.ndarray | None:
        """tracker_from_<tool> 4×4 mm, or None when missing."""
        return self.tools[tool].pose


class _Device(ABC):
    """Lifecycle shared by trackers and robots: open in ``__enter__``/``open()``, close once."""

    name: str = "device"

    def __init__(self) -> None:
        self._opened = False

    def open(self) -> _Device:
        """Connect and initialise the device. On failure, whatever was opened is closed."""
        if self._opened:
            return self
        try:
            self._open()
        except BaseException:
            try:
                self._close()
            except Exception:  # pragma: no cover - best effort cleanup
                log.debug("cleanup after failed open raised", exc_info=True)
            raise
        self._opened = True
        return self

    def close(self) -> None:
        """Stop and disconnect; safe to call twice."""
        if not self._opened:
            return
        self._opened = False
        self._close()

    @property
    def is_open(self) -> bool:
        """True between a successful open() and close()."""
        return self._opened

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def identity(self) -> dict[str, Any]:
        """Identity and firmware of the connected device, for the session header."""
        return {"driver": self.name}

    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...


class Tracker(_Device):
    """An optical tracker. ``tools`` are the configured tool names (e.g. "marker", "probe");
    ``read()`` returns the next ``TrackerFrame`` (it may repeat a frame number when polled
    faster than ``frame_rate_hz``: count distinct frames)."""

    def __init__(self, tools: Sequence[str], frame_rate_hz: float) -> None:
        super().__init__()
        self.tools = list(tools)
        self.frame_rate_hz = float(frame_rate_hz)

    def read(self) -> TrackerFrame:
        """Read one frame. Raises ``DeviceError`` subclasses, never bare exceptions."""
        if not self._opened:
            raise DeviceError(f"{self.name}: read() on a tracker that is not open")
        return self._read()

    @abstractmethod
    def _read(self) -> TrackerFrame: ...


@dataclass(frozen=True)
class Envelope:
    """Safety envelope for robot motion. Poses are base_from_flange, mm.

    ``center`` (P0) with ``max_offset_mm`` (distance of the flange origin from P0) and
    ``max_rotation_deg`` (rotation away from P0); ``box_min_mm``/``box_max_mm`` a workspace
    box in the robot base frame; ``max_speed_mm_s`` and ``max_accel_mm_s2`` caps.
    Any limit left None is not checked.
    """

    center: np.ndarray | None = None
    max_offset_mm: float | None = None
    max_rotation_deg: float | None = None
    box_min_mm: tuple[float, float, float] | None = None
    box_max_mm: tuple[float, float, float] | None = None
    max_speed_mm_s: float | None = None
    max_accel_mm_s2: float | None = None

    def violations(self, pose: np.ndarray) -> list[str]:
        """Every limit this base_from_flange pose (mm) breaks, as readable strings."""
        out: list[str] = []
        p = np.asarray(pose, dtype=np.float64)
        if p.shape != (4, 4) or not np.isfinite(p).all():
            return [f"pose is not a finite 4×4 matrix (shape {p.shape})"]
        t = p[:3, 3]
        if self.center is not None:
            c = np.asarray(self.center, dtype=np.float64)
            if self.max_offset_mm is not None:
                d = float(np.linalg.norm(t - c[:3, 3]))
                if d > self.max_offset_mm + 1e-9:
                    out.append(f"offset from P0 {d:.1f} mm > max_offset_mm {self.max_offset_mm}")
            if self.max_rotation_deg is not None:
                R = c[:3, :3].T @ p[:3, :3]
                ang = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
                if ang > self.max_rotation_deg + 1e-9:
                    out.append(f"rotation from P0 {ang:.2f}° > max_rotation_deg "
                               f"{self.max_rotation_deg}")
        if self.box_min_mm is not None and self.box_max_mm is not None:
            lo = np.asarray(self.box_min_mm, dtype=float)
            hi = np.asarray(self.box_max_mm, dtype=float)
            if np.any(t < lo - 1e-9) or np.any(t > hi + 1e-9):
                out.append(f"position {np.round(t, 1).tolist()} mm outside workspace box "
                           f"{lo.tolist()}..{hi.tolist()}")
        return out

    def check_pose(self, pose: np.ndarray, what: str = "pose") -> None:
        """Raise ``SafetyError`` naming the pose and the limits it breaks."""
        v = self.violations(pose)
        if v:
            raise SafetyError(f"{what} refused: " + "; ".join(v))

    def check_speed(self, speed_mm_s: float, accel_mm_s2: float | None = None) -> None:
        """Raise ``SafetyError`` if a speed (mm/s) or acceleration (mm/s²) exceeds its cap."""
        if not (speed_mm_s > 0 and np.isfinite(speed_mm_s)):
            raise SafetyError(f"speed {speed_mm_s} mm/s is not a positive finite number")
        if self.max_speed_mm_s is not None and speed_mm_s > self.max_speed_mm_s + 1e-9:
            raise SafetyError(f"speed {speed_mm_s} mm/s > max_speed_mm_s {self.max_speed_mm_s}")
        if accel_mm_s2 is not None and self.max_accel_mm_s2 is not None \
                and accel_mm_s2 > self.max_accel_mm_s2 + 1e-9:
            raise SafetyError(f"acceleration {accel_mm_s2} mm/s² > max_accel_mm_s2 "
                              f"{self.max_accel_mm_s2}")


class Robot(_Device):
    """A robot arm. ``flange_pose()`` is base_from_flange 4×4 mm; ``move_to(pose, speed)``
    sends a linear move (speed in mm/s) after checking the safety envelope, and returns only
    when the controller reports the motion finished; ``stop()`` halts motion."""

    def __init__(self, envelope: Envelope | None = None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0) -> None:
        super().__init__()
        self.envelope = envelope or Envelope()
        self.speed_mm_s = float(speed_mm_s)
        self.accel_mm_s2 = float(accel_mm_s2)

    def flange_pose(self) -> np.ndarray:
        """Current base_from_flange, 4×4 mm, as reported by the controller."""
        if not self._opened:
            raise DeviceError(f"{self.name}: flange_pose() on a robot that is not open")
        return self._flange_pose()

    def move_to(self, pose: np.ndarray, speed_mm_s: float | None = None) -> None:
        """Move the flange linearly to ``pose`` (base_from_flange, 4×4 mm) at ``speed_mm_s``
        (default: the configured speed). Raises ``SafetyError`` before sending anything if the
        pose or speed is outside the envelope; ``RobotFault`` / ``DeviceTimeout`` if the
        controller does not report the motion finished."""
        if not self._opened:
            raise DeviceError(f"{self.name}: move_to() on a robot that is not open")
        speed = self.speed_mm_s if speed_mm_s is None else float(speed_mm_s)
        self.envelope.check_speed(speed, self.accel_mm_s2)
        self.envelope.check_pose(pose, "move_to target")
        self._move_to(np.asarray(pose, dtype=np.float64), speed)

    def stop(self) -> None:
        """Halt any motion (best effort; never raises on a closed robot)."""
        if self._opened:
            self._stop()

    @abstractmethod
    def _flange_pose(self) -> np.ndarray: ...

    @abstractmethod
    def _move_to(self, pose: np.ndarray, speed_mm_s: float) -> None: ...

    @abstractmethod
    def _stop(self) -> None: ...


# --- registry ----------------------------------------------------------------------------------

#: driver name -> "module:Class". A new device family is one folder plus one line here.
DRIVERS: dict[str, str] = {
    "ndi": "tmscal.drivers.ndi.tracker:NDITracker",
    "ur": "tmscal.drivers.ur.robot:URRobot",
    "denso": "tmscal.drivers.denso.robot:DensoRobot",
}


def driver_class(name: str) -> Callable[..., _Device]:
    """The driver class registered under ``name``; unknown names raise ``ConfigError`` listing
    the known ones; a driver whose module cannot be imported raises ``ConfigError`` saying why."""
    try:
        target = DRIVERS[name]
    except KeyError:
        raise ConfigError(f"unknown driver {name!r}; known drivers: "
                          f"{', '.join(sorted(DRIVERS))}") from None
    mod, _, cls = target.partition(":")
    try:
        return getattr(importlib.import_module(mod), cls)
    except ImportError as e:
        raise ConfigError(f"driver {name!r} cannot be loaded ({e}); is its extra installed? "
                          f"(e.g. pip install 'tmscal[{name}]')") from e


def wait_until(pred: Callable[[], bool], timeout_s: float, what: str,
               poll_s: float = 0.002) -> None:
    """Poll ``pred`` until true; raise ``DeviceTimeout`` naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise DeviceTimeout(f"timed out after {timeout_s:.1f} s waiting for {what}")
        time.sleep(poll_s)


__all__ = [
    "ToolState", "TrackerFrame", "Tracker", "Robot", "Envelope", "DRIVERS", "driver_class",
    "wait_until", "ConfigError", "ConnectionLost", "DeviceError", "DeviceTimeout",
    "ProtocolError", "RobotFault", "SafetyError", "SessionError", "TmscalError",
]
