"""A protocol-level Universal Robots controller that serves a ``SimRig``.

The unmodified ``ur_rtde`` client library (``RTDEControlInterface``, ``RTDEReceiveInterface``,
``DashboardClient``) drives it, with the library's default flags (script upload) and with
``flags=0`` (no upload). Three TCP servers on one loopback address:

* **30004 RTDE**: protocol negotiation (``V``), controller version (``v``), output recipe
  (``O``) and input recipes (``I``, numbered 1, 2, 3 … per connection, as ur_rtde expects),
  start/pause (``S``/``P``), data packages (``U``) both ways. Each connection streams its output
  recipe from its own thread at the requested frequency, on the real-time and on the fast clock
  alike (only *motion* is instant on the fast clock).
* **29999 dashboard**: banner, ``PolyscopeVersion``, ``get serial number``,
  ``is in remote control`` (→ ``true``), ``stop`` (→ ``Stopped``), ``play``, ``pause``,
  ``unlock protective stop`` and the other status queries; unknown commands get the real
  server's ``could not understand: '…'``.
* **30003 script**: the uploaded URScript program is accepted (kept in ``last_script``) and
  the emulated ``rtde_control`` script starts (``runtime_state`` 2, PLAYING).

The emulated control script follows ur_rtde's register handshake: the command id arrives in
``input_int_register_0`` (``moveL``: cmd 3, pose in ``input_double_register_0..5`` as metres
and rotation vector, speed in ``_6`` m/s, acceleration in ``_7``, asynchronous flag in
``input_int_register_1``); ``output_int_register_0`` is 1 when ready and 2 when the command is
done; asynchronous progress is in ``output_int_register_2`` (bit 15 running, bits 16–23 change
count). A linear move puts the rig's flange at ``pose_from_rotvec(pose)``; in real time it takes
distance / speed seconds (rotation-only moves: angle / speed, speed read as rad/s) and the
reported TCP pose is interpolated on the way; on the fast clock it is immediate.
``actual_TCP_pose`` is ``rotvec_pose_from_matrix(rig.reported_flange())``: the mock's TCP offset
is zero, so TCP = flange. Joint values are fixed placeholders (the mock has no kinematics).

Because ur_rtde's ports are fixed, each mock binds its own loopback address (127.0.0.2,
127.0.0.3, …), so several mocks (and tests) can run side by side.

Hostile input: an output recipe frequency that is not finite or outside
[``MIN_FREQUENCY_HZ``, ``MAX_FREQUENCY_HZ``] is refused (``O`` reply with recipe id 0 and no
types; a later ``S`` answers 0, not started, and nothing streams). A move whose pose, speed or
acceleration is not finite, or whose speed or acceleration is not positive, is a runtime error
of the control script, as on a real controller: the program stops (runtime_state 1), the
flange stays where it was, and nothing non-finite reaches the rig; ``play`` (dashboard) or a
new script upload starts it again. Joint targets must be finite too.

Faults (``URFaults``): a protective stop during the k-th move (safety mode 3,
``safety_status_bits`` bit 2, the flange stops half-way, the program pauses as on a real
robot; cleared with the dashboard's ``unlock protective stop``, resumed with ``play`` or a new
script upload) and a dropped connection at the k-th move (every client socket is closed; the
servers keep listening). Moves are counted from 1 over the mock's life (moveL, moveJ,
moveL_FK, moveJ_IK).
"""

from __future__ import annotations

import logging
import math
import re
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry import (
    matrix_from_rotvec,
    pose_from_rotvec,
    rotvec_from_matrix,
    rotvec_pose_from_matrix,
)
from ..sim.rig import SimRig
from .clock import REAL_TIME, Clock
from .net import loopback_family

log = logging.getLogger(__name__)

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003

# RTDE package types
_V, _v, _O, _I, _S, _P, _U, _M = (ord(c) for c in "VvOISPUM")

# Controller constants (UR e-Series / CB3 RTDE definitions).
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4
ROBOT_MODE_RUNNING = 7
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = 1, 3
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE, SAFETY_BIT_STOPPED_BY_SAFETY = 1 << 0, 1 << 2, 1 << 10
ROBOT_BIT_POWER_ON, ROBOT_BIT_PROGRAM_RUNNING = 1 << 0, 1 << 1
JOINT_RUNNING_MODE = 253

# ur_rtde command ids (input_int_register_0)
CMD_NO_CMD, CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK = 0, 1, 2, 3, 4
CMD_STOPL, CMD_STOPJ, CMD_WATCHDOG, CMD_STOP_SCRIPT = 33, 34, 99, 255
#: commands the script processes and acknowledges with "ready" at once (servo, speed, …)
_REALTIME_CMDS = {24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71}
_MOVE_CMDS = {CMD_MOVEJ: "moveJ", CMD_MOVEJ_IK: "moveJ_IK", CMD_MOVEL: "moveL",
              CMD_MOVEL_FK: "moveL_FK"}

#: Placeholder joint angles (rad) reported as actual_q / target_q: the mock has no kinematics.
HOME_Q = (0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)

_N_REGS = 48

