"""DENSO RC8 / RC8A / COBOTTA robot over b-CAP (TCP, default port 5007).

Frames and units: poses are base_from_flange 4×4 in mm (the controller's P-type "work"
coordinates with no tool and work offset selected: x, y, z in mm, rx, ry, rz in degrees,
converted only through ``tmscal.geometry``); speeds in mm/s.

Session: Service_Start (``,WDT=<ms>`` if a watchdog is set) → Controller_Connect →
Controller_GetRobot → TakeArm → Motor on. Moves are blocking ``Robot_Move`` comp 2 (MOVE L)
with the pose as a VARIANT array ``[[x, y, z, rx, ry, rz, fig], "P", "@P"]`` (fig −1: the
controller chooses the arm configuration) and the option ``SPEED=<percent>`` where
percent = speed_mm_s / max_linear_speed_mm_s × 100. Close (best effort): Motor off, GiveArm,
Robot_Release, Controller_Disconnect, Service_Stop. The controller's ExtSpeed is left as it
is, so the real speed is SPEED × ExtSpeed (never faster than asked).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ...errors import DeviceError
from ...geometry import denso_p_from_matrix, matrix_from_denso_p
from ..base import Envelope, Robot
from .bcap import DEFAULT_PORT, BCAPClient, to_variant

log = logging.getLogger(__name__)


def speed_option(speed_mm_s: float, max_linear_speed_mm_s: float) -> str:
    """The Robot_Move option ``"SPEED=<percent>"`` for a linear speed in mm/s, percent of
    ``max_linear_speed_mm_s`` rounded DOWN to 0.01 (never faster than asked) and clamped to
    [0.01, 100]."""
    pct = min(max(math.floor(10000.0 * speed_mm_s / max_linear_speed_mm_s + 1e-9) / 100.0,
                  0.01), 100.0)
    text = f"{pct:.2f}".rstrip("0").rstrip(".")
    return f"SPEED={text}"


class DensoRobot(Robot):
    """A DENSO robot driven over b-CAP; see the module doc for the command sequence.

    ``host``/``port``: the controller (RC8 default port 5007). ``envelope``, ``speed_mm_s``,
    ``accel_mm_s2``: as in :class:`~tmscal.drivers.base.Robot`. ``max_linear_speed_mm_s``:
    the linear speed (mm/s) that SPEED=100 means on this arm. ``provider``/``machine``: the
    CAO provider (``"CaoProv.DENSO.VRC9"`` for RC9) and its machine argument.
    ``robot_name``: the robot object ("Arm"). ``timeout_s``: the longest wait for any reply,
    including a move (re-armed by each S_EXECUTING keep-alive). ``watchdog_ms``: WDT for
    Service_Start (None: no keep-alives). ``fig``: the figure code sent with every pose.
    """

    name = "denso"

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 envelope: Envelope | None = None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0, max_linear_speed_mm_s: float = 1000.0,
                 provider: str = "CaoProv.DENSO.VRC", machine: str = "localhost",
                 robot_name: str = "Arm", timeout_s: float = 30.0,
                 watchdog_ms: int | None = 400, fig: int = -1) -> None:
        super().__init__(envelope=envelope, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        if max_linear_speed_mm_s <= 0:
            raise ValueError(f"max_linear_speed_mm_s must be > 0, got {max_linear_speed_mm_s}")
        self.host = host
        self.port = int(port)
        self.max_linear_speed_mm_s = float(max_linear_speed_mm_s)
        self.provider = provider
        self.machine = machine
        self.robot_name = robot_name
        self.timeout_s = float(timeout_s)
        self.watchdog_ms = watchdog_ms
        self.fig = int(fig)
        self._client: BCAPClient | None = None
        self._ctrl: int | None = None
        self._robot: int | None = None
        self._service = False
        self._arm = False
        self._motor = False
        self._controller_info: dict[str, Any] = {}

    @property
    def client(self) -> BCAPClient:
        if self._client is None:
            raise DeviceError("denso: not connected", device="denso")
        return self._client

    def _open(self) -> None:
        c = BCAPClient(self.host, self.port, timeout_s=self.timeout_s).connect()
        self._client = c
        c.service_start(f",WDT={int(self.watchdog_ms)}" if self.watchdog_ms else "")
        self._service = True
        self._ctrl = c.controller_connect("", self.provider, self.machine, "")
        self._robot = c.controller_get_robot(self._ctrl, self.robot_name, "")
        self._controller_info = self._read_controller_info()
        c.take_arm(self._robot)
        self._arm = True
        c.motor(self._robot, True)
        self._motor = True
        log.info("DENSO robot %r on %s:%d ready (motor on)", self.robot_name, self.host,
                 self.port)

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

    def _close(self) -> None:
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
        for what, fn in steps:
            if not c.connected:
                break
            try:
                fn()
            except (DeviceError, OSError) as e:
                log.warning("DENSO close: %s failed: %s", what, e)
        c.close()
        self._client = None
        self._robot = self._ctrl = None
        self._service = self._arm = self._motor = False

    def identity(self) -> dict[str, Any]:
        """Driver, endpoint, provider, robot name and what the controller says about itself."""
        return {"driver": self.name, "host": self.host, "port": self.port,
                "provider": self.provider, "machine": self.machine,
                "robot_name": self.robot_name, "controller": dict(self._controller_info)}

    def _flange_pose(self) -> np.ndarray:
        """base_from_flange 4×4 mm from CurPos (P-type)."""
        assert self._robot is not None
        p = self.client.cur_pos(self._robot)
        if len(p) < 6:
            raise DeviceError(f"denso: CurPos returned {len(p)} values, expected 7",
                              device="denso")
        return matrix_from_denso_p(p[:6])

    def _move_to(self, pose: np.ndarray, speed_mm_s: float) -> None:
        """Blocking MOVE L to base_from_flange ``pose`` (4×4 mm) at ``speed_mm_s``."""
        assert self._robot is not None
        p = [float(x) for x in denso_p_from_matrix(pose)]
        target = to_variant([p + [self.fig], "P", "@P"])
        option = speed_option(speed_mm_s, self.max_linear_speed_mm_s)
        log.debug("DENSO MOVE L %s %s", np.round(p, 3).tolist(), option)
        # a failure HRESULT raises RobotFault (code = HRESULT); timeouts and drops their own
        self.client.robot_move(self._robot, 2, target, option, timeout_s=self.timeout_s)

    def _stop(self) -> None:
        """Robot_Halt. If a move is waiting on this connection, the halt is sent without
        waiting for its reply."""
        c = self._client
        if c is None or self._robot is None:
            return
        try:
            c.robot_halt(self._robot, wait=not c.busy)
        except DeviceError as e:
            log.warning("DENSO Robot_Halt failed: %s", e)


__all__ = ["DensoRobot", "speed_option"]
