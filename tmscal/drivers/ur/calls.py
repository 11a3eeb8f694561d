"""The one layer between the UR driver and ur_rtde's calls: ur_rtde's errors become tmscal's
(``_translated``), and a blocking call runs in a worker thread that is abandoned when the
receive link drops or a deadline passes (``_call_watched``). A mixin of
:class:`tmscal.drivers.ur.robot.URRobot`; it does no conversions and no motion.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, RobotFault
from ...net import tcp_probe
from ...timing import Deadline

_POLL_S = 0.005          # how often a wait looks at the worker or the receive stream (s)
_LINK_GRACE_S = 0.5      # a receive link down this long during a call: the call is abandoned
#: ur_rtde error texts that name the robot's state, not the link (RobotFault, not retried)
_ROBOT_STATE_TEXTS = ("remote control", "control script", "control program")
RTDE_PORT = 30004        # UR's fixed RTDE port
#: how long the connect check waits for the controller's RTDE port to accept (s): a LAN
#: answers in milliseconds, and ur_rtde's own connect gives no clear reason when it fails
CONNECT_TIMEOUT_S = 3.0


class RTDECalls:
    """ur_rtde calls with tmscal's errors. The driver provides ``host``, ``name``,
    ``upload_script``, the receive and control interfaces ``_rx`` and ``_ctl``, the flag
    ``_stuck`` (a call was abandoned) and ``_dashboard_check(what)``."""

    host: str
    name: str
    upload_script: bool
    _rx: Any
    _ctl: Any
    _stuck: bool
    _dashboard_check: Callable[[str], dict[str, Any]]

    def _check_reachable(self) -> None:
        """Before ur_rtde is asked to connect (its failures print raw text on stderr and say
        "Timeout" for an instant refusal): open and close a TCP connection to the controller's
        RTDE port, ``CONNECT_TIMEOUT_S`` at most. ``ConnectionLost`` in one line saying which
        failure it was and what to check: refused (an address where no UR controller serves
        RTDE, or one still booting), no answer (address, cable, power, subnet), or the
        system's reason (no route, a name that does not resolve)."""
        why = tcp_probe(self.host, RTDE_PORT, CONNECT_TIMEOUT_S)
        if why is None:
            return
        where = f"ur {self.host}: cannot connect to the controller (RTDE, TCP port {RTDE_PORT})"
        if why == "refused":
            msg = (f"{where}: connection refused: something answers at {self.host} but no UR "
                   "controller serves RTDE there; check that robot.host is the controller's "
                   "address and that the controller has finished booting (PolyScope running)")
        else:
            got = (f"no answer within {CONNECT_TIMEOUT_S:g} s" if why == "timeout"
                   else why)
            msg = (f"{where}: {got}; check robot.host (the controller's address, on the "
                   "pendant: Settings > System > Network), the network cable, that the "
                   "controller is powered on, and that this computer is on the robot's subnet")
        raise ConnectionLost(msg, device=self.name, text=why)

    @contextmanager
    def _translated(self, what: str) -> Iterator[None]:
        """The one place ur_rtde's errors become tmscal's: a ``RuntimeError`` raised inside
        becomes ``ConnectionLost`` (the link is down, or the library says so),
        ``DeviceTimeout`` (the library timed out) or ``DeviceError``, naming ``what``; a
        ``DeviceError`` passes through unchanged (with its ``code``)."""
        try:
            yield
        except RuntimeError as e:
            text = str(e)
            low = text.lower()
            if any(k in low for k in _ROBOT_STATE_TEXTS):
                # ur_rtde refused on the robot's state (remote control, script not running):
                # not a link loss; say what the dashboard shows
                try:
                    self._dashboard_check(what)
                except RobotFault as fault:
                    raise fault from e
                hint = (" press Play on the External Control program at the pendant"
                        if not self.upload_script else " check the pendant for a popup")
                raise RobotFault(f"ur {self.host}: {what} failed: {e};{hint}",
                                 device=self.name, text=text) from e
            if not self._connected() or "connect" in low:
                cls: type[DeviceError] = ConnectionLost
            elif "timeout" in low or "timed out" in low:
                cls = DeviceTimeout
            else:
                cls = DeviceError
            raise cls(f"ur {self.host}: {what} failed: {e}", device=self.name,
                      text=text) from e

    def _call(self, what: str, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)``, a ur_rtde call, with its errors translated (``_translated``)."""
        with self._translated(what):
            return fn(*args)

    def _call_watched(self, what: str, fn: Callable[[], Any], timeout_s: float,
                      watch: bool = True) -> Any:
        """Run a (possibly blocking) ur_rtde call in a worker thread. Raise ``ConnectionLost``
        when the receive link drops while it runs (``watch``), ``DeviceTimeout`` after
        ``timeout_s``; the library's errors are translated (``_translated``)."""
        box: dict[str, Any] = {}

        def run() -> None:
            try:
                box["value"] = fn()
            except BaseException as e:  # handed over to the caller's thread
                box["error"] = e

        worker = threading.Thread(target=run, name=f"ur-{what}", daemon=True)
        worker.start()
        self._watch(worker, what, Deadline(timeout_s), watch)
        if "error" in box:
            with self._translated(what):
                raise box["error"]
        return box.get("value")

    def _watch(self, worker: threading.Thread, what: str, deadline: Deadline,
               watch: bool) -> None:
        """Wait for ``worker``; abandon it (``_stuck``) when the receive link has been down
        for ``_LINK_GRACE_S`` (``watch``) or ``deadline`` expires."""
        lost: Deadline | None = None
        while worker.is_alive():
            worker.join(_POLL_S)
            if not worker.is_alive():
                break
            if watch and lost is None and not self._rx_connected():
                lost = Deadline(_LINK_GRACE_S)
            if lost is not None and lost.expired():
                self._stuck = True
                raise ConnectionLost(f"ur {self.host}: connection lost during {what}",
                                     device=self.name)
            if deadline.expired():
                self._stuck = True
                raise DeviceTimeout(f"ur {self.host}: {what} did not return within "
                                    f"{deadline.timeout_s:.1f} s", device=self.name)

    def _rx_connected(self) -> bool:
        try:
            return bool(self._rx is not None and self._rx.isConnected())
        except RuntimeError:
            return False

    def _connected(self) -> bool:
        try:
            return bool(self._rx is not None and self._ctl is not None
                        and self._rx.isConnected() and self._ctl.isConnected())
        except RuntimeError:
            return False

    def _check_connected(self, what: str) -> None:
        if not self._connected():
            raise ConnectionLost(f"ur {self.host}: {what}: the RTDE connection is lost",
                                 device=self.name)
