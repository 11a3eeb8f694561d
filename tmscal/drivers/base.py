"""Device contracts shared by every driver: ``Tracker``, ``Robot``, ``ForceTorque``,
``TrackerFrame``, the safety ``Envelope``, and (re-exported) the driver registry and the
typed errors.

A driver subclasses ``Tracker`` or ``Robot`` and fills the private hooks (``_open``,
``_close``, ``_read`` / ``_flange_pose``, ``_move_to``, ``_stop``); the base class owns the
public behaviour: the context-manager lifecycle (``close()`` is safe twice and after a failed
``open()``), and, for robots, the safety check that runs before every motion is sent.

Frames and units: tracker poses are ``tracker_from_<tool>`` 4×4 in mm; robot poses are
``base_from_flange`` 4×4 in mm; speeds are mm/s; wrenches are [Fx, Fy, Fz N, Tx, Ty, Tz
N·m] in the force-torque sensor's frame.
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
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
from ..registry import DriverSpec, driver_class  # noqa: F401  (re-exported: the registry)
from ..timing import Deadline
from .robot_lock import RobotLock

log = logging.getLogger(__name__)


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
    faster than ``frame_rate_hz``); ``distinct_frames()`` yields each frame once."""

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

    def distinct_frames(self, limit: int | None = None, timeout_s: float | None = None, *,
                        max_reads: int | None = None,
                        stall_s: float | None = None) -> Iterator[TrackerFrame]:
        """Yield each new frame once: ``read()`` repeats a frame number when polled faster
        than ``frame_rate_hz``, and a repeat is skipped. Stops after ``limit`` distinct frames
        (None: when the caller stops iterating).

        Bounds, each off when None: ``timeout_s`` seconds for the whole iteration (time the
        caller spends between frames counts), ``max_reads`` calls of ``read()``, ``stall_s``
        seconds without a new frame. Reaching one raises ``DeviceTimeout`` naming how many
        distinct frames arrived in how many reads. A frame number is remembered for the last
        ``_SEEN_WINDOW`` distinct frames (a counter that wraps is seen anew after that)."""
        total, stall = Deadline(timeout_s), Deadline(stall_s)
        seen: set[int] = set()
        order: deque[int] = deque()
        reads = distinct = 0
        while limit is None or distinct < limit:
            if reads:
                self._check_frame_bounds(distinct, limit, reads, max_reads, total, stall)
            fr = self.read()
            reads += 1
            if fr.frame in seen:
                continue
            seen.add(fr.frame)
            order.append(fr.frame)
            if len(order) > _SEEN_WINDOW:
                seen.discard(order.popleft())
            distinct += 1
            stall.restart()
            yield fr

    def _check_frame_bounds(self, distinct: int, limit: int | None, reads: int,
                            max_reads: int | None, total: Deadline, stall: Deadline) -> None:
        """``DeviceTimeout`` once a bound of ``distinct_frames`` is reached."""
        if total.expired():
            why = f"{total.timeout_s:g} s"
        elif stall.expired():
            why = f"no new frame for {stall.timeout_s:g} s: frame counter stuck?"
        elif max_reads is not None and reads >= max_reads:
            why = "read limit: frame counter stuck?"
        else:
            return
        of = "" if limit is None else f" of {limit}"
        raise DeviceTimeout(f"{self.name}: tracker delivered only {distinct} distinct frames"
                            f"{of} in {reads} reads ({why})", device=self.name)


#: how many recent distinct frame numbers ``Tracker.distinct_frames`` remembers
_SEEN_WINDOW = 4096


