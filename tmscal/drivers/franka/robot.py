"""Franka robots (FR3; Panda with a franky built against libfranka 0.9.x) through the ``franky``
client library (PyPI ``franky-control``, the ``franka`` extra), which speaks libfranka's network
protocol to the Franka Control Interface (FCI).

Frames and units: ``flange_pose()`` and ``move_to()`` take and return base_from_flange as a
4×4 matrix in mm; speeds are mm/s and accelerations mm/s². The controller reports and commands
the END-EFFECTOR pose ``O_T_EE`` (metres), which includes the end effector set in Desk
(``F_T_NE``) and the one set from a client (``NE_T_EE``); the driver converts every pose with
the ``F_T_EE`` of the same robot state (``frames.base_from_flange`` / ``frames.ee_target``), so
the end-effector setting never leaks into tmscal's flange poses (docs/devices.md, "Franka").

Motion: ``move_to`` sends one absolute ``CartesianMotion`` (franky plans it time-optimally with
Ruckig from the current state; the path is a straight line) with relative dynamics factors from
``frames.dynamics_factors``: cap / (√3 · per-axis limit), so neither the speed nor the
acceleration of the flange exceeds the configured caps in any direction. The motion runs
asynchronously and is waited for in slices, so ``stop()`` can halt it and ``timeout_s`` bounds
it.

Errors: franky's ``ControlException`` (a reflex or a motion error, e.g. "motion aborted by
reflex! [communication_constraints_violation]" when the 1 kHz loop is not held) and
``CommandException`` become ``RobotFault`` with the library's text; ``NetworkException``
becomes ``ConnectionLost``; anything else franky raises becomes ``DeviceError``. A robot in
Reflex mode (errors present) is recovered with ``recover_from_errors()`` only when the config
allows it (``robot.options: {auto_recover: true}``; default false): at open, before a move, and
after a reflex that aborted a move (the move still raises ``RobotFault``, so the acquisition
stops and ``--resume`` continues). Without it the fault names the errors and the fix.
"""

from __future__ import annotations

import importlib.metadata
import logging
import math
import re
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, MissingExtraError, RobotFault
from ...safety import AxisPath, AxisProfile, MotionLaw
from ...timing import Deadline
from ..base import Envelope, Robot
from .frames import MIN_FACTOR, base_from_flange, dynamics_factors, ee_target, matrix_m
from .settings import FrankaSettings

#: the options' defaults, declared once in FrankaSettings.OPTIONS
_OPT = FrankaSettings.defaults()

_T = TypeVar("_T")

log = logging.getLogger(__name__)

__all__ = ["FrankaRobot", "fault_from_exception", "arm_from_urdf", "COMMUNICATION_TEXT"]

_JOIN_SLICE_S = 0.05  # how long one wait for the running motion lasts before stop() is checked
#: the reflex franky/libfranka report when the 1 kHz control loop was not held
COMMUNICATION_TEXT = "communication_constraints_violation"
#: franky exception class names → the tmscal error they become
_FAULT_CLASSES = ("ControlException", "CommandException", "InvalidOperationException")
_LINK_CLASSES = ("NetworkException",)


def fault_from_exception(e: BaseException, what: str, host: str) -> DeviceError:
    """The tmscal error for an exception franky raised during ``what``: ``RobotFault`` for a
    reflex, motion or command error, ``ConnectionLost`` for a network error, ``DeviceError``
    otherwise; each carries the library's text (``.text``) and names the host."""
    name = type(e).__name__
    text = str(e).strip() or name
    msg = f"franka {host}: {what}: {text}"
    if name in _FAULT_CLASSES:
        hint = ""
        if COMMUNICATION_TEXT in text:
            hint = (" (the 1 kHz control loop was not held: use a real-time kernel and a direct "
                    "Ethernet link to the controller)")
        return RobotFault(msg + hint, text=name, device="franka")
    if name in _LINK_CLASSES:
        return ConnectionLost(msg, text=name, device="franka")
    if name == "IncompatibleVersionException":
        return DeviceError(msg + " (a Panda needs franky built against libfranka 0.9.x; see "
                           "docs/devices.md)", text=name, device="franka")
    if name == "RealtimeException":
        return DeviceError(msg + " (robot.options.realtime: true needs a real-time kernel and "
                           "real-time priority for this user; false runs without)", text=name,
                           device="franka")
    return DeviceError(msg, text=name, device="franka")


