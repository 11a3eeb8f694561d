"""The Universal Robots e-Series' built-in wrist force-torque sensor through RTDE
(``ur_rtde``'s ``RTDEReceiveInterface``), as a tmscal ``ForceTorque`` driver.

Two outputs, converted nothing (N and N·m as the controller sends them):

* ``kind="raw"`` — ``ft_raw_wrench`` (``getFtRawWrench``, PolyScope ≥ 5.9): the raw wrench in
  the FLANGE frame (the sensor's frame), not payload-compensated and not zeroed, so its bias
  is unknown. This is what kinematic self-calibration needs (docs/selfcal.md).
* ``kind="tcp"`` — ``actual_TCP_force`` (``getActualTCPForce``): the payload-compensated
  wrench at the TCP in the robot BASE frame, re-zeroed by ``zero_ftsensor()`` and whenever the
  payload is set.

The driver opens its own RTDE receive connection (read-only, with a recipe of only
``timestamp`` and the two wrenches) rather than sharing the ``URRobot``'s: the controller
serves several RTDE clients, the F/T sensor is then built, opened and reconnected on its own
(``acquisition.devices.make_ft``) like every other device, and the robot's recipe stays
what every controller version has, so a PolyScope older than 5.9, which has no
``ft_raw_wrench``, still runs the robot and fails only here.

Warning (as for ``URRobot``): ur_rtde's constructors hold the GIL, so this driver cannot talk
to a UR mock served from the same Python process.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, MissingExtraError
from ...timing import Deadline
from ..base import ForceTorque
from .settings import URWrenchSettings

__all__ = ["URWrench", "WRENCH_KINDS", "WRENCH_VARIABLES"]

#: the options' defaults, declared once in URWrenchSettings.OPTIONS
_OPT = URWrenchSettings.defaults()

#: kind → (RTDE output variable, ur_rtde getter, frame the wrench is expressed in)
WRENCH_KINDS = {"raw": ("ft_raw_wrench", "getFtRawWrench", "flange"),
                "tcp": ("actual_TCP_force", "getActualTCPForce", "base")}
#: the recipe of the sensor's own RTDE connection
WRENCH_VARIABLES = ["timestamp", "actual_TCP_force", "ft_raw_wrench"]
_POLL_S = 0.0005


class URWrench(ForceTorque):
    """The UR wrench at controller ``host`` (RTDE port 30004). ``kind`` "raw" (flange frame)
    or "tcp" (base frame, payload compensated); ``frequency_hz`` the RTDE rate (None: ur_rtde's
    default, 500 Hz on e-Series); ``timeout_s`` the longest wait for one new data package.
    ``read(n)`` returns n samples from n consecutive packages."""

    name = "ur_wrench"
    #: ``ft.host: robot`` in a config means the robot's address (the sensor is in the arm)
    on_robot = True

    def __init__(self, host: str, kind: str = _OPT["kind"],
                 frequency_hz: float | None = _OPT["frequency_hz"],
                 timeout_s: float = _OPT["timeout_s"]) -> None:
        super().__init__()
        if not isinstance(host, str) or not host:
            raise ValueError("URWrench: host must be a non-empty address")
        o = URWrenchSettings.check_options("URWrench", kind=kind, frequency_hz=frequency_hz,
                                           timeout_s=timeout_s)
        self.host, self.kind = host, kind
        self.frequency_hz: float | None = o["frequency_hz"]
        self.timeout_s: float = o["timeout_s"]
        self.frame = WRENCH_KINDS[kind][2]
        self._rx: Any = None

    def _open(self) -> None:
        try:
            import rtde_receive
        except ImportError as e:  # pragma: no cover - the ur extra is missing
            raise MissingExtraError(f"ur_wrench {self.host}", "ur", str(e)) from e
        freq = -1.0 if self.frequency_hz is None else float(self.frequency_hz)
        try:
            self._rx = rtde_receive.RTDEReceiveInterface(self.host, freq, WRENCH_VARIABLES)
        except RuntimeError as e:
            raise ConnectionLost(f"ur_wrench {self.host}: RTDE connection failed ({e}); "
                                 "ft_raw_wrench needs PolyScope ≥ 5.9", device=self.name) from e

    def _close(self) -> None:
        if self._rx is None:
            return
        try:
            self._rx.disconnect()
        except RuntimeError:  # pragma: no cover - best effort
            pass
        self._rx = None

    def identity(self) -> dict[str, Any]:
        """Driver, host, which output and its frame."""
        var = WRENCH_KINDS[self.kind][0]
        return {"driver": self.name, "host": self.host, "kind": self.kind, "variable": var,
                "frame": self.frame}

    def _call(self, what: str, fn: Any) -> Any:
        try:
            return fn()
        except RuntimeError as e:
            raise ConnectionLost(f"ur_wrench {self.host}: {what} failed ({e})",
                                 device=self.name) from e

    def _read(self, n: int) -> np.ndarray:
        getter = getattr(self._rx, WRENCH_KINDS[self.kind][1])
        out = np.empty((n, 6))
        last = self._call("getTimestamp", self._rx.getTimestamp)
        for i in range(n):
            deadline = Deadline(self.timeout_s)
            while True:
                if not self._call("isConnected", self._rx.isConnected):
                    raise ConnectionLost(f"ur_wrench {self.host}: the RTDE connection is lost",
                                         device=self.name)
                t = self._call("getTimestamp", self._rx.getTimestamp)
                if t != last:
                    break
                if deadline.expired():
                    raise DeviceTimeout(f"ur_wrench {self.host}: no new RTDE package within "
                                        f"{self.timeout_s:g} s ({i} of {n} samples)",
                                        device=self.name)
                time.sleep(_POLL_S)
            last = t
            v = np.asarray(self._call(WRENCH_KINDS[self.kind][1], getter), dtype=np.float64)
            if v.shape != (6,) or not np.isfinite(v).all():
                raise DeviceError(f"ur_wrench {self.host}: {WRENCH_KINDS[self.kind][1]} "
                                  f"returned {v.tolist()}, expected 6 finite values",
                                  device=self.name)
            out[i] = v
        return out