#: Output recipe frequencies (Hz) the mock accepts (e-Series controllers stream at ≤ 500 Hz).
MIN_FREQUENCY_HZ, MAX_FREQUENCY_HZ = 1.0, 500.0

# --- RTDE variable types ----------------------------------------------------------------------

_TYPE_FMT = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i",
             "DOUBLE": "d", "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i",
             "VECTOR6UINT32": "6I"}

_VECTOR6D = {
    "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q",
    "actual_qd", "actual_qdd", "actual_current", "actual_current_as_torque",
    "actual_current_window", "joint_control_output", "actual_TCP_pose", "actual_TCP_speed",
    "actual_TCP_force", "target_TCP_pose", "target_TCP_speed", "joint_temperatures",
    "actual_joint_voltage", "ft_raw_wrench", "payload_inertia", "tcp_offset",
    "external_force_torque", "joint_position_deviation_ratio", "collision_detection_ratio",
}
_VECTOR3D = {"actual_tool_accelerometer", "payload_cog", "elbow_position", "elbow_velocity"}
_INT32 = {"robot_mode", "safety_mode", "safety_status", "tool_output_voltage",
          "tool_analog_output_types"}
_UINT32 = {"runtime_state", "robot_status_bits", "safety_status_bits", "tool_mode",
           "analog_io_types", "tool_analog_input_types", "output_bit_registers0_to_31",
           "output_bit_registers32_to_63", "input_bit_registers0_to_31",
           "input_bit_registers32_to_63", "euromap67_input_bits", "euromap67_output_bits",
           "script_control_line"}
_UINT64 = {"actual_digital_input_bits", "actual_digital_output_bits"}
_UINT8 = {"tool_output_mode", "tool_digital_output0_mode", "tool_digital_output1_mode",
          "standard_digital_output_mask", "standard_digital_output",
          "configurable_digital_output_mask", "configurable_digital_output",
          "tool_digital_output_mask", "tool_digital_output", "standard_analog_output_mask",
          "standard_analog_output_type", "speed_slider_mask"}


def rtde_type(name: str) -> str:
    """The RTDE type name of a variable (``DOUBLE`` for names this mock does not know)."""
    if name in _VECTOR6D:
        return "VECTOR6D"
    if name in _VECTOR3D:
        return "VECTOR3D"
    if name == "joint_mode":
        return "VECTOR6INT32"
    if name in _INT32 or re.fullmatch(r"(input|output)_int_register_\d+", name):
        return "INT32"
    if name in _UINT32:
        return "UINT32"
    if name in _UINT64:
        return "UINT64"
    if name in _UINT8:
        return "UINT8"
    if re.fullmatch(r"(input|output)_bit_register_\d+", name):
        return "BOOL"
    return "DOUBLE"


@dataclass(frozen=True)
class URFaults:
    """Faults to inject. Moves (moveL, moveJ, moveL_FK, moveJ_IK) are counted from 1.

    ``protective_stop_at_move``: the k-th move triggers a protective stop half-way (the program
    pauses; the client's ``moveL`` fails). ``drop_connection_at_move``: the network link fails
    during the k-th move: the controller finishes that move, and when the client clears the
    command every client socket (RTDE, dashboard, script) is shut down and the listeners close,
    so reconnects are refused. None disables a fault. (Dropping the link while ur_rtde 1.6.5
    waits inside a call makes the library hang, or segfault when it can reconnect.)
    """

    protective_stop_at_move: int | None = None
    drop_connection_at_move: int | None = None


@dataclass
class _Motion:
    start: np.ndarray          # base_from_flange 4×4 mm at the start
    target: np.ndarray         # base_from_flange 4×4 mm commanded
    t0: float
    duration: float            # s
    asynchronous: bool
    speed: float               # m/s (rad/s for rotation-only moves)
    stop_fraction: float | None = None   # protective stop at this fraction of the motion

    def fraction(self, now: float) -> float:
        if self.duration <= 0:
            return 1.0
        return min(1.0, max(0.0, (now - self.t0) / self.duration))

    def pose_at(self, f: float) -> np.ndarray:
        """Interpolated base_from_flange (mm): translation lerp, rotation along the geodesic."""
        if f >= 1.0:
            return self.target.copy()
        out = np.eye(4)
        out[:3, 3] = self.start[:3, 3] + f * (self.target[:3, 3] - self.start[:3, 3])
        rel = self.start[:3, :3].T @ self.target[:3, :3]
        out[:3, :3] = self.start[:3, :3] @ matrix_from_rotvec(f * rotvec_from_matrix(rel))
        return out