def _franky() -> Any:
    try:
        import franky
    except ImportError as e:  # pragma: no cover - the franka extra is missing
        raise MissingExtraError("driver 'franka'", "franka", str(e)) from e
    return franky


class FrankaRobot(Robot):
    """A Franka arm through ``franky``.

    Parameters
    ----------
    host:
        The FCI address (the robot's "Control" network address, not the arm's Desk address on
        a Panda). libfranka's ports are fixed (TCP 1337, UDP replies), so the driver takes no
        port.
    envelope, speed_mm_s, accel_mm_s2:
        Safety envelope and default linear speed (mm/s) and acceleration (mm/s²); see
        ``Robot``. They cap franky's relative dynamics (``frames.dynamics_factors``).
    auto_recover:
        False (default): a robot in Reflex mode raises ``RobotFault`` naming its errors.
        True: the driver calls ``recover_from_errors()`` (logged) before moving on.
    realtime:
        False (default): franky's ``RealtimeConfig.Ignore`` (no real-time scheduling needed,
        as in a simulator or a non-RT kernel). True: ``RealtimeConfig.Enforce``: connecting
        fails unless the process may run the control loop with real-time priority.
    timeout_s:
        Longest a single move may take (s) before ``DeviceTimeout`` (the motion is stopped).
    """

    name = "franka"

    def __init__(self, host: str, envelope: Envelope | None = None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0, auto_recover: bool = _OPT["auto_recover"],
                 realtime: bool = _OPT["realtime"], timeout_s: float = _OPT["timeout_s"]) -> None:
        super().__init__(envelope=envelope, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        if not host or not isinstance(host, str):
            raise ValueError("FrankaRobot: host must be a non-empty address")
        o = FrankaSettings.check_options("FrankaRobot", auto_recover=auto_recover,
                                         realtime=realtime, timeout_s=timeout_s)
        self.host = host
        self.auto_recover: bool = o["auto_recover"]
        self.realtime: bool = o["realtime"]
        self.timeout_s: float = o["timeout_s"]
        self._robot: Any = None
        self._identity: dict[str, Any] = {}
        self._halt = threading.Event()
        self._moving = threading.Event()

    # --- lifecycle ----------------------------------------------------------------------------

    def _open(self) -> None:
        franky = _franky()
        rt = franky.RealtimeConfig.Enforce if self.realtime else franky.RealtimeConfig.Ignore
        with self._translated("connect"):
            self._robot = franky.Robot(self.host, relative_dynamics_factor=1.0,
                                       realtime_config=rt)
            state = self._robot.state
        self._check_state("open")
        self._identity = self._convert(lambda: _identity_of(state), "end-effector frame")
        self._identity["arm"] = self._arm()
        log.info("franka %s: connected (flange to end effector F_T_EE: %s mm)", self.host,
                 [round(v, 1) for v in np.asarray(self._identity["F_T_EE_mm"])[:3, 3]])

    def _close(self) -> None:
        r, self._robot = self._robot, None
        if r is None:
            return
        try:
            if r.is_in_control:
                r.stop()
        except Exception as e:  # franky's own exception types: best effort at close
            log.warning("franka %s: stop at close failed: %s", self.host, e)

    def lock_address(self) -> str:
        """The FCI host (libfranka's ports are fixed): one tmscal per arm."""
        return self.host

    def identity(self) -> dict[str, Any]:
        """Driver, host, franky version, the end-effector frames at open (``F_T_NE_mm``,
        ``NE_T_EE_mm``, ``F_T_EE_mm``: 4×4 mm) and ``arm`` (``fr3`` or ``panda``: the robot
        the URDF the controller sends names, :func:`arm_from_urdf`; None when it sends none);
        nothing that changes while the robot moves (the joint angles: ``joint_positions()``),
        so a reconnect finds the same identity."""
        return {"driver": self.name, "host": self.host, **self._identity}

    def _arm(self) -> str | None:
        """The registered arm the controller's robot model names (libfranka's
        ``getRobotModel``, franky's ``Robot.model_urdf``); None when it cannot tell."""
        try:
            urdf = self._robot.model_urdf
        except Exception as e:  # franky's own types: an FCI without the command, an old build
            log.info("franka %s: the controller sends no robot model (%s); arm unknown",
                     self.host, e)
            return None
        return arm_from_urdf(urdf)

    def joint_positions(self) -> np.ndarray:
        """The seven joint angles now (rad), for the session or a check."""
        if not self._opened:
            raise DeviceError(f"{self.name}: joint_positions() on a robot that is not open")
        with self._translated("read the joint state"):
            return np.array([float(v) for v in self._robot.state.q], dtype=np.float64)

    # --- robot hooks --------------------------------------------------------------------------

    def _flange_pose(self) -> np.ndarray:
        with self._translated("read the robot state"):
            state = self._robot.state
        return self._convert(lambda: base_from_flange(state.O_T_EE, state.F_T_EE), "O_T_EE")

    def motion_law(self) -> MotionLaw:
        """franky plans a Cartesian motion of the end effector (``F_T_EE``, read now) per
        axis (x, y, z of the start frame and the rotation vector's components, each monotone,
        all ending together: not a straight line), each within the relative factor × its
        limit: the path is the hull of those axes (``AxisPath``) and the rotation turns at
        most at speed × rotation limit / translation limit (``AxisProfile``). The slowest it
        can be commanded: a factor of ``MIN_FACTOR``."""
        with self._translated("read the robot state and limits"):
            state = self._robot.state
            vlim = float(self._robot.translation_velocity_limit.get())
            alim = float(self._robot.translation_acceleration_limit.get())
            rvlim = float(self._robot.rotation_velocity_limit.get())
            ralim = float(self._robot.rotation_acceleration_limit.get())
        f_t_ee = self._convert(lambda: matrix_m(state.F_T_EE, "F_T_EE"), "F_T_EE").copy()
        f_t_ee[:3, 3] *= 1000.0
        return MotionLaw(AxisPath(f_t_ee), AxisProfile(
            1000.0 * vlim / rvlim, 1000.0 * alim / ralim,
            min_speed_mm_s=MIN_FACTOR * math.sqrt(3.0) * vlim * 1000.0,
            min_accel_mm_s2=MIN_FACTOR * math.sqrt(3.0) * alim * 1000.0,
            name="franky's Cartesian motion"))

    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        franky = _franky()
        self._check_state("move_to")
        with self._translated("prepare the motion"):
            state = self._robot.state
            vlim = float(self._robot.translation_velocity_limit.get())
            alim = float(self._robot.translation_acceleration_limit.get())
        target = self._convert(lambda: ee_target(pose, state.F_T_EE), "F_T_EE")
        try:
            fv, fa, fj = dynamics_factors(speed_mm_s, accel_mm_s2, vlim, alim)
        except ValueError as e:
            raise RobotFault(f"franka {self.host}: move_to refused: {e}",
                             device=self.name) from None
        log.debug("franka %s: CartesianMotion to O_T_EE %s m, factors v %.4f a %.4f",
                  self.host, target[:3, 3].tolist(), fv, fa)
        motion = franky.CartesianMotion(
            franky.Affine(target), franky.ReferenceType.Absolute,
            relative_dynamics_factor=franky.RelativeDynamicsFactor(fv, fa, fj))
        self._halt.clear()
        self._moving.set()
        try:
            with self._translated("move_to", recover=True):
                self._robot.move(motion, asynchronous=True)
                self._wait_motion()
        finally:
            self._moving.clear()

    def _wait_motion(self) -> None:
        """Wait for the running motion in slices; stop it on ``stop()`` (RobotFault) or after
        ``timeout_s`` (DeviceTimeout). franky raises the motion's own error from
        ``join_motion``."""
        deadline = Deadline(self.timeout_s)
        while not self._robot.join_motion(_JOIN_SLICE_S):
            if self._halt.is_set() or deadline.expired():
                self._robot.stop()
                try:  # the preempted motion ends with libfranka's "Move command preempted!"
                    self._robot.join_motion(5.0)
                except Exception as e:
                    log.debug("franka %s: after stop: %s", self.host, e)
                if self._halt.is_set():
                    raise RobotFault(f"franka {self.host}: move_to halted by stop()",
                                     device=self.name)
                raise DeviceTimeout(f"franka {self.host}: move_to did not finish within "
                                    f"{self.timeout_s:.1f} s (motion stopped)",
                                    device=self.name)

    def _stop(self) -> None:
        if self._robot is None:
            return
        if self._moving.is_set():  # the waiting move stops it and raises
            self._halt.set()
            return
        try:
            self._robot.stop()
        except Exception as e:  # franky's own exception types: best effort
            log.warning("franka %s: stop failed: %s", self.host, e)

    # --- helpers ------------------------------------------------------------------------------

    @contextmanager
    def _translated(self, what: str, recover: bool = False) -> Iterator[None]:
        """The one place franky's errors become tmscal's (``fault_from_exception``); with
        ``recover`` and ``auto_recover``, a fault is followed by ``recover_from_errors()``."""
        try:
            yield
        except DeviceError:
            raise
        except Exception as e:
            err = fault_from_exception(e, what, self.host)
            if recover and isinstance(err, RobotFault) and self.auto_recover:
                self._recover(what)
            raise err from e

    def _convert(self, fn: Callable[[], _T], what: str) -> _T:
        try:
            return fn()
        except ValueError as e:
            raise DeviceError(f"franka {self.host}: the controller reported an invalid {what}: "
                              f"{e}", device=self.name) from None

    def _recover(self, what: str) -> None:
        log.warning("franka %s: %s: calling recover_from_errors() (robot.options.auto_recover)",
                    self.host, what)
        try:
            ok = self._robot.recover_from_errors()
        except Exception as e:
            raise fault_from_exception(e, f"{what}: recover_from_errors", self.host) from e
        if ok is False:
            raise RobotFault(f"franka {self.host}: {what}: recover_from_errors() failed; clear "
                             "the error in Desk", device=self.name)

    def _check_state(self, what: str) -> None:
        """``RobotFault`` when the robot is user-stopped or in Reflex with errors (recovered
        instead when ``auto_recover``)."""
        with self._translated(f"{what}: read the robot state"):
            state = self._robot.state
            mode = getattr(state.robot_mode, "name", str(state.robot_mode))
            errors = str(state.current_errors)
            has_errors = bool(self._robot.has_errors)
        if mode == "UserStopped":
            raise RobotFault(f"franka {self.host}: {what} refused: the user stop is pressed: "
                             "release it (the external activation device), then resume",
                             text=mode, device=self.name)
        if mode != "Reflex" and not has_errors:
            return
        if self.auto_recover:
            self._recover(what)
            return
        raise RobotFault(f"franka {self.host}: {what} refused: robot in {mode} with errors "
                         f"{errors}: clear them in Desk, or allow recovery with robot.options: "
                         "{auto_recover: true}", text=mode, device=self.name)


_ROBOT_NAME = re.compile(r"<robot\b[^>]*?\bname\s*=\s*[\"']([^\"']{1,100})[\"']")


def arm_from_urdf(urdf: Any) -> str | None:
    """The registered Franka arm (``fr3``, ``panda``) the robot description ``urdf`` (the
    text libfranka's ``getRobotModel`` returns) names in its ``<robot name="…">``; None when
    it names none of them. An FR3's controller sends its own URDF (``<robot name="fr3">``;
    franky-sim sends its FR3's); a controller that sends none leaves the arm unknown."""
    from ...calib.kinematics import find_arm

    m = _ROBOT_NAME.search(urdf) if isinstance(urdf, str) else None
    return None if m is None else find_arm("Franka", m.group(1))


def _identity_of(state: Any) -> dict[str, Any]:
    """The identity fields read from a franky ``RobotState`` at open (poses 4×4 in mm)."""
    def mm(v: Any, what: str) -> list[list[float]]:
        m = matrix_m(v, what).copy()
        m[:3, 3] *= 1000.0
        return m.round(6).tolist()
    try:
        version = importlib.metadata.version("franky-control")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - a source build
        version = None
    return {"franky_version": version,
            "F_T_NE_mm": mm(state.F_T_NE, "F_T_NE"), "NE_T_EE_mm": mm(state.NE_T_EE, "NE_T_EE"),
            "F_T_EE_mm": mm(state.F_T_EE, "F_T_EE")}
