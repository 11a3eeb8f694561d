"""Universal Robots driver on the ``ur_rtde`` client library (PyPI ``ur-rtde``).

Frames and units: ``flange_pose()`` and ``move_to()`` take and return base_from_flange as a
4×4 matrix in mm; speeds are mm/s and accelerations mm/s². UR's own form (metres + rotation
vector, m/s, m/s²) exists only at this edge, converted by ``tmscal.geometry.pose_from_rotvec``
and ``rotvec_pose_from_matrix``.

TCP versus flange: RTDE reports and ``moveL`` commands the *TCP* pose (base_from_tcp). The
driver reads the controller's active TCP offset (flange_from_tcp, ``getTCPOffset``) once when it
opens and converts: base_from_flange = base_from_tcp · tcp_from_flange. Keep the TCP offset
fixed while tmscal runs (a zero offset, TCP = flange, is the simplest and is what the mock
reports); the offset found is recorded in ``identity()``.

Warning: ur_rtde's constructors hold Python's GIL while they wait for the controller, so an
``URRobot`` cannot talk to a ``tmscal.mocks.ur.URMock`` served from the same Python process:
run the mock in another process (``tmscal mock``) or the robot in a subprocess.
"""

from __future__ import annotations

import ctypes
import logging
import threading
import time
from typing import Any

import numpy as np

from ...errors import (
    ConnectionLost,
    DeviceError,
    DeviceTimeout,
    MissingExtraError,
    ProtocolError,
    RobotFault,
)
from ...geometry import invert, pose_from_rotvec, rotvec_pose_from_matrix
from ...safety import LinearPath, MotionLaw, SharedProfile
from ...timing import Deadline
from ..base import Envelope, Robot
from .arm import ur_arm
from .calls import RTDECalls
from .settings import URSettings
from .states import (
    MODE_ACTION,
    ROBOT_MODE_RUNNING,
    ROBOT_MODES,
    RUNTIME_STATES,
    SAFETY_MODES,
    dashboard_value,
    remote_check_applies,
)

#: the options' defaults, declared once in URSettings.OPTIONS
_OPT = URSettings.defaults()

log = logging.getLogger(__name__)

#: What the driver asks the controller to stream (everything its checks read).
RECEIVE_VARIABLES = ["timestamp", "actual_TCP_pose", "robot_mode", "safety_mode",
                     "safety_status_bits", "runtime_state", "robot_status_bits", "actual_q"]
_SAFE_MODES = (1, 2)   # NORMAL, REDUCED: motion allowed
_POLL_S = 0.005          # how often a wait looks at the worker or the receive stream (s)
_FRESH_POLL_S = 0.0005   # how often a wait for new data looks at the timestamp (s)
_DIAGNOSE_S = 1.0        # longest wait for the receive stream to show why a move failed (s)
_SCRIPT_START_S = 5.0    # longest wait for a re-uploaded control script to run (ur_rtde's 5 s)
#: moveL's rotation caps: this many rad/s (rad/s²) per m/s (m/s²) of its tool speed
#: (acceleration); the controller runs the longer of the translation and rotation profiles
#: (an answer on the Universal Robots forum, "MoveL: Tool Angular Speed"; not in UR's script
#: manual: CHECK at a rig; docs/devices.md, docs/safety.md)
MOVEL_RAD_PER_M = 4.0


def base_from_flange_from_tcp(tcp_pose: Any, flange_from_tcp: np.ndarray) -> np.ndarray:
    """base_from_flange (4×4 mm) from a UR TCP pose vector [x, y, z (m), rx, ry, rz (rad)]
    and the TCP offset flange_from_tcp (4×4 mm)."""
    return pose_from_rotvec(tcp_pose) @ invert(flange_from_tcp)