def _listen(host: str, port: int, family: socket.AddressFamily = socket.AF_INET
            ) -> socket.socket:
    s = socket.socket(family, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((host, port))
    s.listen(8)
    s.settimeout(0.2)
    return s


def _recv_exact(sock: socket.socket, n: int, alive: Callable[[], bool]) -> bytes | None:
    """n bytes, or None when the peer closed or the mock is shutting down."""
    buf = bytearray()
    while len(buf) < n:
        if not alive():
            return None
        try:
            chunk = sock.recv(n - len(buf))
        except TimeoutError:
            continue
        except OSError:
            return None
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


class URMock:
    """A Universal Robots controller (RTDE 30004, dashboard 29999, script 30003) serving ``rig``.

    Parameters
    ----------
    rig:
        The simulated rig; moves call ``rig.move_flange`` (base_from_flange 4×4 mm) and the
        reported TCP pose is ``rig.reported_flange()`` (TCP offset zero: TCP = flange).
    host:
        Loopback address to bind (127.0.0.0/8, ::1 or localhost; anything else raises
        ``ConfigError``); ports are UR's fixed ones.
    clock:
        ``REAL_TIME``: moves take distance/speed seconds; ``FAST``: moves complete at once.
        Data streaming runs at the client's requested rate on both.
    faults:
        ``URFaults`` to inject.
    version:
        Controller software version (major, minor, bugfix, build) reported on RTDE and by the
        dashboard's ``PolyscopeVersion``. ≥ 5.6 makes ur_rtde query version and serial.
    serial:
        Serial number reported by ``get serial number``.
    model:
        Robot model reported by ``get robot model``.
    program_running:
        True (default): a control program is already running at start (runtime_state 2,
        ready), as it must be for clients using ``flags=0``; with the default upload flag
        ur_rtde then stops it and uploads its own. False: the controller starts stopped and
        only a script upload (or dashboard ``play`` after one) makes it run.
    """

    def __init__(self, rig: SimRig, host: str = "127.0.0.2", clock: Clock = REAL_TIME,
                 faults: URFaults = URFaults(), version: tuple[int, int, int, int] = (
                     5, 11, 0, 108249),
                 serial: str = "20185500001", model: str = "UR5",
                 program_running: bool = True) -> None:
        self._family = loopback_family(host, "URMock host")
        if len(version) != 4:
            raise ValueError(f"version must be (major, minor, bugfix, build), got {version!r}")
        self.rig = rig
        self.host = host
        self.clock = clock
        self.faults = faults
        self.version = tuple(int(v) for v in version)
        self.serial = serial
        self.model = model
        self.last_script: str | None = None
        self.scripts_received = 0
        self.dashboard_log: list[str] = []
        self.move_count = 0

        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listeners: list[socket.socket] = []
        self._clients: set[socket.socket] = set()
        self._t_start = time.monotonic()

        # controller state (guarded by _lock)
        self.in_int = [0] * _N_REGS
        self.in_double = [0.0] * _N_REGS
        self.out_int = [0] * _N_REGS
        self.out_double = [0.0] * _N_REGS
        self.external_force_torque = [0.0] * 6
        self.safety_mode = SAFETY_NORMAL
        self.runtime_state = RUNTIME_PLAYING if program_running else RUNTIME_STOPPED
        self.target_q = list(HOME_Q)
        self._program_loaded = program_running
        self._executing = False
        self._motion: _Motion | None = None
        self._interrupted: _Motion | None = None   # resumed by dashboard "play"
        self._async_wr_count = 0
        self._async_op_id = 0
        self._done_pending = False     # a sync command waits for its motion to finish
        self._drop_after_command = False
        if program_running:
            self.out_int[0] = 1
            self._write_async(-1)

    # --- lifecycle ----------------------------------------------------------------------------

    def start(self) -> str:
        """Bind the three ports on ``host`` and serve in daemon threads. Returns the host
        string to give to ur_rtde (``RTDEControlInterface(host)``)."""
        if self._listeners:
            return self.host
        try:
            for port, handler in ((RTDE_PORT, self._serve_rtde),
                                  (DASHBOARD_PORT, self._serve_dashboard),
                                  (SCRIPT_PORT, self._serve_script)):
                ls = _listen(self.host, port, self._family)
                self._listeners.append(ls)
                self._spawn(self._accept_loop, ls, handler, name=f"ur-accept-{port}")
        except OSError:
            self.close()
            raise
        self._spawn(self._script_loop, name="ur-script")
        log.info("UR mock serving on %s (RTDE %d, dashboard %d, script %d)", self.host,
                 RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORT)
        return self.host

    def close(self) -> None:
        """Stop every thread and close every socket (safe to call twice)."""
        self._stop.set()
        for ls in self._listeners:
            try:
                ls.close()
            except OSError:
                pass
        self._drop_clients()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)
        self._threads.clear()
        self._listeners.clear()

    def __enter__(self) -> URMock:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _spawn(self, fn: Callable[..., Any], *args: Any, name: str) -> None:
        t = threading.Thread(target=fn, args=args, name=name, daemon=True)
        self._threads.append(t)
        t.start()

    def _alive(self) -> bool:
        return not self._stop.is_set()

    def _accept_loop(self, ls: socket.socket, handler: Callable[[socket.socket], None]) -> None:
        while self._alive():
            try:
                conn, _ = ls.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(0.2)
            with self._lock:
                self._clients.add(conn)
            self._spawn(self._run_client, conn, handler, name=f"ur-client-{handler.__name__}")
            self._threads = [t for t in self._threads if t.is_alive()]

    def _run_client(self, conn: socket.socket, handler: Callable[[socket.socket], None]) -> None:
        try:
            handler(conn)
        except OSError as e:
            log.debug("UR mock client connection ended: %s", e)
        finally:
            with self._lock:
                self._clients.discard(conn)
            try:
                conn.close()
            except OSError:
                pass

    def _drop_link(self) -> None:
        """The network link fails: listeners close (reconnects are refused) and every client
        connection is shut down."""
        for ls in self._listeners:
            try:
                ls.close()
            except OSError:
                pass
        self._drop_clients()

    def _drop_clients(self) -> None:
        """Shut every client connection down (the handler threads then close the sockets)."""
        with self._lock:
            clients = list(self._clients)
            self._clients.clear()
        for c in clients:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    # --- controller state ---------------------------------------------------------------------

    @property
    def protective_stopped(self) -> bool:
        return self.safety_mode == SAFETY_PROTECTIVE_STOP

    def _safety_status_bits(self) -> int:
        if self.safety_mode == SAFETY_PROTECTIVE_STOP:
            return SAFETY_BIT_PROTECTIVE | SAFETY_BIT_STOPPED_BY_SAFETY
        return SAFETY_BIT_NORMAL

    def _robot_status_bits(self) -> int:
        bits = ROBOT_BIT_POWER_ON
        if self.runtime_state == RUNTIME_PLAYING:
            bits |= ROBOT_BIT_PROGRAM_RUNNING
        return bits

    def _write_async(self, value: int) -> None:
        """output_int_register_2 as the script's write_async_progress_register(value) writes
        it: change count (7 bits) in bits 16–23, operation id (7 bits, incremented when an
        operation starts, value 0) in bits 24–30, bit 15 + progress while running (value ≥ 0);
        a negative value means finished."""
        self._async_wr_count = (self._async_wr_count + 1) % 128
        if value == 0:
            self._async_op_id = (self._async_op_id + 1) % 128
        reg = self._async_wr_count * 65536 + self._async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int[2] = reg

    def _flange_now(self, now: float) -> np.ndarray:
        """Reported base_from_flange (4×4 mm), interpolated while a real-time move runs."""
        m = self._motion
        if m is not None:
            return m.pose_at(m.fraction(now))
        return self.rig.reported_flange()

    def tcp_pose(self) -> list[float]:
        """actual_TCP_pose as UR reports it: [x, y, z (m), rx, ry, rz (rad)]."""
        with self._lock:
            T = self._flange_now(self.clock.now())
        return [float(v) for v in rotvec_pose_from_matrix(T)]

    def _tcp_speed(self, now: float) -> list[float]:
        m = self._motion
        if m is None or m.duration <= 0 or m.fraction(now) >= 1.0:
            return [0.0] * 6
        v = (m.target[:3, 3] - m.start[:3, 3]) / 1000.0 / m.duration
        w = m.start[:3, :3] @ rotvec_from_matrix(m.start[:3, :3].T @ m.target[:3, :3]) \
            / m.duration
        return [float(x) for x in (*v, *w)]

    def _start_program(self, why: str) -> None:
        """(Re)start the emulated rtde_control script: clean state, ready for a command."""
        self._abort_motion()
        self._interrupted = None
        self._program_loaded = True
        self._executing = False
        self._done_pending = False
        self.out_int[0] = 1
        self._write_async(-1)
        self.runtime_state = RUNTIME_PLAYING
        log.info("UR mock: control script running (%s)", why)

    def _stop_program(self, why: str) -> None:
        self._abort_motion()
        self._interrupted = None
        self._executing = False
        self._done_pending = False
        self.runtime_state = RUNTIME_STOPPED
        log.info("UR mock: program stopped (%s)", why)

    def _abort_motion(self, now: float | None = None) -> None:
        """Stop the flange where it is now (decelerations are not modelled)."""
        m = self._motion
        if m is None:
            return
        now = self.clock.now() if now is None else now
        self.rig.move_flange(m.pose_at(m.fraction(now)))
        self._motion = None
        if m.asynchronous:
            self._write_async(-1)

    def _pause(self) -> None:
        """Pause the program (dashboard ``pause`` or a protective stop): the flange stops where
        it is and a running move resumes on ``play``."""
        m = self._motion
        if m is not None:
            self.rig.move_flange(m.pose_at(m.fraction(self.clock.now())))
            self._interrupted = m
            self._motion = None
        self.runtime_state = RUNTIME_PAUSED

    def _resume(self) -> None:
        m, self._interrupted = self._interrupted, None
        self.runtime_state = RUNTIME_PLAYING
        if m is not None:
            now = self.clock.now()
            self._start_motion(m.target, m.speed, m.asynchronous, now, "resumed move",
                               resumed=True)

    def _protective_stop(self, m: _Motion) -> None:
        f = m.stop_fraction if m.stop_fraction is not None else 0.5
        self.rig.move_flange(m.pose_at(f))
        self._motion = None
        self._interrupted = m
        self.safety_mode = SAFETY_PROTECTIVE_STOP
        self.runtime_state = RUNTIME_PAUSED
        if m.asynchronous:
            self._write_async(-1)
        log.warning("UR mock: PROTECTIVE STOP during move %d (flange stopped at %.0f%%)",
                    self.move_count, 100 * f)

    def _advance(self, now: float) -> None:
        """Finish or interrupt the running motion according to the clock."""
        m = self._motion
        if m is None:
            return
        if m.stop_fraction is not None and (self.clock.fast or m.fraction(now) >= m.stop_fraction):
            self._protective_stop(m)
            return
        if self.clock.fast or m.fraction(now) >= 1.0:
            self.rig.move_flange(m.target)
            self._motion = None
            if m.asynchronous:
                self._write_async(-1)
            elif self._done_pending:
                self._done_pending = False
                self.out_int[0] = 2

    def _tick(self) -> None:
        """One cycle of the emulated rtde_control script's main loop (called every 4 ms and
        on every input package): commands 0 → ready; a new command runs once, then signals
        done (``output_int_register_0`` = 2) until the client clears it."""
        with self._lock:
            now = self.clock.now()
            if self.runtime_state != RUNTIME_PLAYING:
                return
            self._advance(now)
            if self.runtime_state != RUNTIME_PLAYING or self._done_pending:
                return   # paused, stopped, or still inside a synchronous move
            cmd = self.in_int[0]
            if cmd in _REALTIME_CMDS:
                log.debug("UR mock: real-time command %d acknowledged without effect", cmd)
                self.out_int[0] = 1
                return
            if cmd == CMD_NO_CMD:
                if self._executing and self._drop_after_command:
                    self._drop_after_command = False
                    log.warning("UR mock: link down after move %d", self.move_count)
                    self._drop_link()
                self._executing = False
                self.out_int[0] = 1
                return
            if self._executing:
                return
            self._executing = True
            if cmd in _MOVE_CMDS:
                self.move_count += 1
                self._drop_after_command = self.faults.drop_connection_at_move == self.move_count
            self._execute(cmd, now)

    def _runtime_error(self, why: str) -> None:
        """A runtime error of the control script: the program stops where the flange is."""
        log.error("UR mock: runtime error in the control script: %s; program stopped", why)
        self._stop_program(f"runtime error: {why}")

    def _bad_move(self, cmd: int) -> str | None:
        """Why the move registers of ``cmd`` cannot be executed (None when they can): the
        pose (or joints), speed and acceleration must be finite, speed and acceleration > 0."""
        d = self.in_double
        vals = [float(x) for x in d[0:8]]
        if not all(math.isfinite(x) for x in vals):
            what = "joint target" if cmd in (CMD_MOVEJ, CMD_MOVEL_FK) else "pose"
            return f"{_MOVE_CMDS[cmd]}: non-finite {what}, speed or acceleration {vals}"
        if cmd in (CMD_MOVEL, CMD_MOVEJ_IK) and not all(math.isfinite(x * 1000.0)
                                                        for x in vals[:3]):
            return f"{_MOVE_CMDS[cmd]}: position {vals[:3]} m is not finite in millimetres"
        if vals[6] <= 0 or vals[7] <= 0:
            return f"{_MOVE_CMDS[cmd]}: speed {vals[6]} and acceleration {vals[7]} must be > 0"
        return None

    def _execute(self, cmd: int, now: float) -> None:
        d = self.in_double
        if cmd in _MOVE_CMDS:
            why = self._bad_move(cmd)
            if why is not None:
                self._runtime_error(why)
                return
        if cmd == CMD_MOVEL:
            pose = pose_from_rotvec(d[0:6])
            speed, asynchronous = d[6], bool(self.in_int[1])
            self._start_motion(pose, speed, asynchronous, now, "moveL")
        elif cmd in (CMD_MOVEJ, CMD_MOVEL_FK, CMD_MOVEJ_IK):
            # No kinematics: joint targets are recorded and reported, the flange stays put;
            # moveJ_IK takes a pose and is executed like moveL.
            if cmd == CMD_MOVEJ_IK:
                self._start_motion(pose_from_rotvec(d[0:6]), d[6], bool(self.in_int[1]), now,
                                   "moveJ_IK")
                return
            self.target_q = [float(v) for v in d[0:6]]
            log.warning("UR mock: %s with joint targets: no kinematics, flange not moved",
                        _MOVE_CMDS[cmd])
            self.out_int[0] = 2
        elif cmd in (CMD_STOPL, CMD_STOPJ):
            self._abort_motion(now)
            self._done_pending = False
            self.out_int[0] = 2
        elif cmd == CMD_STOP_SCRIPT:
            # the script ends without signalling done
            self._stop_program("STOP_SCRIPT command")
        else:
            # getters answer zeros in output_double_register_0.. (e.g. getTCPOffset: zero TCP)
            log.debug("UR mock: command %d acknowledged without effect", cmd)
            for i in range(24):
                self.out_double[i] = 0.0
            self.out_int[0] = 2

    def _start_motion(self, target: np.ndarray, speed: float, asynchronous: bool, now: float,
                      what: str, resumed: bool = False) -> None:
        """Start a linear move of the flange to ``target`` (base_from_flange 4×4 mm) at
        ``speed`` m/s. A synchronous move signals done when it ends (see ``_advance``)."""
        start = self._flange_now(now)
        dist_m = float(np.linalg.norm(target[:3, 3] - start[:3, 3])) / 1000.0
        angle = float(np.linalg.norm(rotvec_from_matrix(start[:3, :3].T @ target[:3, :3])))
        speed = speed if speed > 0 else 0.25
        duration = 0.0 if self.clock.fast else max(dist_m, angle) / speed
        if not (np.isfinite(target).all() and math.isfinite(duration)):
            self._runtime_error(f"{what}: target or duration not finite ({duration} s)")
            return
        self._abort_motion(now)
        stop_at = (0.5 if not resumed and self.faults.protective_stop_at_move == self.move_count
                   else None)
        self._motion = _Motion(start, np.asarray(target, dtype=np.float64).copy(), now,
                               duration, asynchronous, speed, stop_at)
        log.debug("UR mock: %s move %d, %.1f mm, %.3f rad, %.3f s%s", what, self.move_count,
                  dist_m * 1000, angle, duration, " (async)" if asynchronous else "")
        if asynchronous:
            self._write_async(0)
            if not resumed:
                self.out_int[0] = 2
        else:
            self._done_pending = True
        self._advance(now)

    def _script_loop(self) -> None:
        period = 0.004
        nxt = time.monotonic()
        while self._alive():
            self._tick()
            nxt += period
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                nxt = time.monotonic()

    # --- RTDE ---------------------------------------------------------------------------------

    def _value_getters(self, name: str) -> Callable[[float], Any]:
        """A function now → value(s) for output variable ``name`` (typed default if unknown)."""
        m = re.fullmatch(r"(input|output)_(int|double)_register_(\d+)", name)
        if m:
            regs = {("input", "int"): self.in_int, ("input", "double"): self.in_double,
                    ("output", "int"): self.out_int, ("output", "double"): self.out_double}
            arr, i = regs[(m.group(1), m.group(2))], int(m.group(3))
            if i >= _N_REGS:
                return lambda now: 0
            return lambda now: arr[i]
        table: dict[str, Callable[[float], Any]] = {
            "timestamp": lambda now: now - self._t_start,
            "actual_TCP_pose": lambda now: self._tcp_vector(now),
            "target_TCP_pose": lambda now: self._target_tcp_vector(now),
            "actual_TCP_speed": self._tcp_speed,
            "target_TCP_speed": self._tcp_speed,
            "actual_q": lambda now: self.target_q,
            "target_q": lambda now: self.target_q,
            "robot_mode": lambda now: ROBOT_MODE_RUNNING,
            "safety_mode": lambda now: self.safety_mode,
            "safety_status": lambda now: self.safety_mode,
            "safety_status_bits": lambda now: self._safety_status_bits(),
            "runtime_state": lambda now: self.runtime_state,
            "robot_status_bits": lambda now: self._robot_status_bits(),
            "joint_mode": lambda now: [JOINT_RUNNING_MODE] * 6,
            "joint_temperatures": lambda now: [30.0] * 6,
            "actual_joint_voltage": lambda now: [48.0] * 6,
            "actual_main_voltage": lambda now: 48.0,
            "actual_robot_voltage": lambda now: 48.0,
            "actual_robot_current": lambda now: 0.5,
            "speed_scaling": lambda now: 1.0,
            "target_speed_fraction": lambda now: 1.0,
            "actual_execution_time": lambda now: 0.3,
            "actual_tool_accelerometer": lambda now: [0.0, 0.0, 9.81],
            "external_force_torque": lambda now: self.external_force_torque,
            "output_bit_registers0_to_31": lambda now: 0,
            "output_bit_registers32_to_63": lambda now: 0,
        }
        if name in table:
            return table[name]
        t = rtde_type(name)
        zero: Any = {"VECTOR6D": [0.0] * 6, "VECTOR3D": [0.0] * 3, "VECTOR6INT32": [0] * 6,
                     "VECTOR6UINT32": [0] * 6, "DOUBLE": 0.0, "BOOL": False}.get(t, 0)
        return lambda now: zero

    def _tcp_vector(self, now: float) -> list[float]:
        return list(rotvec_pose_from_matrix(self._flange_now(now)))

    def _target_tcp_vector(self, now: float) -> list[float]:
        m = self._motion
        return list(rotvec_pose_from_matrix(m.target)) if m is not None else self._tcp_vector(now)

    def _serve_rtde(self, conn: socket.socket) -> None:
        _RTDEConnection(self, conn).run()

    # --- dashboard ----------------------------------------------------------------------------

    def _dashboard_reply(self, line: str) -> tuple[str, bool]:
        """The dashboard server's answer to one command line, and whether to hang up."""
        cmd = line.strip()
        low = cmd.lower()
        v = ".".join(str(x) for x in self.version)
        with self._lock:
            name = "rtde_control"
            state = {RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED"}.get(
                self.runtime_state, "STOPPED")
            if low == "polyscopeversion":
                return f"URSoftware {v} (Mar 24 2021)", False
            if low == "get serial number":
                return self.serial, False
            if low == "get robot model":
                return self.model, False
            if low == "is in remote control":
                return "true", False
            if low == "stop":
                # A real controller answers "Stopped" even when the program has just ended
                # (ur_rtde sends STOP_SCRIPT and then "stop", and insists on "Stopped").
                if self.runtime_state != RUNTIME_STOPPED:
                    self._stop_program("dashboard stop")
                return "Stopped", False
            if low == "play":
                if not self._program_loaded:
                    return "Failed to execute: play", False
                if self.safety_mode != SAFETY_NORMAL:
                    return "Failed to execute: play", False
                if self.runtime_state == RUNTIME_PAUSED:
                    self._resume()
                else:
                    self._start_program("dashboard play")
                return "Starting program", False
            if low == "pause":
                if self.runtime_state != RUNTIME_PLAYING:
                    return "Failed to execute: pause", False
                self._pause()
                return "Pausing program", False
            if low == "unlock protective stop":
                self.safety_mode = SAFETY_NORMAL
                return "Protective stop releasing", False
            if low == "close safety popup":
                return "closing safety popup", False
            if low == "close popup":
                return "closing popup", False
            if low.startswith("popup "):
                return "showing popup", False
            if low == "running":
                return f"Program running: {str(self.runtime_state == RUNTIME_PLAYING).lower()}", \
                    False
            if low == "programstate":
                return f"{state} {name}.urp", False
            if low == "get loaded program":
                return (f"Loaded program: /programs/{name}.urp" if self._program_loaded
                        else "No program loaded"), False
            if low == "isprogramsaved":
                return f"true {name}.urp", False
            if low == "robotmode":
                return "Robotmode: RUNNING", False
            if low in ("safetymode", "safetystatus"):
                s = "PROTECTIVE_STOP" if self.protective_stopped else "NORMAL"
                return f"{'Safetymode' if low == 'safetymode' else 'Safetystatus'}: {s}", False
            if low == "power on":
                return "Powering on", False
            if low == "power off":
                return "Powering off", False
            if low == "brake release":
                return "Brake releasing", False
            if low == "restart safety":
                self.safety_mode = SAFETY_NORMAL
                return "Restarting safety", False
            if low.startswith("load "):
                return f"Loading program: {cmd[5:]}", False
            if low.startswith("addtolog "):
                return "Added log message", False
            if low.startswith("setuserrole "):
                return "Setting user role: " + cmd[12:], False
            if low == "quit":
                return "Disconnected", True
            if low == "shutdown":
                return "Shutting down", True
        return f"could not understand: '{cmd}'", False

    def _serve_dashboard(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buf = b""
        while self._alive():
            try:
                chunk = conn.recv(4096)
            except TimeoutError:
                continue
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                raw, buf = buf.split(b"\n", 1)
                line = raw.decode("utf-8", "replace").strip()
                if not line:
                    continue
                self.dashboard_log.append(line)
                reply, hang_up = self._dashboard_reply(line)
                log.debug("UR mock dashboard: %r -> %r", line, reply)
                conn.sendall(reply.encode() + b"\n")
                if hang_up:
                    return
            if len(buf) > 65536:
                log.warning("UR mock dashboard: line too long, dropping the connection")
                return

    # --- script port --------------------------------------------------------------------------

    def _serve_script(self, conn: socket.socket) -> None:
        buf = bytearray()
        while self._alive():
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                chunk = None
            if chunk == b"":
                self._take_script(bytes(buf))
                return
            if chunk:
                buf += chunk
                if len(buf) > 4_000_000:
                    log.warning("UR mock script port: script too large, dropped")
                    return
            if self._take_script(bytes(buf)):
                buf.clear()

    def _take_script(self, data: bytes) -> bool:
        """Run a complete program (``def name(): … end`` at column 0, or ``sec``). True if
        ``data`` held one."""
        text = data.decode("utf-8", "replace")
        stripped = text.rstrip()
        m = re.match(r"\s*(def|sec)\s+(\w+)\s*\(", text)
        if not m or not re.search(r"(^|\n)end$", stripped):
            return False
        self.last_script = text
        self.scripts_received += 1
        log.info("UR mock: received program %r (%d bytes)", m.group(2), len(data))
        with self._lock:
            self._start_program(f"script {m.group(2)!r} uploaded")
        return True


class _RTDEConnection:
    """One RTDE client: setup requests answered in order, then a streaming thread."""

    def __init__(self, mock: URMock, conn: socket.socket) -> None:
        self.mock = mock
        self.conn = conn
        self.send_lock = threading.Lock()
        self.output_names: list[str] = []
        self.output_struct: struct.Struct | None = None
        self.output_getters: list[tuple[Callable[[float], Any], bool]] = []
        self.frequency = 125.0
        self.output_refused = False   # an output recipe was refused (bad frequency)
        self.inputs: dict[int, tuple[list[str], struct.Struct]] = {}
        self.streaming = threading.Event()
        self.closed = threading.Event()
        self.stream_thread: threading.Thread | None = None

    def alive(self) -> bool:
        return self.mock._alive() and not self.closed.is_set()

    def send(self, ptype: int, payload: bytes = b"") -> None:
        with self.send_lock:
            self.conn.sendall(struct.pack(">HB", 3 + len(payload), ptype) + payload)

    def run(self) -> None:
        try:
            while self.alive():
                head = _recv_exact(self.conn, 3, self.alive)
                if head is None:
                    return
                size, ptype = struct.unpack(">HB", head)
                if size < 3:
                    log.warning("UR mock RTDE: bad package size %d; closing", size)
                    return
                payload = _recv_exact(self.conn, size - 3, self.alive)
                if payload is None:
                    return
                self.handle(ptype, payload)
        finally:
            self.closed.set()
            self.streaming.clear()

    def handle(self, ptype: int, payload: bytes) -> None:
        mock = self.mock
        if ptype == _V:
            version = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else 0
            self.send(_V, bytes([1 if version in (1, 2) else 0]))
        elif ptype == _v:
            self.send(_v, struct.pack(">IIII", *mock.version))
        elif ptype == _O:
            if len(payload) < 8:
                self.send(_O, b"\x00")
                return
            freq = struct.unpack(">d", payload[:8])[0]
            if not (math.isfinite(freq) and MIN_FREQUENCY_HZ <= freq <= MAX_FREQUENCY_HZ):
                log.warning("UR mock RTDE: output frequency %r Hz outside [%g, %g]: recipe "
                            "refused", freq, MIN_FREQUENCY_HZ, MAX_FREQUENCY_HZ)
                self.output_refused = True
                self.send(_O, b"\x00")
                return
            self.frequency = freq
            names = [n for n in payload[8:].decode("ascii", "replace").split(",") if n]
            types = [rtde_type(n) for n in names]
            self.output_names = names
            self.output_struct = struct.Struct(">B" + "".join(_TYPE_FMT[t] for t in types))
            self.output_getters = [(mock._value_getters(n), _TYPE_FMT[t][0].isdigit())
                                   for n, t in zip(names, types, strict=True)]
            log.debug("UR mock RTDE: output recipe at %.0f Hz: %s", self.frequency,
                      ",".join(names))
            self.send(_O, b"\x01" + ",".join(types).encode())
        elif ptype == _I:
            names = [n for n in payload.decode("ascii", "replace").split(",") if n]
            types = [rtde_type(n) for n in names]
            rid = len(self.inputs) + 1
            self.inputs[rid] = (names, struct.Struct(">" + "".join(_TYPE_FMT[t] for t in types)))
            log.debug("UR mock RTDE: input recipe %d: %s", rid, ",".join(names))
            self.send(_I, bytes([rid & 0xFF]) + ",".join(types).encode())
        elif ptype == _S:
            if self.output_refused and self.output_struct is None:
                self.send(_S, b"\x00")  # the output recipe was refused: nothing to stream
                return
            self.send(_S, b"\x01")
            self.streaming.set()
            if self.stream_thread is None and self.output_struct is not None:
                self.stream_thread = threading.Thread(target=self.stream, daemon=True,
                                                      name="ur-rtde-stream")
                self.stream_thread.start()
        elif ptype == _P:
            self.streaming.clear()
            self.send(_P, b"\x01")
        elif ptype == _U:
            self.input(payload)
        else:
            log.debug("UR mock RTDE: ignoring package type %r (%d bytes)", chr(ptype),
                      len(payload))

    def input(self, payload: bytes) -> None:
        if not payload:
            return
        rid = payload[0]
        recipe = self.inputs.get(rid)
        if recipe is None:
            log.warning("UR mock RTDE: data for unknown input recipe %d ignored", rid)
            return
        names, st = recipe
        if len(payload) - 1 != st.size:
            log.warning("UR mock RTDE: input recipe %d: %d bytes, expected %d; ignored", rid,
                        len(payload) - 1, st.size)
            return
        values = list(st.unpack(payload[1:]))
        mock = self.mock
        with mock._lock:
            for name in names:
                t = rtde_type(name)
                n = {"VECTOR6D": 6, "VECTOR3D": 3, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}.get(t, 1)
                val, values = values[:n], values[n:]
                m = re.fullmatch(r"input_(int|double)_register_(\d+)", name)
                if m and int(m.group(2)) < _N_REGS:
                    arr = mock.in_int if m.group(1) == "int" else mock.in_double
                    arr[int(m.group(2))] = val[0]
                elif name == "external_force_torque":
                    mock.external_force_torque = [float(x) for x in val]
            log.debug("UR mock RTDE: input recipe %d, cmd %d (runtime_state %d, "
                      "output_int_register_0 %d)", rid, mock.in_int[0], mock.runtime_state,
                      mock.out_int[0])
        mock._tick()

    def stream(self) -> None:
        """Send the output recipe at the requested frequency (wall-clock on every clock)."""
        assert self.output_struct is not None
        period = 1.0 / min(max(self.frequency, MIN_FREQUENCY_HZ), MAX_FREQUENCY_HZ)
        nxt = time.monotonic()
        mock = self.mock
        try:
            while self.alive():
                if self.streaming.is_set():
                    values: list[Any] = [1]
                    with mock._lock:
                        now = mock.clock.now()
                        for getter, is_vector in self.output_getters:
                            v = getter(now)
                            if is_vector:
                                values.extend(v)
                            else:
                                values.append(v)
                    self.send(_U, self.output_struct.pack(*values))
                nxt += period
                delay = nxt - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                elif delay < -0.1:
                    nxt = time.monotonic()
        except OSError as e:
            log.debug("UR mock RTDE stream ended: %s", e)
        finally:
            self.closed.set()
