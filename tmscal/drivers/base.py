"""Device contracts shared by every driver: ``Tracker``, ``Robot``, ``ForceTorque``,
``TrackerFrame``, the safety ``Envelope``, and (re-exported) the driver registry and the
typed errors.

A driver subclasses ``Tracker`` or ``Robot`` and fills the private hooks (``_open``,
``_close``, ``_read`` / ``_flange_pose``, ``_move_to``, ``_stop``); the base class owns the
public behaviour: the context-manager lifecycle (``close()`` is safe twice and after a failed
``open()``), and, for robots, the safety check that runs before every motion is sent.

The safety ``Envelope`` lives in :mod:`tmscal.safety` (with the checks of a whole move) and is
re-exported here.

Frames and units: tracker poses are ``tracker_from_<tool>`` 4×4 in mm; robot poses are
``base_from_flange`` 4×4 in mm; speeds are mm/s; wrenches are [Fx, Fy, Fz N, Tx, Ty, Tz
N·m] in the force-torque sensor's frame.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Generator, Mapping, Sequence
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
from ..safety import DEFAULT_LAW, MotionLaw, Route, plan_move
from ..safety import Envelope as Envelope  # re-exported: ``from ..drivers.base import Envelope``
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
    #: False for a device whose time is not the wall clock (the in-process ``sim`` drivers: a
    #: move ends at once, frames come as fast as they are read), so that checks of timing
    #: (the acceptance suite's frame rate and stop mid-move) are not judged on it
    real_time: bool = True

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
                        stall_s: float | None = None) -> Generator[TrackerFrame, None, None]:
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


class Robot(_Device):
    """A robot arm. ``flange_pose()`` is base_from_flange 4×4 mm; ``move_to(pose, speed)``
    moves the flange there after checking the whole way against the safety envelope, and
    returns only when the controller reports the motion finished; ``stop()`` halts motion.

    A driver declares how its controller executes a Cartesian move (``motion_law``: the frame
    it interpolates, the path and how it times a move that also turns) and fills
    ``_move_to(pose, speed_mm_s, accel_mm_s2)``, which sends ONE motion; the base class plans
    the move (:func:`tmscal.safety.plan_move`) and sends its legs.

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

    def motion_law(self) -> MotionLaw:
        """How this controller executes one Cartesian move (:class:`tmscal.safety.MotionLaw`):
        the frame it moves, its path, how it times a move that turns. The default is the most
        cautious law (a straight move of the flange whose rotation only its translation
        times); drivers override it with their controller's."""
        return DEFAULT_LAW

    def move_to(self, pose: np.ndarray, speed_mm_s: float | None = None) -> Route:
        """Move the flange to ``pose`` (base_from_flange, 4×4 mm) at most at ``speed_mm_s``
        (default: the configured speed) and the configured acceleration.

        Before anything is sent: the speed and acceleration against the caps, the target
        against the envelope; then the robot's pose now (one read of the controller) and the
        whole path the controller will take from there (:func:`tmscal.safety.plan_move`): the
        flange origin and every tool point in the box, the offset and rotation from P0, all
        the way. A path that leaves the envelope is split through P0 (translate, turn,
        translate), or refused. Each leg's speed and acceleration are lowered so that every
        tool point keeps under the caps. Raises ``SafetyError`` (nothing sent) when refused;
        ``RobotFault`` / ``DeviceTimeout`` if the controller does not report a leg finished
        (the later legs are not sent). Returns the :class:`tmscal.safety.Route` sent."""
        if not self._opened:
            raise DeviceError(f"{self.name}: move_to() on a robot that is not open")
        speed = self.speed_mm_s if speed_mm_s is None else speed_mm_s
        self.envelope.check_speed(speed, self.accel_mm_s2)
        try:  # the very array that was checked is the one sent (a private copy)
            target = np.array(pose, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise SafetyError(f"move_to target refused: not a 4×4 pose ({e})") from None
        self.envelope.check_pose(target, "move_to target")
        start = self.flange_pose()
        route = plan_move(self.envelope, start, target, self.motion_law(), float(speed),
                          self.accel_mm_s2, f"{self.name} move")
        if route.split:
            log.info("%s: the straight move leaves the envelope (%s); going through P0 in %d "
                     "legs", self.name, route.why, len(route.legs))
        for leg in route.legs:
            self._move_to(leg.target, leg.speed_mm_s, leg.accel_mm_s2)
        return route

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
    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        """Send ONE motion of the flange to ``pose`` (base_from_flange 4×4 mm) at
        ``speed_mm_s`` and ``accel_mm_s2`` as the controller's own move (the one
        ``motion_law`` describes); return when the controller reports it finished."""

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
    "ToolState", "TrackerFrame", "Tracker", "Robot", "ForceTorque", "Envelope", "MotionLaw",
    "Route", "DriverSpec", "driver_class",
    "ConfigError", "ConnectionLost", "DeviceError", "DeviceTimeout",
    "ProtocolError", "RobotFault", "SafetyError", "SessionError", "TmscalError",
]