def tcp_pose_from_base_from_flange(base_from_flange: np.ndarray,
                                   flange_from_tcp: np.ndarray) -> list[float]:
    """The UR TCP pose vector [x, y, z (m), rx, ry, rz (rad)] that puts the flange at
    ``base_from_flange`` (4×4 mm), given the TCP offset flange_from_tcp (4×4 mm)."""
    return [float(v) for v in rotvec_pose_from_matrix(base_from_flange @ flange_from_tcp)]


class URRobot(RTDECalls, Robot):
    """A Universal Robots arm (CB3 / e-Series) through ``ur_rtde``.

    Parameters
    ----------
    host:
        Controller address (IPv4 or name). The ports are UR's fixed ones (30004 RTDE,
        29999 dashboard, 30003 script).
    envelope, speed_mm_s, accel_mm_s2:
        Safety envelope and default linear speed (mm/s) and acceleration (mm/s²); see
        ``Robot``.
    upload_script:
        True (default): ur_rtde uploads its ``rtde_control`` URScript over the script port
        (replacing a running program; needs Remote Control on e-Series). False: the External
        Control URCap path (``FLAG_USE_EXT_UR_CAP``): ur_rtde serves its script on
        ``ur_cap_port`` and the URCap's program node fetches and runs it when the operator
        presses Play on the pendant (Local Control is fine); ``open`` waits for that.
    ur_cap_port:
        Port of ur_rtde's script sender for the URCap (the URCap installation's "Custom port",
        50002 by default); used only with ``upload_script=False``.
    frequency_hz:
        RTDE data rate; None lets ur_rtde choose (500 Hz on e-Series, 125 Hz on CB3).
    timeout_s:
        Longest a single move, or a wait for controller data, may take (s); beyond it the
        driver raises ``DeviceTimeout``.

    Robot state (docs/devices.md): ``open`` asks the dashboard server first and raises
    ``RobotFault`` naming the cause and the fix at the pendant when remote control is off
    (script upload only), the robot is not powered and brake-released, or a protective or
    emergency stop is active; these are never treated as link losses. After a protective stop
    the control script no longer runs: once the stop is cleared, ``move_to`` finds it
    stopped (``isProgramRunning``), re-uploads it (``reuploadScript``) and continues, or
    raises ``RobotFault`` saying why it cannot.

    ``move_to`` sends a synchronous ``moveL`` and returns once the controller reported it done
    and a newer data package has arrived (so ``flange_pose()`` then reads the final pose).
    ur_rtde 1.6.5 can block forever inside a control call when the link drops during it, so
    the call runs in a worker thread that the driver abandons (raising ``ConnectionLost``)
    when the RTDE receive link is lost.
    """

    name = "ur"

    def __init__(self, host: str, envelope: Envelope | None = None, speed_mm_s: float = 100.0,
                 accel_mm_s2: float = 500.0, upload_script: bool = _OPT["upload_script"],
                 frequency_hz: float | None = _OPT["frequency_hz"],
                 timeout_s: float = _OPT["timeout_s"],
                 ur_cap_port: int = _OPT["ur_cap_port"]) -> None:
        super().__init__(envelope=envelope, speed_mm_s=speed_mm_s, accel_mm_s2=accel_mm_s2)
        if not host:
            raise ValueError("URRobot: host must be a non-empty address")
        o = URSettings.check_options("URRobot", upload_script=upload_script,
                                     frequency_hz=frequency_hz, timeout_s=timeout_s,
                                     ur_cap_port=ur_cap_port)
        self.host = host
        self.upload_script: bool = o["upload_script"]
        self.frequency_hz: float | None = o["frequency_hz"]
        self.timeout_s: float = o["timeout_s"]
        self.ur_cap_port: int = o["ur_cap_port"]
        self.flange_from_tcp = np.eye(4)
        self._rx: Any = None
        self._ctl: Any = None
        self._identity: dict[str, Any] = {}
        self._stuck = False     # a control call was abandoned: the library may be wedged
        self._moving = threading.Event()   # an asynchronous moveL is being waited for
        self._halt = threading.Event()     # stop() asked the waiting move to send stopL
        self._wrench_sensors: dict[str, Any] = {}   # kind → open URWrench (wrench())

    # --- lifecycle ----------------------------------------------------------------------------

    def _open(self) -> None:
        try:
            import rtde_control
            import rtde_receive
        except ImportError as e:  # pragma: no cover - the ur extra is missing
            raise MissingExtraError(f"ur {self.host}", "ur", str(e)) from e
        freq = -1.0 if self.frequency_hz is None else float(self.frequency_hz)
        F = rtde_control.RTDEControlInterface.Flags
        # ur_rtde: FLAG_UPLOAD_SCRIPT sends the script to port 30003; FLAG_USE_EXT_UR_CAP
        # serves it to the External Control URCap and skips the remote-control check
        flags = F.FLAG_UPLOAD_SCRIPT if self.upload_script else F.FLAG_USE_EXT_UR_CAP
        self._check_reachable()
        self._identity = self._dashboard_check("connect")
        self._identity["arm"] = ur_arm(self._identity.get("model"),
                                       self._identity.get("controller_version"),
                                       self._identity.get("serial"))
        with self._translated("connect"):
            self._rx = rtde_receive.RTDEReceiveInterface(self.host, freq, RECEIVE_VARIABLES)
            if not self.upload_script:
                log.warning("ur %s: waiting for the External Control program: press Play on "
                            "the pendant (the URCap fetches the script from this computer, "
                            "port %d)", self.host, self.ur_cap_port)
            self._ctl = rtde_control.RTDEControlInterface(self.host, freq, int(flags),
                                                          self.ur_cap_port)
        self._wait_fresh_data("first data from the controller")
        try:
            self._check_safety("open")
        except RobotFault as e:
            log.warning("%s (moves will be refused until it is cleared)", e)
        offset = self._call_watched("getTCPOffset", self._ctl.getTCPOffset, self.timeout_s)
        if len(offset) == 6:
            self.flange_from_tcp = pose_from_rotvec(offset)
        else:
            log.warning("ur %s: getTCPOffset returned %r; assuming TCP = flange", self.host,
                        offset)
        if np.abs(rotvec_pose_from_matrix(self.flange_from_tcp)).max() > 0:
            log.warning("ur %s: TCP offset %s (m, rad) is not zero; poses are converted to "
                        "the flange with it", self.host, list(offset))
        self._identity["tcp_offset_m_rad"] = [float(v) for v in offset] if len(offset) == 6 \
            else None
        log.info("ur %s: connected (%s)", self.host, self._identity)

    def _close(self) -> None:
        for sensor in self._wrench_sensors.values():
            sensor.close()
        self._wrench_sensors.clear()
        for what, iface in (("control", self._ctl), ("receive", self._rx)):
            if iface is None:
                continue
            if what == "control" and self._stuck:
                log.warning("ur %s: a control call is stuck in ur_rtde; control interface "
                            "left connected", self.host)
                _keep_forever(iface)
                continue
            try:
                self._call_watched(f"{what} disconnect", iface.disconnect, 5.0, watch=False)
            except DeviceError as e:
                log.warning("ur %s: %s disconnect failed: %s", self.host, what, e)
        self._ctl = None
        self._rx = None

    def lock_address(self) -> str:
        """The controller's host (UR's ports are fixed): one tmscal per UR."""
        return self.host

    def identity(self) -> dict[str, Any]:
        """Driver, host, controller (PolyScope) version, serial number, model, ``arm`` (the
        registered arm the dashboard's answers name, ``tmscal.drivers.ur.arm``: ``ur5e``,
        ``ur10``, …; None when they do not tell), TCP offset."""
        return {"driver": self.name, "host": self.host, **self._identity}

    def _dashboard_check(self, what: str) -> dict[str, Any]:
        """Ask the dashboard server for the controller's identity (best effort: a missing
        answer is None) and its state; raise ``RobotFault`` naming ``what``, the cause and
        the fix at the pendant when the robot cannot run the control script: remote control
        off (e-Series ≥ 5.6, script upload only), robot mode not RUNNING, safety status not
        NORMAL/REDUCED. An unreachable dashboard is logged and left to ur_rtde to report; a
        reply that is not UTF-8 raises ``ProtocolError`` naming the command."""
        out: dict[str, Any] = {"controller_version": None, "serial": None, "model": None}
        try:
            import dashboard_client
        except ImportError:  # pragma: no cover - older ur_rtde wheels
            return out
        db = dashboard_client.DashboardClient(self.host)
        try:
            self._dashboard_ask("connect", db.connect)
            for key, command, fn in (
                    ("controller_version", "PolyscopeVersion", db.polyscopeVersion),
                    ("serial", "get serial number", db.getSerialNumber),
                    ("model", "get robot model", db.getRobotModel),
                    ("robot_mode", "robotmode", db.robotmode),
                    ("safety_status", "safetystatus", db.safetystatus)):
                try:
                    out[key] = str(self._dashboard_ask(command, fn)).strip() or None
                except RuntimeError as e:
                    log.debug("ur %s: dashboard %s failed: %s", self.host, key, e)
            if not self.upload_script or not remote_check_applies(out["controller_version"]):
                out["remote_control"] = None
            else:
                out["remote_control"] = bool(self._dashboard_ask("is in remote control",
                                                                 db.isInRemoteControl))
        except RuntimeError as e:
            log.warning("ur %s: dashboard server not reachable: %s", self.host, e)
            return out
        finally:
            try:
                db.disconnect()
            except RuntimeError:
                pass
        fault = self._state_fault(what, out)
        if fault is not None:
            raise fault
        return {k: out[k] for k in ("controller_version", "serial", "model")}

    def _dashboard_ask(self, command: str, fn: Any) -> Any:
        """``fn()``, ur_rtde's call for dashboard ``command``; a reply that is not UTF-8 (the
        library cannot hand it to Python: ``UnicodeDecodeError``) raises ``ProtocolError``
        naming the command and showing the bytes escaped (at most 200)."""
        try:
            return fn()
        except UnicodeDecodeError as e:
            raw = e.object if isinstance(e.object, bytes) else bytes(e.object)
            shown = repr(raw[:200]) + (" …" if len(raw) > 200 else "")
            raise ProtocolError(f"ur {self.host}: the dashboard server's reply to {command!r} "
                                f"is not UTF-8 text: {shown}", text=command,
                                device=self.name) from None

    def _state_fault(self, what: str, st: dict[str, Any]) -> RobotFault | None:
        """The ``RobotFault`` for a dashboard state (``_dashboard_check``) in which the control
        script cannot run, or None."""
        mode = dashboard_value(st.get("robot_mode"))
        safety = dashboard_value(st.get("safety_status"))
        if safety is not None and safety not in ("NORMAL", "REDUCED"):
            return RobotFault(f"ur {self.host}: {what}: safety status {safety}: clear it at "
                              "the pendant (a protective stop: 'unlock protective stop'), then "
                              "run again", text=safety, device=self.name)
        if mode is not None and mode != "RUNNING":
            action = MODE_ACTION.get(mode, "the robot is not ready: bring it to RUNNING at "
                                            "the pendant")
            return RobotFault(f"ur {self.host}: {what}: robot mode {mode}: {action}, then run "
                              "again", text=mode, device=self.name)
        if st.get("remote_control") is False:
            return RobotFault(f"ur {self.host}: {what}: remote control is not enabled: switch "
                              "the pendant to Remote Control (the icon at its top right), or "
                              "use the External Control URCap (upload_script: false), then run "
                              "again", text="LOCAL_CONTROL", device=self.name)
        return None

    # --- robot hooks --------------------------------------------------------------------------

    def _flange_pose(self) -> np.ndarray:
        self._check_connected("flange_pose")
        v = self._call("getActualTCPPose", self._rx.getActualTCPPose)
        if len(v) != 6 or not np.all(np.isfinite(v)):
            raise ProtocolError(f"ur {self.host}: getActualTCPPose returned {v!r}, expected 6 "
                                "finite values", device=self.name)
        return base_from_flange_from_tcp(v, self.flange_from_tcp)

    def joint_positions(self) -> np.ndarray:
        """The six joint angles now (rad), from RTDE ``actual_q`` (``getActualQ``)."""
        if not self._opened:
            raise DeviceError(f"{self.name}: joint_positions() on a robot that is not open")
        self._check_connected("joint_positions")
        v = self._call("getActualQ", self._rx.getActualQ)
        if len(v) != 6 or not np.all(np.isfinite(v)):
            raise ProtocolError(f"ur {self.host}: getActualQ returned {v!r}, expected 6 "
                                "finite values", device=self.name)
        return np.array(v, dtype=np.float64)

    def wrench(self, kind: str = "raw", n: int = 1) -> np.ndarray:
        """The wrist force-torque sensor's wrench (6,) [Fx, Fy, Fz N, Tx, Ty, Tz N·m], the
        mean of ``n`` consecutive RTDE packages, converted nothing. ``kind`` "raw":
        ``ft_raw_wrench`` (getFtRawWrench; PolyScope ≥ 5.9), FLANGE frame, not payload
        compensated, not zeroed; "tcp": ``actual_TCP_force`` (getActualTCPForce), BASE frame,
        payload compensated. Read through a ``URWrench`` on its own RTDE connection, opened on
        first use and closed with the robot (``tmscal.drivers.ur.wrench`` says why)."""
        if not self._opened:
            raise DeviceError(f"{self.name}: wrench() on a robot that is not open")
        from .wrench import URWrench

        sensor = self._wrench_sensors.get(kind)
        if sensor is None:
            sensor = URWrench(self.host, kind, frequency_hz=self.frequency_hz,
                              timeout_s=self.timeout_s)
            sensor.open()  # returns the sensor itself, typed as the base _Device
            self._wrench_sensors[kind] = sensor
        return sensor.read(n).mean(axis=0)

    def motion_law(self) -> MotionLaw:
        """``moveL`` moves the TCP (``flange_from_tcp``, read at open) on a straight line and
        the rotation geodesic with one path share, timed by the longer of its translation and
        rotation profiles (:data:`MOVEL_RAD_PER_M`: 250 mm of translation per rad)."""
        return MotionLaw(LinearPath(self.flange_from_tcp),
                         SharedProfile(1000.0 / MOVEL_RAD_PER_M, name="a UR moveL"))

    def _move_to(self, pose: np.ndarray, speed_mm_s: float, accel_mm_s2: float) -> None:
        self._check_connected("move_to")
        self._check_safety("move_to")
        self._ensure_script("move_to")
        target = tcp_pose_from_base_from_flange(pose, self.flange_from_tcp)
        speed, accel = speed_mm_s / 1000.0, accel_mm_s2 / 1000.0
        log.debug("ur %s: moveL %s at %.4f m/s, %.4f m/s²", self.host, target, speed, accel)
        # asynchronous, so that stop() can halt it: a synchronous moveL cannot be stopped
        # until it ends (ur_rtde's move_async example); the wait below polls its progress
        self._halt.clear()
        self._moving.set()
        try:
            ok = self._call_watched("moveL", lambda: self._ctl.moveL(target, speed, accel, True),
                                    self.timeout_s)
            if not ok:
                self._diagnose_failed_move(target)
            self._wait_async_move(target)
        finally:
            self._moving.clear()
        self._wait_fresh_data("controller data after moveL")
        # an asynchronous move that a safety stop or a power-off ended also ends its progress
        fault = self._fault(f"moveL to {target} aborted", self._safety())
        if fault is not None:
            raise fault

    def _wait_async_move(self, target: list[float]) -> None:
        """Poll the asynchronous moveL's progress until it ends (progress < 0). A stop()
        meanwhile sends stopL from this thread (one thread talks to ur_rtde at a time) and
        raises RobotFault; a safety stop, a lost link or ``timeout_s`` raise as for a
        synchronous move."""
        deadline = Deadline(self.timeout_s)
        while True:
            if self._halt.is_set():
                self._call_watched("stopL", lambda: self._ctl.stopL(10.0, False), 5.0)
                raise RobotFault(f"ur {self.host}: moveL to {target} halted by stop()",
                                 device=self.name)
            if self._call("getAsyncOperationProgress",
                          self._ctl.getAsyncOperationProgress) < 0:
                return
            self._check_connected(f"moveL to {target}")
            fault = self._fault(f"moveL to {target} aborted", self._safety())
            if fault is not None:
                raise fault
            if deadline.expired():
                raise DeviceTimeout(f"ur {self.host}: moveL to {target} did not finish within "
                                    f"{self.timeout_s:.1f} s", device=self.name)
            self._halt.wait(_POLL_S)

    def _stop(self) -> None:
        if self._ctl is None or self._stuck:
            return
        if self._moving.is_set():  # the waiting move sends stopL; wait (bounded) for it
            self._halt.set()
            deadline = Deadline(6.0)
            while self._moving.is_set() and not deadline.expired():
                time.sleep(_POLL_S)
            if not self._moving.is_set():
                return
            log.warning("ur %s: the move did not end within 6 s of stop()", self.host)
        try:
            self._call_watched("stopL", lambda: self._ctl.stopL(10.0, False), 5.0)
        except DeviceError as e:
            log.warning("ur %s: stopL failed: %s", self.host, e)

    # --- helpers ------------------------------------------------------------------------------

    def _safety(self) -> tuple[int, str, bool, bool, int, int]:
        """(safety mode, its name, protective stop, emergency stop, runtime state, robot
        mode), read through the translator."""
        def read() -> tuple[int, str, bool, bool, int, int]:
            rx = self._rx
            mode = int(rx.getSafetyMode())
            return (mode, SAFETY_MODES.get(mode, f"safety mode {mode}"),
                    bool(rx.isProtectiveStopped()), bool(rx.isEmergencyStopped()),
                    int(rx.getRuntimeState()), int(rx.getRobotMode()))
        return self._call("safety status", read)

    def _fault(self, what: str, status: tuple[int, str, bool, bool, int, int]
               ) -> RobotFault | None:
        """A ``RobotFault`` naming ``what`` when ``status`` (from ``_safety``) says the robot
        is stopped, faulted, powered off or braked, else None."""
        mode, name, protective, emergency, _, robot_mode = status
        if protective or emergency or mode not in _SAFE_MODES:
            hint = (": clear it at the pendant, then resume" if protective else "")
            return RobotFault(f"ur {self.host}: {what}: robot in {name}{hint}", code=mode,
                              text=name, device=self.name)
        if robot_mode != ROBOT_MODE_RUNNING:
            rname = ROBOT_MODES.get(robot_mode, f"robot mode {robot_mode}")
            action = MODE_ACTION.get(rname, "the robot is not ready: bring it to RUNNING at "
                                             "the pendant")
            return RobotFault(f"ur {self.host}: {what}: robot mode {rname}: {action}, then "
                              "resume", code=robot_mode, text=rname, device=self.name)
        return None

    def _check_safety(self, what: str) -> None:
        """Raise the ``RobotFault`` the receive stream shows; a fault is confirmed on data
        newer than the call (the stream lags the dashboard: a stop just cleared there)."""
        if self._fault(f"{what} refused", self._safety()) is None:
            return
        self._wait_fresh_data(f"controller data for {what}")
        fault = self._fault(f"{what} refused", self._safety())
        if fault is not None:
            raise fault

    def _ensure_script(self, what: str) -> None:
        """Make sure the control script runs: after a protective stop (cleared since) it does
        not. Script upload: check the robot's state on the dashboard, ``reuploadScript`` and
        wait for ``isProgramRunning``; the URCap path cannot restart it from here. Raise
        ``RobotFault`` saying why when it does not run."""
        if self._call("isProgramRunning", self._ctl.isProgramRunning):
            return
        runtime = int(self._call("getRuntimeState", self._rx.getRuntimeState))
        state = RUNTIME_STATES.get(runtime, str(runtime))
        if not self.upload_script:
            raise RobotFault(f"ur {self.host}: {what} refused: the External Control program is "
                             f"not running (program {state}): press Play on the pendant, then "
                             "resume", code=runtime, text=state, device=self.name)
        self._dashboard_check(f"{what}: re-uploading the control script")
        log.warning("ur %s: the control script is not running (program %s, e.g. after a "
                    "protective stop); re-uploading it", self.host, state)
        self._call_watched("reuploadScript", self._ctl.reuploadScript, self.timeout_s)
        deadline = Deadline(min(_SCRIPT_START_S, self.timeout_s))
        while not self._call("isProgramRunning", self._ctl.isProgramRunning):
            if deadline.expired():
                runtime = int(self._call("getRuntimeState", self._rx.getRuntimeState))
                state = RUNTIME_STATES.get(runtime, str(runtime))
                raise RobotFault(f"ur {self.host}: {what}: the re-uploaded control script did "
                                 f"not start within {deadline.timeout_s:.0f} s (program "
                                 f"{state}); check the pendant for a popup", code=runtime,
                                 text=state, device=self.name)
            self._check_connected(what)
            time.sleep(_POLL_S)
        log.info("ur %s: control script running again", self.host)

    def _diagnose_failed_move(self, target: list[float]) -> None:
        """moveL returned False: raise the typed error that says why. The receive stream may
        lag the control stream by a few cycles, so watch it for a short while."""
        deadline = Deadline(min(_DIAGNOSE_S, self.timeout_s))
        while True:
            if not self._connected():
                raise ConnectionLost(f"ur {self.host}: connection lost during moveL to "
                                     f"{target}", device=self.name)
            status = self._safety()
            fault = self._fault(f"moveL to {target} aborted", status)
            if fault is not None:
                raise fault
            if deadline.expired():
                name, runtime = status[1], status[4]
                state = RUNTIME_STATES.get(runtime, str(runtime))
                raise RobotFault(f"ur {self.host}: moveL to {target} failed (safety {name}, "
                                 f"program {state}); is the control script running?",
                                 code=runtime, text=state, device=self.name)
            time.sleep(_POLL_S)

    def _wait_fresh_data(self, what: str) -> None:
        """Wait until the receive stream has moved on by two packages, so that a pose read next
        was produced after the event just seen on the control stream."""
        last = float(self._call("getTimestamp", self._rx.getTimestamp))
        seen = 0
        deadline = Deadline(self.timeout_s)
        while seen < 2:
            self._check_connected(what)
            t = float(self._call("getTimestamp", self._rx.getTimestamp))
            if t != last:
                seen += 1
                last = t
            elif deadline.expired():
                raise DeviceTimeout(f"ur {self.host}: no {what} within {self.timeout_s:.1f} s",
                                    device=self.name)
            else:
                time.sleep(_FRESH_POLL_S)


def _keep_forever(iface: Any) -> None:
    """Never free ``iface`` (an ur_rtde interface whose call is stuck in its own thread).
    Freed, its C++ destructor would meet that thread still joinable and abort the whole
    process (``terminate called without an active exception``), at the latest when Python
    frees what is left at exit, after the session and the error line were written. One
    reference more than anyone gives back keeps it alive until the process ends."""
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(iface))