def _limit(name: str, value: Any) -> float | None:
    """A positive finite limit (or None); anything else raises ValueError naming it."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"Envelope.{name}: expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        raise ValueError(f"Envelope.{name}: {value!r} is too large") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"Envelope.{name}: expected a finite number > 0, got {value!r}")
    return v


def _points(name: str, value: Any, k: int | None = None) -> np.ndarray:
    """A (k, 3) finite float array, read-only; anything else raises ValueError naming it."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as e:
        raise ValueError(f"Envelope.{name}: expected [x, y, z] points in mm ({e})") from None
    if a.ndim == 1 and k == 1:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3 or (k is not None and a.shape[0] != k):
        raise ValueError(f"Envelope.{name}: expected [x, y, z] points in mm, got shape "
                         f"{a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"Envelope.{name}: every coordinate must be finite, got "
                         f"{a.tolist()}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Envelope:
    """Safety envelope for robot motion. Poses are base_from_flange, mm.

    ``center`` (P0, base_from_flange 4×4 mm) with ``max_offset_mm`` (distance of the flange
    origin from P0) and ``max_rotation_deg`` (rotation angle away from P0, degrees);
    ``box_min_mm``/``box_max_mm`` a workspace box in the robot base frame (mm) that the flange
    origin and every one of ``tool_points_mm`` (k×3 points in the FLANGE frame, mm: the coil
    centre, points on the coil's rim) must stay inside; ``max_speed_mm_s`` and
    ``max_accel_mm_s2`` caps.

    Any limit left None is not checked. Limits that are given are validated when the envelope
    is built (ValueError for NaN, ±inf, non-positive caps, a box with min ≥ max on an axis),
    and ``violations`` fails closed: a comparison that cannot be made counts as a violation.
    """

    center: np.ndarray | None = None
    max_offset_mm: float | None = None
    max_rotation_deg: float | None = None
    box_min_mm: tuple[float, float, float] | None = None
    box_max_mm: tuple[float, float, float] | None = None
    max_speed_mm_s: float | None = None
    max_accel_mm_s2: float | None = None
    tool_points_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        put = object.__setattr__
        for name in ("max_offset_mm", "max_rotation_deg", "max_speed_mm_s", "max_accel_mm_s2"):
            put(self, name, _limit(name, getattr(self, name)))
        if self.center is not None:
            c = np.array(self.center, dtype=np.float64)
            if c.shape != (4, 4) or not np.isfinite(c).all():
                raise ValueError(f"Envelope.center: expected a finite 4×4 pose (mm), got shape "
                                 f"{c.shape}")
            c.setflags(write=False)
            put(self, "center", c)
        if (self.box_min_mm is None) != (self.box_max_mm is None):
            raise ValueError("Envelope: give both box_min_mm and box_max_mm, or neither")
        if self.box_min_mm is not None:
            lo = _points("box_min_mm", self.box_min_mm, 1)[0]
            hi = _points("box_max_mm", self.box_max_mm, 1)[0]
            if not (lo < hi).all():
                raise ValueError(f"Envelope: box_min_mm {lo.tolist()} must be below box_max_mm "
                                 f"{hi.tolist()} on every axis")
            put(self, "box_min_mm", tuple(float(x) for x in lo))
            put(self, "box_max_mm", tuple(float(x) for x in hi))
        if self.tool_points_mm is not None:
            put(self, "tool_points_mm", _points("tool_points_mm", self.tool_points_mm))

    def violations(self, pose: np.ndarray) -> list[str]:
        """Every limit this base_from_flange pose (mm) breaks, as readable strings. A pose that
        is not a finite rigid 4×4 is one violation; a NaN comparison is a violation."""
        from ..geometry import angle_between, check_pose

        try:
            p = check_pose(pose, "pose")
        except (ValueError, TypeError) as e:
            return [f"pose is not a finite rigid 4×4 matrix ({e})"]
        out: list[str] = []
        t = p[:3, 3]
        if self.center is not None:
            c = self.center
            if self.max_offset_mm is not None:
                d = float(np.linalg.norm(t - c[:3, 3]))
                if not d <= self.max_offset_mm + 1e-9:
                    out.append(f"offset from P0 {d:.1f} mm > max_offset_mm {self.max_offset_mm}")
            if self.max_rotation_deg is not None:
                ang = float(np.degrees(angle_between(c, p)))
                if not ang <= self.max_rotation_deg + 1e-9:
                    out.append(f"rotation from P0 {ang:.2f}° > max_rotation_deg "
                               f"{self.max_rotation_deg}")
        if self.box_min_mm is not None and self.box_max_mm is not None:
            lo = np.asarray(self.box_min_mm, dtype=np.float64)
            hi = np.asarray(self.box_max_mm, dtype=np.float64)
            pts = [("flange origin", t)]
            if self.tool_points_mm is not None:
                base = self.tool_points_mm @ p[:3, :3].T + t
                pts += [(f"tool point {i} {np.round(q, 1).tolist()} (flange frame)", b)
                        for i, (q, b) in enumerate(zip(self.tool_points_mm, base))]
            for what, b in pts:
                if not (np.all(b >= lo - 1e-9) and np.all(b <= hi + 1e-9)):
                    out.append(f"{what} at {np.round(b, 1).tolist()} mm outside workspace box "
                               f"{lo.tolist()}..{hi.tolist()}")
        return out

    def check_pose(self, pose: np.ndarray, what: str = "pose") -> None:
        """Raise ``SafetyError`` naming the pose and the limits it breaks."""
        v = self.violations(pose)
        if v:
            raise SafetyError(f"{what} refused: " + "; ".join(v))

    def check_speed(self, speed_mm_s: float, accel_mm_s2: float | None = None) -> None:
        """Raise ``SafetyError`` if a speed (mm/s) or acceleration (mm/s²) is not a positive
        finite number or exceeds its cap."""
        if not _positive_finite(speed_mm_s):
            raise SafetyError(f"speed {speed_mm_s!r} mm/s is not a positive finite number")
        if self.max_speed_mm_s is not None and not speed_mm_s <= self.max_speed_mm_s + 1e-9:
            raise SafetyError(f"speed {speed_mm_s} mm/s > max_speed_mm_s {self.max_speed_mm_s}")
        if accel_mm_s2 is None:
            return
        if not _positive_finite(accel_mm_s2):
            raise SafetyError(f"acceleration {accel_mm_s2!r} mm/s² is not a positive finite "
                              "number")
        if self.max_accel_mm_s2 is not None and not accel_mm_s2 <= self.max_accel_mm_s2 + 1e-9:
            raise SafetyError(f"acceleration {accel_mm_s2} mm/s² > max_accel_mm_s2 "
                              f"{self.max_accel_mm_s2}")


def _positive_finite(x: Any) -> bool:
    """True for a real number (not bool) that is finite and > 0."""
    if isinstance(x, bool) or not isinstance(x, int | float | np.integer | np.floating):
        return False
    try:
        return math.isfinite(float(x)) and float(x) > 0
    except OverflowError:
        return False


class Robot(_Device):
    """A robot arm. ``flange_pose()`` is base_from_flange 4×4 mm; ``move_to(pose, speed)``
    sends a linear move (speed in mm/s) after checking the safety envelope, and returns only
    when the controller reports the motion finished; ``stop()`` halts motion.

    One tmscal process per robot: ``open()`` first takes the lock of the robot's address
    (:meth:`lock_address`, :class:`~tmscal.drivers.robot_lock.RobotLock`), so a second opener
    (another ``tmscal acquire`` or ``tmscal robot``, or a second open robot on the same address
    in this process) gets ``SafetyError`` naming the address and the holder's pid before
    anything is sent; ``close()`` releases it, and the kernel does when the process ends."""

    def __init__(self, envelope: Envelope | None = None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0) -> None:
        super().__init__()
        self.envelope = envelope or Envelope()
        self.speed_mm_s = float(speed_mm_s)
        self.accel_mm_s2 = float(accel_mm_s2)
        self._robot_lock: RobotLock | None = None

    def lock_address(self) -> str | None:
        """The address that names the physical robot for the one-process-per-robot lock
        (``host``, ``host:port`` …); None (the default: a simulated or test robot) takes no
        lock. Drivers of real robots override it."""
        return None

    def open(self) -> Robot:
        """Take the robot's lock (``SafetyError`` when another tmscal holds it), then connect
        and initialise; on failure the lock is released and whatever was opened closed."""
        if self._opened:
            return self
        address = self.lock_address()
        lock = RobotLock(self.name, address).acquire() if address else None
        try:
            super().open()
        except BaseException:
            if lock is not None:
                lock.release()
            raise
        self._robot_lock = lock
        return self

    def close(self) -> None:
        """Stop and disconnect, then release the robot's lock; safe to call twice."""
        try:
            super().close()
        finally:
            lock, self._robot_lock = self._robot_lock, None
            if lock is not None:
                lock.release()

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
        speed = self.speed_mm_s if speed_mm_s is None else speed_mm_s
        self.envelope.check_speed(speed, self.accel_mm_s2)
        try:  # the very array that was checked is the one sent (a private copy)
            target = np.array(pose, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise SafetyError(f"move_to target refused: not a 4×4 pose ({e})") from None
        self.envelope.check_pose(target, "move_to target")
        self._move_to(target, float(speed))

    def joint_positions(self) -> np.ndarray:
        """The joint angles now (rad, one per axis), for the session (``joints_rad``) and
        kinematic self-calibration. Drivers that can read them override this; the default
        raises NotImplementedError naming the driver."""
        raise NotImplementedError(f"{self.name}: this robot driver does not report joint "
                                  "angles")

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


class ForceTorque(_Device):
    """A six-axis force-torque sensor. ``read(n)`` returns ``n`` consecutive samples as an
    (n, 6) float64 array [Fx, Fy, Fz (N), Tx, Ty, Tz (N·m)] in the SENSOR frame (the frame
    the sensor's calibration defines; for a wrist sensor, fixed to the flange). The driver
    converts counts to units at its edge and raises ``DeviceError`` subclasses, never bare
    exceptions; ``close()`` stops any stream it started (docs/devices.md)."""

    def read(self, n: int = 1) -> np.ndarray:
        """``n`` ≥ 1 samples, (n, 6): N and N·m, sensor frame."""
        if not self._opened:
            raise DeviceError(f"{self.name}: read() on a force-torque sensor that is not open")
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"{self.name}: read(n) needs an integer n ≥ 1, got {n!r}")
        out = np.asarray(self._read(int(n)), dtype=np.float64)
        if out.shape != (n, 6):  # pragma: no cover - a driver bug
            raise DeviceError(f"{self.name}: driver returned shape {out.shape}, expected "
                              f"({n}, 6)")
        return out

    @abstractmethod
    def _read(self, n: int) -> np.ndarray: ...


__all__ = [
    "ToolState", "TrackerFrame", "Tracker", "Robot", "ForceTorque", "Envelope", "DriverSpec",
    "driver_class",
    "ConfigError", "ConnectionLost", "DeviceError", "DeviceTimeout",
    "ProtocolError", "RobotFault", "SafetyError", "SessionError", "TmscalError",
]
