"""The second b-CAP connection that carries Robot_Halt while a move runs.

A b-CAP connection executes one request at a time: while it waits for a blocking Robot_Move,
the controller answers any other request on it (Robot_Halt included) with E_BUSY_PROC
0x809100AA (DENSO's reference b-CAP server, DENSORobot/orin_bcap ``bcap_server.c``). DENSO's
own ROS driver (DENSORobot/denso_robot_ros, ``denso_robot_core``) therefore keeps a separate
"watch" connection and sends Robot_Halt over it. :class:`HaltLink` is that connection:
Service_Start (no watchdog) → Controller_Connect → Controller_GetRobot, no TakeArm (Halt needs
none). Every wait on it is bounded by ``timeout_s``, and S_EXECUTING keep-alives do not extend
a bound (:data:`~tmscal.drivers.denso.client.KEEPALIVE_REARMS`): a controller that answers
"still executing" for ever cannot make a stop hang.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import partial

from ...errors import DeviceError, DeviceTimeout
from ...timing import Deadline
from .client import BCAPClient, close_down
from .hresult import DEVICE, E_TIMEOUT, hresult_name

log = logging.getLogger(__name__)


class HaltLink:
    """A b-CAP connection to ``host:port`` that only halts the robot ``robot_name``.

    ``timeout_s`` bounds the TCP connect and each reply (so :meth:`open` waits at most
    4 × ``timeout_s`` for an unreachable or silent controller), and :meth:`halt` as a whole:
    one deadline of ``timeout_s`` over the (re)connect it may need and the Robot_Halt reply,
    which keep-alives do not extend. Errors are the client's (``ConnectionLost``,
    ``DeviceTimeout``, ``DeviceError`` with the HRESULT), raised, never swallowed.
    """

    def __init__(self, host: str, port: int, provider: str, machine: str, robot_name: str,
                 timeout_s: float) -> None:
        self.client = BCAPClient(host, port, timeout_s=timeout_s)
        self.provider = provider
        self.machine = machine
        self.robot_name = robot_name
        self._ctrl: int | None = None
        self._robot: int | None = None

    @property
    def ready(self) -> bool:
        """True when connected with a robot handle."""
        return self.client.connected and self._robot is not None

    def open(self, deadline: Deadline | None = None) -> HaltLink:
        """Connect and get the robot handle, each wait at most ``timeout_s`` (and all of them
        within ``deadline`` when given); on failure the socket is closed and the error
        raised."""
        c = self.client
        try:
            c.connect(self._wait(deadline, "connect"))
            c.service_start("", timeout_s=self._wait(deadline, "Service_Start"))
            self._ctrl = c.controller_connect("", self.provider, self.machine, "",
                                              timeout_s=self._wait(deadline,
                                                                   "Controller_Connect"))
            self._robot = c.controller_get_robot(self._ctrl, self.robot_name, "",
                                                 timeout_s=self._wait(deadline,
                                                                      "Controller_GetRobot"))
        except DeviceError:
            self.close(release=False)
            raise
        return self

    def halt(self) -> None:
        """Robot_Halt, waiting for its reply: at most ``timeout_s`` in all, including the
        (re)connect when the link is not open; keep-alives do not extend it. Raises on a
        failure HRESULT (``DeviceError``), no reply in time (``DeviceTimeout``) or a drop
        (``ConnectionLost``)."""
        deadline = Deadline(self.client.timeout_s)
        if not self.ready:
            self.open(deadline)
        assert self._robot is not None
        self.client.robot_halt(self._robot, timeout_s=self._wait(deadline, "Robot_Halt"))

    def _wait(self, deadline: Deadline | None, what: str) -> float:
        """How long the next step (``what``) may wait: ``timeout_s``, or what is left of
        ``deadline`` if less; ``DeviceTimeout`` when nothing is left."""
        if deadline is None:
            return self.client.timeout_s
        left = deadline.remaining()
        if left <= 0:
            raise DeviceTimeout(f"b-CAP halt connection: no time left for {what} (the halt "
                                f"is bounded by {deadline.timeout_s:g} s)", code=E_TIMEOUT,
                                text=hresult_name(E_TIMEOUT), device=DEVICE)
        return min(left, self.client.timeout_s)

    def close(self, release: bool = True) -> None:
        """Release the handles (best effort, bounded) and close the connection."""
        c = self.client
        steps: list[tuple[str, Callable[[], None]]] = []
        if release and c.connected:
            if self._robot is not None:
                steps.append(("Robot_Release", partial(c.robot_release, self._robot)))
            if self._ctrl is not None:
                steps.append(("Controller_Disconnect",
                              partial(c.controller_disconnect, self._ctrl)))
            steps.append(("Service_Stop", c.service_stop))
        close_down(c, steps, "DENSO halt connection")
        self._ctrl = self._robot = None


__all__ = ["HaltLink"]
