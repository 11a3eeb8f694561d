"""DENSO RC8 / RC8A / COBOTTA robot over b-CAP (TCP, default port 5007).

Frames and units: poses are base_from_flange 4×4 in mm (the controller's P-type "work"
coordinates with no tool and work offset selected: x, y, z in mm, rx, ry, rz in degrees,
converted only through ``tmscal.geometry``); speeds in mm/s, accelerations in mm/s².

Session (as DENSO's own denso_robot_ros opens one): Service_Start (``,WDT=<ms>`` if a
watchdog is set) → Controller_Connect → Controller_GetRobot → ``Controller_Execute
ClearError`` (and ``ManualReset`` with ``manual_reset=True``, for a COBOTTA) → TakeArm →
ExtSpeed → Motor on; then a second connection for Robot_Halt (:mod:`.halt`). Moves are
blocking ``Robot_Move`` comp 2 (MOVE L) with the pose as a VARIANT array
``[[x, y, z, rx, ry, rz, fig], "P", "@E"]`` (fig −1: the controller chooses the arm
configuration; ``@E``: the reply comes when the arm has reached the target and settled, as in
DENSO's value-move sample, not ``@P``/``@0``, which may reply while it still moves) and the
option ``SPEED=<percent>``. Close (best effort): the halt connection, then Motor off, GiveArm,
Robot_Release, Controller_Disconnect, Service_Stop. See ``docs/devices.md``.

Speed and acceleration (DENSO's RC8 manuals: the controller scales motion by percentages).
The real speed is SPEED × ExtSpeed of the arm's maximum, the real acceleration (and
deceleration) internal ACCEL × external accel. TakeArm (keep 0) resets the internal values to
100 %, and ``open`` sends ``ExtSpeed [ext_speed_percent, accel %, decel %]`` with

* SPEED % = ``speed_mm_s / max_linear_speed_mm_s × 100`` per move (:func:`speed_option`),
* accel % = decel % = ``accel_mm_s2 / max_linear_accel_mm_s2 × 100`` (:func:`accel_percent`,
  the smaller of the configured acceleration and the envelope's cap),

each rounded DOWN to 0.01 %, so the arm is never commanded faster or harder than configured
as long as ``max_linear_speed_mm_s`` / ``max_linear_accel_mm_s2`` are not below what the arm
reaches at 100 %. Overestimating them only makes the motion gentler.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ...errors import ConnectionLost, DeviceError, ProtocolError
from ...geometry import denso_p_from_matrix, matrix_from_denso_p
from ...safety import LinearPath, MotionLaw, SharedProfile
from ..base import Envelope, Robot
from ..robot_lock import host_port
from .arm import denso_arm
from .client import DEFAULT_PORT, BCAPClient, close_down
from .halt import HaltLink
from .settings import DensoSettings
from .variant import to_variant

log = logging.getLogger(__name__)

#: the options' defaults, declared once in DensoSettings.OPTIONS
_OPT = DensoSettings.defaults()

#: Default ``max_linear_accel_mm_s2``: an assumed upper bound (≈ 2 g) on the linear
#: acceleration DENSO's 6-axis arms reach at 100 %; deliberately high so that the percentage
#: derived from it errs on the gentle side. Set the arm's own figure (CHECK at the rig).
DEFAULT_MAX_LINEAR_ACCEL_MM_S2: float = _OPT["max_linear_accel_mm_s2"]


def _positive(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def _percent_down(value: float, full_scale: float) -> float:
    """``value / full_scale × 100`` rounded DOWN to 0.01 and capped at 100."""
    return min(math.floor(10000.0 * value / full_scale + 1e-9) / 100.0, 100.0)


def _pct_text(pct: float) -> str:
    return f"{pct:.2f}".rstrip("0").rstrip(".")


def speed_option(speed_mm_s: float, max_linear_speed_mm_s: float) -> str:
    """The Robot_Move option ``"SPEED=<percent>"`` for a linear speed in mm/s, percent of
    ``max_linear_speed_mm_s`` rounded DOWN to 0.01 (never faster than asked) and clamped to
    [0.01, 100]. Raises ``ValueError`` for a non-finite or non-positive argument."""
    speed = _positive("speed_mm_s", speed_mm_s)
    full = _positive("max_linear_speed_mm_s", max_linear_speed_mm_s)
    pct = max(_percent_down(speed, full), 0.01)
    return f"SPEED={_pct_text(pct)}"


def accel_percent(accel_mm_s2: float, max_linear_accel_mm_s2: float) -> float:
    """The controller's acceleration percentage for a linear acceleration in mm/s²: percent of
    ``max_linear_accel_mm_s2`` rounded DOWN to 0.01 and capped at 100, so the arm is never
    commanded above ``accel_mm_s2``. Raises ``ValueError`` for a non-finite or non-positive
    argument, or an acceleration below 0.01 % (which no percentage can express without
    exceeding it)."""
    accel = _positive("accel_mm_s2", accel_mm_s2)
    full = _positive("max_linear_accel_mm_s2", max_linear_accel_mm_s2)
    pct = _percent_down(accel, full)
    if pct < 0.01:
        raise ValueError(f"accel_mm_s2 {accel:g} is below 0.01 % of max_linear_accel_mm_s2 "
                         f"{full:g}: the controller cannot be commanded that gently")
    return pct


class DensoRobot(Robot):
    """A DENSO robot driven over b-CAP; see the module doc for the command sequence.

    ``host``/``port``: the controller (RC8 default port 5007). ``envelope``, ``speed_mm_s``,
    ``accel_mm_s2``: as in :class:`~tmscal.drivers.base.Robot`. ``max_linear_speed_mm_s``:
    the linear speed (mm/s) that SPEED=100 means on this arm. ``max_linear_accel_mm_s2``: the
    linear acceleration (mm/s²) that 100 % acceleration means (default
    :data:`DEFAULT_MAX_LINEAR_ACCEL_MM_S2`). ``ext_speed_percent``: the speed part of the
    ExtSpeed sent at open (default 100: the SPEED option alone sets the speed; lower it to slow
    every move further); it replaces whatever external speed the pendant or another program
    left on the controller. ``manual_reset``: also send ``ManualReset`` after ClearError at
    open (a COBOTTA's safety-state reset; an RC8/RC8A needs only ClearError). ``halt_timeout_s``:
    the bound on one Robot_Halt over the halt connection, (re)connect included (s; keep-alives
    do not extend it). ``provider``/``machine``: the CAO provider (``"CaoProv.DENSO.VRC9"``
    for RC9) and its machine argument. ``robot_name``: the robot object ("Arm").
    ``timeout_s``: the longest wait for any reply (s): a move's wait is re-armed by each
    S_EXECUTING keep-alive, any other request's is one deadline that keep-alives cannot
    extend (Service_Start included). ``watchdog_ms``: WDT for Service_Start (None: no
    keep-alives). ``fig``: the figure code sent with every pose.
    """

    name = "denso"

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 envelope: Envelope | None = None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0,
                 max_linear_speed_mm_s: float = _OPT["max_linear_speed_mm_s"],
                 max_linear_accel_mm_s2: float = _OPT["max_linear_accel_mm_s2"],
                 ext_speed_percent: float = _OPT["ext_speed_percent"],
                 provider: str = _OPT["provider"], machine: str = _OPT["machine"],
                 robot_name: str = _OPT["robot_name"], timeout_s: float = _OPT["timeout_s"],
                 watchdog_ms: int | None = _OPT["watchdog_ms"], fig: int = _OPT["fig"],
                 manual_reset: bool = _OPT["manual_reset"],
                 halt_timeout_s: float = _OPT["halt_timeout_s"]) -> None:
        super().__init__(envelope=envelope, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        _positive("speed_mm_s", speed_mm_s)
        o = DensoSettings.check_options(
            "DensoRobot", max_linear_speed_mm_s=max_linear_speed_mm_s,
            max_linear_accel_mm_s2=max_linear_accel_mm_s2, ext_speed_percent=ext_speed_percent,
            provider=provider, machine=machine, robot_name=robot_name, timeout_s=timeout_s,
            watchdog_ms=watchdog_ms, fig=fig, manual_reset=manual_reset,
            halt_timeout_s=halt_timeout_s)
        self.max_linear_speed_mm_s: float = o["max_linear_speed_mm_s"]
        self.max_linear_accel_mm_s2: float = o["max_linear_accel_mm_s2"]
        accel_percent(accel_mm_s2, self.max_linear_accel_mm_s2)  # refuses bad values now
        self.ext_speed_percent: float = o["ext_speed_percent"]
        self.host = host
        self.port = int(port)
        self.provider: str = o["provider"]
        self.machine: str = o["machine"]
        self.robot_name: str = o["robot_name"]
        self.timeout_s: float = o["timeout_s"]
        self.watchdog_ms: int | None = o["watchdog_ms"]
        self.fig: int = o["fig"]
        self.manual_reset: bool = o["manual_reset"]
        self.halt_timeout_s: float = o["halt_timeout_s"]
        self._halt: HaltLink | None = None
        self._client: BCAPClient | None = None
        self._ctrl: int | None = None
        self._robot: int | None = None
        self._service = False
        self._arm = False
        self._motor = False
        self._controller_info: dict[str, Any] = {}
        self._type_name: str | None = None
        self._ext_accel_pct: float | None = None   # the ExtSpeed accel % sent at open

    @property
    def client(self) -> BCAPClient:
        if self._client is None:
            raise DeviceError(f"{self.name}: not connected", device=self.name)
        return self._client

    def _open(self) -> None:
        c = BCAPClient(self.host, self.port, timeout_s=self.timeout_s).connect()
        self._client = c
        c.service_start(f",WDT={int(self.watchdog_ms)}" if self.watchdog_ms else "")
        self._service = True
        self._ctrl = c.controller_connect("", self.provider, self.machine, "")
        self._robot = c.controller_get_robot(self._ctrl, self.robot_name, "")
        self._controller_info = self._read_controller_info()
        self._type_name = self._read_type_name()
        self._clear_errors()
        c.take_arm(self._robot)
        self._arm = True
        accel = self.accel_percent()
        c.ext_speed(self._robot, self.ext_speed_percent, accel, accel)
        self._ext_accel_pct = accel
        log.info("DENSO ExtSpeed %s %%, accel = decel = %s %% of %g mm/s²",
                 _pct_text(self.ext_speed_percent), _pct_text(accel),
                 self.max_linear_accel_mm_s2)
        c.motor(self._robot, True)
        self._motor = True
        self._halt = HaltLink(self.host, self.port, self.provider, self.machine,
                              self.robot_name, self.halt_timeout_s).open()
        log.info("DENSO robot %r on %s:%d ready (motor on, halt connection open)",
                 self.robot_name, self.host, self.port)

    def _clear_errors(self) -> None:
        """ClearError (and ManualReset when asked) before TakeArm, as DENSO's denso_robot_ros
        does: an error latched on the controller would refuse TakeArm and Motor. A failure
        raises (the controller cannot be cleared from here: see the pendant)."""
        assert self._client is not None and self._ctrl is not None
        self._client.controller_execute(self._ctrl, "ClearError")
        if self.manual_reset:
            self._client.controller_execute(self._ctrl, "ManualReset")

    def accel_percent(self) -> float:
        """The acceleration (= deceleration) percentage sent with ExtSpeed: the smaller of
        ``accel_mm_s2`` and the envelope's ``max_accel_mm_s2`` (mm/s²) as a percentage of
        ``max_linear_accel_mm_s2``, rounded down (:func:`accel_percent`)."""
        a = self.accel_mm_s2
        cap = self.envelope.max_accel_mm_s2
        if cap is not None and cap < a:
            a = cap
        return accel_percent(a, self.max_linear_accel_mm_s2)

    def _read_controller_info(self) -> dict[str, Any]:
        """Controller variables that identify it (best effort: missing ones are skipped)."""
        info: dict[str, Any] = {}
        assert self._client is not None and self._ctrl is not None
        for var in ("@VERSION",):
            try:
                h = self._client.controller_get_variable(self._ctrl, var, "")
                try:
                    info[var.lstrip("@").lower()] = self._client.variable_get_value(h)
                finally:
                    self._client.variable_release(h)
            except DeviceError as e:
                log.debug("DENSO controller variable %s not readable: %s", var, e)
        return info

    def _read_type_name(self) -> str | None:
        """The robot's ``@TYPE_NAME`` (best effort: None when it cannot be read)."""
        assert self._client is not None and self._robot is not None
        try:
            h = self._client.robot_get_variable(self._robot, "@TYPE_NAME", "")
            try:
                v = self._client.variable_get_value(h)
            finally:
                self._client.variable_release(h)
        except DeviceError as e:
            log.debug("DENSO robot variable @TYPE_NAME not readable: %s", e)
            return None
        return v if isinstance(v, str) else None

    def _close(self) -> None:
        halt, self._halt = self._halt, None
        if halt is not None:
            halt.close()
        c = self._client
        if c is None:
            return
        steps: list[tuple[str, Any]] = []
        if self._robot is not None:
            r = self._robot
            if self._motor:  # motor off while the arm is still held, then give it back
                steps.append(("Motor off", lambda: c.motor(r, False)))
            if self._arm:
                steps.append(("GiveArm", lambda: c.give_arm(r)))
            steps.append(("Robot_Release", lambda: c.robot_release(r)))
        if self._ctrl is not None:
            h = self._ctrl
            steps.append(("Controller_Disconnect", lambda: c.controller_disconnect(h)))
        if self._service:
            steps.append(("Service_Stop", c.service_stop))
        close_down(c, steps, "DENSO close")
        self._client = None
        self._robot = self._ctrl = None
        self._service = self._arm = self._motor = False
        self._ext_accel_pct = None

    def lock_address(self) -> str:
        """``host:port`` of the controller (and the robot name when not "Arm"): one tmscal
        per DENSO robot."""
        where = host_port(self.host, self.port)
        return where if self.robot_name == "Arm" else f"{where}/{self.robot_name}"

    def identity(self) -> dict[str, Any]:
        """Driver, endpoint, provider, robot name, what the controller says about itself, the
        robot's ``@TYPE_NAME`` (``type_name``) and the registered arm it names (``arm``:
        ``vs060``, ``cobotta``; None when it names none; ``tmscal.drivers.denso.arm``)."""
        return {"driver": self.name, "host": self.host, "port": self.port,
                "provider": self.provider, "machine": self.machine,
                "robot_name": self.robot_name, "controller": dict(self._controller_info),
                "type_name": self._type_name, "arm": denso_arm(self._type_name)}

    def _flange_pose(self) -> np.ndarray:
        """base_from_flange 4×4 mm from CurPos (P-type). A CurPos reply that is not 6 or 7
        finite numbers raises ``ProtocolError`` (see :meth:`BCAPClient.cur_pos`)."""
        assert self._robot is not None
        p = self.client.cur_pos(self._robot)  # type, length and finiteness checked there
        T = matrix_from_denso_p(p[:6])
        if not np.isfinite(T).all():  # pragma: no cover - finite P-type gives a finite pose
            raise ProtocolError(f"{self.name}: CurPos {p} gives a non-finite pose",
                                device=self.name)
        return T

    #: joints of the arm: ``joint_positions`` keeps the first this many CurJnt values (an
    #: RC8 sends eight, J7 and J8 being optional extra axes)
    arm_axes = 6

    def joint_positions(self) -> np.ndarray:
        """The arm's joint angles now (rad; the first ``arm_axes``), from CurJnt (degrees on
        the wire, converted here). A reply that is not ``arm_axes`` to 32 finite numbers
        raises ``ProtocolError`` naming CurJnt."""
        if not self._opened:
            raise DeviceError(f"{self.name}: joint_positions() on a robot that is not open")
        assert self._robot is not None
        v = self.client.cur_jnt(self._robot)
        if len(v) < self.arm_axes:
            raise ProtocolError(f"{self.name}: CurJnt returned {len(v)} joint angles, "
                                f"expected at least {self.arm_axes}", device=self.name)
        return np.radians(np.array(v[:self.arm_axes], dtype=np.float64))

    def open_accel_mm_s2(self) -> float:
        """The acceleration (mm/s²) that the ExtSpeed sent at open set (its percentage of
        ``max_linear_accel_mm_s2``; before open, the one it would send). A move's
        ``ACCEL``/``DECEL`` percentages scale it."""
        pct = self.accel_percent() if self._ext_accel_pct is None else self._ext_accel_pct
        return pct / 100.0 * self.max_linear_accel_mm_s2

    def motion_law(self) -> MotionLaw:
        """``MOVE L`` moves the flange (no tool selected) on a straight line and the rotation
        geodesic, timed by its translation only (the mock's model; docs/safety.md: CHECK at
        a rig), so a turn without translation is refused when tool points would move. The
        slowest it can be commanded: SPEED 0.01 % and ACCEL 0.01 %."""
        return MotionLaw(LinearPath(), SharedProfile(
            0.0, min_speed_mm_s=self.max_linear_speed_mm_s * 1e-4,
            min_accel_mm_s2=self.open_accel_mm_s2() * 1e-4, name="a DENSO MOVE L"))

    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        """Blocking MOVE L to base_from_flange ``pose`` (4×4 mm) at ``speed_mm_s``; an
        ``accel_mm_s2`` below the one set at open adds ``ACCEL``/``DECEL`` percentages of it
        (rounded down)."""
        assert self._robot is not None
        p = [float(x) for x in denso_p_from_matrix(pose)]
        target = to_variant([p + [self.fig], "P", "@E"])  # reply when reached and settled
        option = speed_option(speed_mm_s, self.max_linear_speed_mm_s)
        full = self.open_accel_mm_s2()
        if accel_mm_s2 < full:
            pct = _pct_text(max(_percent_down(accel_mm_s2, full), 0.01))
            option += f",ACCEL={pct},DECEL={pct}"
        log.debug("DENSO MOVE L %s %s", np.round(p, 3).tolist(), option)
        # a failure HRESULT raises RobotFault (code = HRESULT); timeouts and drops their own
        self.client.robot_move(self._robot, 2, target, option, timeout_s=self.timeout_s)

    def _stop(self) -> None:
        """Robot_Halt over the halt connection (the move's own connection answers anything
        with E_BUSY_PROC while it runs) and check its reply. A dropped halt connection is
        reopened once; each attempt is bounded by ``halt_timeout_s`` in all (so ``stop``
        returns within 2 × ``halt_timeout_s``, whatever keep-alives the controller sends). A
        failure is logged and raised (``DeviceError`` / ``ConnectionLost`` /
        ``DeviceTimeout`` with its code)."""
        if self._halt is None:
            self._halt = HaltLink(self.host, self.port, self.provider, self.machine,
                                  self.robot_name, self.halt_timeout_s)
        try:
            try:
                self._halt.halt()
            except ConnectionLost as e:
                log.warning("DENSO halt connection lost (%s); reconnecting once", e)
                self._halt.close(release=False)
                self._halt.halt()
        except DeviceError as e:
            log.error("DENSO Robot_Halt failed: %s", e)
            raise
        log.info("DENSO Robot_Halt acknowledged")


__all__ = ["DensoRobot", "speed_option", "accel_percent", "DEFAULT_MAX_LINEAR_ACCEL_MM_S2"]
