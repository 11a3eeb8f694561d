"""The simulated UR controller behind the mock's servers: the emulated ``rtde_control`` script
(ur_rtde's register handshake), the program's runtime state, linear motion of the sim rig's
flange, the protective stop, and the values RTDE streams. No sockets here: the servers
(``servers.py``) feed register writes in and read variables out, under ``self._lock``.

The handshake: the command id arrives in ``input_int_register_0`` (``moveL``: cmd 3, pose in
``input_double_register_0..5`` as metres and rotation vector, speed in ``_6`` m/s,
acceleration in ``_7``, asynchronous flag in ``input_int_register_1``);
``output_int_register_0`` is 1 when ready and 2 when the command is done; asynchronous
progress is in ``output_int_register_2`` (bit 15 running, bits 16–23 change count).
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import InitVar, dataclass
from typing import Any

import numpy as np

from ...geometry import (
    invert,
    pose_from_rotvec,
    rotvec_pose_from_matrix,
)
from ...sim.arm import Unreachable
from ...sim.rig import SimRig
from ..clock import REAL_TIME, Clock
from ..wrench import URWrenchOutputs
from .motion import Motion
from .rtde import rtde_type, zero_value

log = logging.getLogger(__name__)

# Controller constants (UR e-Series / CB3 RTDE definitions).
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = 1, 2, 4
ROBOT_MODE_POWER_OFF, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING = 3, 5, 7
#: RTDE ``robot_mode`` values as the dashboard's ``robotmode`` names them
ROBOT_MODE_NAMES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING",
                    3: "POWER_OFF", 4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING"}
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = 1, 3
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE, SAFETY_BIT_STOPPED_BY_SAFETY = 1 << 0, 1 << 2, 1 << 10
ROBOT_BIT_POWER_ON, ROBOT_BIT_PROGRAM_RUNNING = 1 << 0, 1 << 1
JOINT_RUNNING_MODE = 253

# ur_rtde command ids (input_int_register_0)
CMD_NO_CMD, CMD_MOVEJ, CMD_MOVEJ_IK, CMD_MOVEL, CMD_MOVEL_FK = 0, 1, 2, 3, 4
CMD_STOPL, CMD_STOPJ, CMD_WATCHDOG, CMD_STOP_SCRIPT = 33, 34, 99, 255
CMD_GET_TCP_OFFSET = 40
#: commands the script processes and acknowledges with "ready" at once (servo, speed, …)
REALTIME_CMDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71})
MOVE_CMDS = {CMD_MOVEJ: "moveJ", CMD_MOVEJ_IK: "moveJ_IK", CMD_MOVEL: "moveL",
             CMD_MOVEL_FK: "moveL_FK"}

#: Placeholder joint angles (rad) reported as actual_q / target_q by a mock without an arm
#: (no ``mock.kinematics``); with one, they are the rig's joints.
HOME_Q = (0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)

#: Number of input/output int and double registers.
N_REGISTERS = 48
_REGISTER = re.compile(r"(input|output)_(int|double)_register_(\d+)")
#: Cycle of the emulated control script's main loop (s).
SCRIPT_PERIOD_S = 0.004

#: Output variables whose value never changes in the mock.
CONSTANT_OUTPUTS: dict[str, Any] = {
    "joint_mode": [JOINT_RUNNING_MODE] * 6,
    "joint_temperatures": [30.0] * 6, "actual_joint_voltage": [48.0] * 6,
    "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0, "actual_robot_current": 0.5,
    "speed_scaling": 1.0, "target_speed_fraction": 1.0, "actual_execution_time": 0.3,
    "actual_tool_accelerometer": [0.0, 0.0, 9.81], "output_bit_registers0_to_31": 0,
    "output_bit_registers32_to_63": 0,
}


@dataclass(frozen=True)
class URFaults:
    """Faults to inject. Moves (moveL, moveJ, moveL_FK, moveJ_IK) are counted from 1.

    ``protective_stop_at_move``: the k-th move triggers a protective stop half-way (the control
    script stops; the client's ``moveL`` fails). ``power_off_at_move``: the robot is powered
    off (robot mode POWER_OFF) half-way through the k-th move, as when someone presses the
    pendant's power button; the program stops. ``drop_at_move``: the network link fails during
    the k-th move: the controller finishes that move, and when the client clears the command
    every client socket (RTDE, dashboard, script) is shut down and the listeners close, so
    reconnects are refused (named like the DENSO mock's ``drop_at_request``; the earlier name
    ``drop_connection_at_move`` is still accepted). None disables a fault. (Dropping the
    link while ur_rtde 1.6.5 waits inside a call makes the library hang, or segfault when it
    can reconnect.) ``non_utf8_dashboard_reply``: the dashboard answers this command (case
    and surrounding blanks ignored, e.g. ``"get serial number"``) with its reply wrapped in
    bytes that are not UTF-8 (``\xff\xfe`` … ``\x80``), as a corrupt or foreign server might.
    """

    protective_stop_at_move: int | None = None
    drop_at_move: int | None = None
    power_off_at_move: int | None = None
    drop_connection_at_move: InitVar[int | None] = None
    non_utf8_dashboard_reply: str | None = None

    def __post_init__(self, drop_connection_at_move: int | None) -> None:
        if drop_connection_at_move is None:
            return
        if self.drop_at_move is not None and self.drop_at_move != drop_connection_at_move:
            raise ValueError("URFaults: drop_at_move and drop_connection_at_move (its earlier "
                             "name) disagree; give one")
        object.__setattr__(self, "drop_at_move", drop_connection_at_move)


# The InitVar's class attribute would always read None: read the field it stands for.
URFaults.drop_connection_at_move = property(  # type: ignore[attr-defined]
    lambda self: self.drop_at_move, doc="The earlier name of ``drop_at_move``.")


class URController:
    """The controller state machine serving ``rig`` (see the module docstring).

    ``clock``: ``REAL_TIME``, moves take their trapezoidal profile's time (``motion``);
    ``FAST``, they complete at once (``last_motion_s`` holds the modelled time on both).
    ``faults``: ``URFaults`` to inject. ``program_running``: a control program runs at
    start (runtime_state 2, ready); False, the controller starts stopped. ``robot_mode``
    (RTDE values, ``ROBOT_MODE_RUNNING`` by default; ``ROBOT_MODE_POWER_OFF``: powered off)
    and ``remote_control`` (the pendant's Remote/Local Control switch) are the operator's:
    a program starts only on a RUNNING robot, with no protective stop, and (over the network)
    in remote control, as on an e-Series controller. State is guarded
    by ``_lock``; ``_tick()`` is one cycle of the control script. ``_link_down()`` is the
    hook a server fills to drop its connections (the ``drop_at_move`` fault).
    """

    def __init__(self, rig: SimRig, clock: Clock = REAL_TIME, faults: URFaults = URFaults(),
                 program_running: bool = True, robot_mode: int = ROBOT_MODE_RUNNING,
                 remote_control: bool = True, tcp_offset: np.ndarray | None = None) -> None:
        self.rig = rig
        #: the active TCP, flange_from_tcp 4×4 mm (``getTCPOffset``; None: TCP = flange):
        #: RTDE reports and moveL commands the TCP, which moves on the straight line
        self.flange_from_tcp = np.eye(4) if tcp_offset is None else \
            np.array(tcp_offset, dtype=np.float64)
        if self.flange_from_tcp.shape != (4, 4) or not np.isfinite(self.flange_from_tcp).all():
            raise ValueError("URController: tcp_offset must be a finite 4×4 pose (mm)")
        #: every move the controller started, oldest first (bounded): each ``Motion`` gives
        #: the flange it executes at any time (``pose_at_time``), for tests of the path
        self.trajectory: deque[Motion] = deque(maxlen=10_000)
        self.clock = clock
        self.faults = faults
        self.move_count = 0
        self._lock = threading.RLock()
        self._t_start = time.monotonic()
        self.in_int = [0] * N_REGISTERS
        self.in_double = [0.0] * N_REGISTERS
        self.out_int = [0] * N_REGISTERS
        self.out_double = [0.0] * N_REGISTERS
        self.external_force_torque = [0.0] * 6
        #: ft_raw_wrench and actual_TCP_force (``tmscal.mocks.wrench.URWrenchOutputs``;
        #: None: both read zero)
        self.wrench: URWrenchOutputs | None = None
        self.safety_mode = SAFETY_NORMAL
        self.robot_mode = int(robot_mode)
        self.remote_control = bool(remote_control)
        program_running = program_running and self.robot_mode == ROBOT_MODE_RUNNING
        self.runtime_state = RUNTIME_PLAYING if program_running else RUNTIME_STOPPED
        self.target_q = list(HOME_Q)
        self._program_loaded = program_running
        self._executing = False
        self._motion: Motion | None = None
        #: modelled duration (s) of the last move's trapezoidal profile, on every clock (the
        #: fast clock does not wait for it), and of every move, oldest first (bounded)
        self.last_motion_s: float | None = None
        self.motion_log: deque[float] = deque(maxlen=100_000)
        #: every move command as the control script read it from the RTDE input registers,
        #: oldest first (bounded): {"command": "moveL", "target": the six pose (m, rad) or
        #: joint (rad) values, "speed": m/s (rad/s), "accel": m/s² (rad/s²), "async": bool}
        self.received_moves: deque[dict[str, Any]] = deque(maxlen=100_000)
        self._interrupted: Motion | None = None   # resumed by dashboard "play"
        self._async_wr_count = 0
        self._async_op_id = 0
        self._done_pending = False     # a sync command waits for its motion to finish
        self._drop_after_command = False
        if program_running:
            self.out_int[0] = 1
            self._write_async(-1)

    def _link_down(self) -> None:
        """The network link fails (filled by the servers; nothing to drop here)."""

    def _motion_started(self) -> None:
        """A move began (filled by the servers: the script loop ticks while one runs)."""

    # --- status -------------------------------------------------------------------------------

    @property
    def protective_stopped(self) -> bool:
        return self.safety_mode == SAFETY_PROTECTIVE_STOP

    def _safety_status_bits(self) -> int:
        if self.safety_mode == SAFETY_PROTECTIVE_STOP:
            return SAFETY_BIT_PROTECTIVE | SAFETY_BIT_STOPPED_BY_SAFETY
        return SAFETY_BIT_NORMAL

    def _robot_status_bits(self) -> int:
        bits = ROBOT_BIT_POWER_ON if self.robot_mode > ROBOT_MODE_POWER_OFF else 0
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
            T = self._flange_now(self.clock.now()) @ self.flange_from_tcp
        return [float(v) for v in rotvec_pose_from_matrix(T)]

    # --- RTDE variables -----------------------------------------------------------------------

    def value_getter(self, name: str) -> Callable[[float], Any]:
        """A function now → value(s) of output variable ``name`` (typed zero if unknown)."""
        regs = self._registers(name)
        if regs is not None:
            arr, i = regs
            return (lambda now: 0) if i >= N_REGISTERS else (lambda now: arr[i])
        if name in CONSTANT_OUTPUTS:
            value = CONSTANT_OUTPUTS[name]
            return lambda now: value
        table: dict[str, Callable[[float], Any]] = {
            "timestamp": lambda now: now - self._t_start,
            "actual_TCP_pose": self._tcp_vector,
            "target_TCP_pose": self._target_tcp_vector,
            "actual_TCP_speed": self._tcp_speed,
            "target_TCP_speed": self._tcp_speed,
            "actual_q": lambda now: self._joints(),
            "target_q": lambda now: self._joints(),
            "robot_mode": lambda now: self.robot_mode,
            "safety_mode": lambda now: self.safety_mode,
            "safety_status": lambda now: self.safety_mode,
            "safety_status_bits": lambda now: self._safety_status_bits(),
            "runtime_state": lambda now: self.runtime_state,
            "robot_status_bits": lambda now: self._robot_status_bits(),
            "external_force_torque": lambda now: self.external_force_torque,
            "ft_raw_wrench": lambda now: [0.0] * 6 if self.wrench is None else self.wrench.raw(),
            "actual_TCP_force": lambda now: [0.0] * 6 if self.wrench is None
            else self.wrench.tcp(self._flange_now(now)),
        }
        if name in table:
            return table[name]
        zero = zero_value(rtde_type(name))
        return lambda now: zero

    def write_input(self, name: str, values: list[Any]) -> None:
        """An input variable from a client's data package (call with ``_lock`` held)."""
        regs = self._registers(name, inputs_only=True)
        if regs is not None and regs[1] < N_REGISTERS:
            regs[0][regs[1]] = values[0]
        elif name == "external_force_torque":
            self.external_force_torque = [float(x) for x in values]

    def _registers(self, name: str, inputs_only: bool = False) -> tuple[list[Any], int] | None:
        """(register array, index) for ``{input,output}_{int,double}_register_N``."""
        m = _REGISTER.fullmatch(name)
        if m is None or (inputs_only and m.group(1) != "input"):
            return None
        arrays: dict[tuple[str, str], list[Any]] = {
            ("input", "int"): self.in_int, ("input", "double"): self.in_double,
            ("output", "int"): self.out_int, ("output", "double"): self.out_double}
        return arrays[(m.group(1), m.group(2))], int(m.group(3))

    def _joints(self) -> list[float]:
        """actual_q / target_q (rad): the rig's joints when it has an arm (``mock.kinematics``),
        else the last joint target (placeholders: no kinematics)."""
        q = self.rig.joints()
        return self.target_q if q is None else [float(v) for v in q]

    def _tcp_vector(self, now: float) -> list[float]:
        return list(rotvec_pose_from_matrix(self._flange_now(now) @ self.flange_from_tcp))

    def _target_tcp_vector(self, now: float) -> list[float]:
        m = self._motion
        return list(rotvec_pose_from_matrix(m.target)) if m is not None else self._tcp_vector(now)

    def _tcp_speed(self, now: float) -> list[float]:
        m = self._motion
        return [0.0] * 6 if m is None else m.velocity(now)

    # --- the program --------------------------------------------------------------------------

    def _reset_script(self, runtime_state: int) -> None:
        """Stop any motion and forget the script's command state."""
        self._abort_motion()
        self._interrupted = None
        self._executing = False
        self._done_pending = False
        self.runtime_state = runtime_state

    def _start_program(self, why: str) -> None:
        """(Re)start the emulated rtde_control script: clean state, ready for a command."""
        self._reset_script(RUNTIME_PLAYING)
        self._program_loaded = True
        self.out_int[0] = 1
        self._write_async(-1)
        log.info("UR mock: control script running (%s)", why)

    def why_no_program(self, network: bool) -> str | None:
        """Why the controller would refuse to start a program now (None: it would start it):
        the robot is not RUNNING (powered off, brakes engaged), a protective stop is active,
        or (``network``: the program comes over the script port, not from the pendant) the
        robot is in local control."""
        if self.robot_mode != ROBOT_MODE_RUNNING:
            return f"robot mode {ROBOT_MODE_NAMES.get(self.robot_mode, self.robot_mode)}"
        if self.safety_mode != SAFETY_NORMAL:
            return "protective stop"
        if network and not self.remote_control:
            return "local control (remote control is off)"
        return None

    def power_off(self, why: str = "power off") -> None:
        """The robot is powered off: motion stops where it is, the program stops."""
        with self._lock:
            self._stop_program(why)
            self.robot_mode = ROBOT_MODE_POWER_OFF
            log.warning("UR mock: robot powered off (%s)", why)

    def power_on(self) -> None:
        """Power on (robot mode IDLE: brakes still engaged)."""
        with self._lock:
            if self.robot_mode == ROBOT_MODE_POWER_OFF:
                self.robot_mode = ROBOT_MODE_IDLE

    def release_brakes(self) -> None:
        """Brake release: an IDLE robot becomes RUNNING."""
        with self._lock:
            if self.robot_mode == ROBOT_MODE_IDLE:
                self.robot_mode = ROBOT_MODE_RUNNING

    def set_remote_control(self, on: bool) -> None:
        """The pendant's Remote/Local Control switch."""
        with self._lock:
            self.remote_control = bool(on)

    def _stop_program(self, why: str) -> None:
        self._reset_script(RUNTIME_STOPPED)
        log.info("UR mock: program stopped (%s)", why)

    def _runtime_error(self, why: str) -> None:
        """A runtime error of the control script: the program stops where the flange is."""
        log.error("UR mock: runtime error in the control script: %s; program stopped", why)
        self._stop_program(f"runtime error: {why}")

    def _halt(self, m: Motion, fraction: float) -> None:
        """Put the flange where motion ``m`` is at ``fraction`` and end the motion (an arm
        that cannot reach a point of the path stays where it was)."""
        try:
            self.rig.move_flange(m.pose_at(fraction))
        except Unreachable as e:
            log.error("UR mock: %s; the arm stays where it was", e)
        self._motion = None

    def _abort_motion(self, now: float | None = None) -> None:
        """Stop the flange where it is now (decelerations are not modelled)."""
        m = self._motion
        if m is None:
            return
        self._halt(m, m.fraction(self.clock.now() if now is None else now))
        if m.asynchronous:
            self._write_async(-1)

    def _pause(self) -> None:
        """Pause the program (dashboard ``pause`` or a protective stop): the flange stops where
        it is and a running move resumes on ``play``."""
        m = self._motion
        if m is not None:
            self._halt(m, m.fraction(self.clock.now()))
            self._interrupted = m
        self.runtime_state = RUNTIME_PAUSED

    def _resume(self) -> None:
        m, self._interrupted = self._interrupted, None
        self.runtime_state = RUNTIME_PLAYING
        if m is not None:
            self._start_motion(m.target, m.speed, m.accel, m.asynchronous, self.clock.now(),
                               "resumed move", resumed=True)

    def _protective_stop(self, m: Motion) -> None:
        """A fault half-way through motion ``m``: the flange stops there and the control
        script stops (runtime_state STOPPED); it runs again only when re-uploaded (or played
        from the dashboard) after the stop is cleared. ``m.stop_kind`` "power_off": the robot
        is powered off instead of protective-stopped."""
        f = m.stop_fraction if m.stop_fraction is not None else 0.5
        self._halt(m, f)
        if m.asynchronous:
            self._write_async(-1)
        if m.stop_kind == "power_off":
            self.power_off(f"power off during move {self.move_count}")
            return
        self.safety_mode = SAFETY_PROTECTIVE_STOP
        self._stop_program(f"protective stop during move {self.move_count}")
        log.warning("UR mock: PROTECTIVE STOP during move %d (flange stopped at %.0f%%)",
                    self.move_count, 100 * f)

    # --- the control script's cycle -----------------------------------------------------------

    def _advance(self, now: float) -> None:
        """Finish or interrupt the running motion according to the clock."""
        m = self._motion
        if m is None:
            return
        if m.stop_fraction is not None and (self.clock.fast or m.fraction(now) >= m.stop_fraction):
            self._protective_stop(m)
            return
        if self.clock.fast or m.fraction(now) >= 1.0:
            self._halt(m, 1.0)
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
            if cmd in REALTIME_CMDS:
                log.debug("UR mock: real-time command %d acknowledged without effect", cmd)
                self.out_int[0] = 1
                return
            if cmd == CMD_NO_CMD:
                self._command_cleared()
                return
            if self._executing:
                return
            self._executing = True
            if cmd in MOVE_CMDS:
                self.move_count += 1
                self._drop_after_command = self.faults.drop_at_move == self.move_count
            self._execute(cmd, now)

    def _command_cleared(self) -> None:
        """The client cleared the command: ready again (the link drops here when the
        ``drop_at_move`` fault fired for the command just done)."""
        if self._executing and self._drop_after_command:
            self._drop_after_command = False
            log.warning("UR mock: link down after move %d", self.move_count)
            self._link_down()
        self._executing = False
        self.out_int[0] = 1

    def _bad_move(self, cmd: int) -> str | None:
        """Why the move registers of ``cmd`` cannot be executed (None when they can): the
        pose (or joints), speed and acceleration must be finite, speed and acceleration > 0."""
        vals = [float(x) for x in self.in_double[0:8]]
        if not all(math.isfinite(x) for x in vals):
            what = "joint target" if cmd in (CMD_MOVEJ, CMD_MOVEL_FK) else "pose"
            return f"{MOVE_CMDS[cmd]}: non-finite {what}, speed or acceleration {vals}"
        if cmd in (CMD_MOVEL, CMD_MOVEJ_IK) and not all(math.isfinite(x * 1000.0)
                                                        for x in vals[:3]):
            return f"{MOVE_CMDS[cmd]}: position {vals[:3]} m is not finite in millimetres"
        if vals[6] <= 0 or vals[7] <= 0:
            return f"{MOVE_CMDS[cmd]}: speed {vals[6]} and acceleration {vals[7]} must be > 0"
        return None

    def _execute(self, cmd: int, now: float) -> None:
        d = self.in_double
        if cmd in MOVE_CMDS:
            self.received_moves.append({
                "command": MOVE_CMDS[cmd], "target": [float(x) for x in d[0:6]],
                "speed": float(d[6]), "accel": float(d[7]), "async": bool(self.in_int[1])})
            why = self._bad_move(cmd)
            if why is not None:
                self._runtime_error(why)
                return
        if cmd in (CMD_MOVEL, CMD_MOVEJ_IK):
            # moveJ_IK takes a pose and is executed like moveL
            self._start_motion(pose_from_rotvec(d[0:6]), d[6], d[7], bool(self.in_int[1]),
                               now, MOVE_CMDS[cmd])
        elif cmd in (CMD_MOVEJ, CMD_MOVEL_FK):
            # No kinematics: joint targets are recorded and reported, the flange stays put.
            self.target_q = [float(v) for v in d[0:6]]
            log.warning("UR mock: %s with joint targets: no kinematics, flange not moved",
                        MOVE_CMDS[cmd])
            self.out_int[0] = 2
        elif cmd in (CMD_STOPL, CMD_STOPJ):
            self._abort_motion(now)
            self._done_pending = False
            self.out_int[0] = 2
        elif cmd == CMD_STOP_SCRIPT:
            # the script ends without signalling done
            self._stop_program("STOP_SCRIPT command")
        elif cmd == CMD_GET_TCP_OFFSET:   # get_tcp_offset() into output_double_register_0..5
            self.out_double[0:6] = [float(v) for v in
                                    rotvec_pose_from_matrix(self.flange_from_tcp)]
            self.out_int[0] = 2
        else:
            # getters answer zeros in output_double_register_0.. (e.g. getTCPOffset: zero TCP)
            log.debug("UR mock: command %d acknowledged without effect", cmd)
            for i in range(24):
                self.out_double[i] = 0.0
            self.out_int[0] = 2

    def _start_motion(self, target: np.ndarray, speed: float, accel: float,
                      asynchronous: bool, now: float, what: str, resumed: bool = False) -> None:
        """Start a linear move of the TCP to ``target`` (base_from_tcp 4×4 mm; the flange
        when TCP = flange) on a trapezoidal profile capped at ``speed`` m/s and ``accel`` m/s²
        (rad/s, rad/s² for the rotation; see :mod:`.motion`). Its modelled duration goes to
        ``last_motion_s`` on every clock, the motion to ``trajectory``; on the real-time
        clock the rig's flange follows the profile. A synchronous move signals done when it
        ends (see ``_advance``)."""
        start = self._flange_now(now) @ self.flange_from_tcp
        speed = speed if speed > 0 else 0.25
        accel = accel if accel > 0 else 1.2
        target = np.asarray(target, dtype=np.float64).copy()
        if not np.isfinite(target).all():
            self._runtime_error(f"{what}: target not finite")
            return
        try:   # a speed or acceleration too large to scale (e.g. 1e307 m/s) is refused
            m = Motion(start, target, now, asynchronous, speed, accel, instant=self.clock.fast,
                       flange_from_tcp=self.flange_from_tcp)
        except ValueError as e:
            self._runtime_error(f"{what}: {e}")
            return
        if not math.isfinite(m.modelled_s):
            self._runtime_error(f"{what}: duration not finite ({m.modelled_s} s)")
            return
        # an arm (mock.kinematics) that cannot get there
        if self.rig.reach(target @ invert(self.flange_from_tcp)) is None:
            self._runtime_error(f"{what}: no inverse kinematics solution for the target "
                                "within the joint limits (out of reach)")
            return
        self._abort_motion(now)
        if not resumed and self.faults.protective_stop_at_move == self.move_count:
            m.stop_fraction = 0.5
        elif not resumed and self.faults.power_off_at_move == self.move_count:
            m.stop_fraction, m.stop_kind = 0.5, "power_off"
        self._motion = m
        self._motion_started()
        self.trajectory.append(m)
        self.last_motion_s = m.modelled_s
        self.motion_log.append(m.modelled_s)
        if m.duration > 0:
            clock = self.clock
            self.rig.follow(lambda: m.pose_at(m.fraction(clock.now())))
        log.debug("UR mock: %s move %d, %.1f mm, %.3f s%s", what, self.move_count,
                  float(np.linalg.norm(target[:3, 3] - start[:3, 3])), m.modelled_s,
                  " (async)" if asynchronous else "")
        if asynchronous:
            self._write_async(0)
            if not resumed:
                self.out_int[0] = 2
        else:
            self._done_pending = True
        self._advance(now)
