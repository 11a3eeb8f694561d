"""The simulated RC8 controller behind the DENSO mock: its shared state (motor, speeds,
variables, the rig), the per-connection state (handles, arm, watchdog, motion) and one small
handler per b-CAP function, looked up in a table by function ID. The data classes (faults,
motions, connections) live in ``state.py``.

A handler takes the connection's :class:`Session`, the request's serial and its arguments
(padded with EMPTY to four) and returns the reply's value (None: no value; ``DEFERRED``: the
reply comes when the motion ends), or raises :class:`~.args.Refusal` with an error HRESULT.
"""

from __future__ import annotations

import itertools
import logging
import math
import re
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from ...drivers.denso.hresult import (
    E_ACCESSDENIED,
    E_CAO_OBJECT_NOTFOUND,
    E_HANDLE,
    E_INVALIDARG,
    E_MOTOR_OFF,
    E_NOTIMPL,
    hresult_name,
)
from ...drivers.denso.packet import Fn, function_name
from ...drivers.denso.robot import DEFAULT_MAX_LINEAR_ACCEL_MM_S2
from ...drivers.denso.variant import (
    NUMERIC_VTS,
    VT_ARRAY,
    VT_BOOL,
    VT_BSTR,
    VT_EMPTY,
    VT_I4,
    VT_R4,
    VT_R8,
    VT_VARIANT,
    Variant,
)
from ...geometry import denso_p_from_matrix, matrix_from_denso_p
from ...motion import Trapezoid
from ...sim.arm import Unreachable
from ...sim.rig import SimRig, straight_path
from ..clock import Clock
from . import args
from .args import PCT_MIN, Refusal
from .state import DensoFaults, Executed, Job, Session

log = logging.getLogger(__name__)

#: Watchdog periods (ms) Service_Start accepts (0 = off).
WDT_MIN_MS, WDT_MAX_MS = 10, 3_600_000
#: A handler's answer when the reply is sent later (when a blocking move ends).
DEFERRED = object()
#: On the real-time clock, how long before the arm is still a pass (``@0``) or ``@P`` move
#: replies (s): the command has reached the target, the servo has not (RC8 manuals).
SETTLE_S = 0.05

_CONTROLLER_VARIABLES = ("@VERSION", "@MODE")
_ROBOT_VARIABLES = ("@CURRENT_POSITION", "@CURRENT_ANGLE", "@TYPE_NAME")
#: ``@TYPE_NAME`` of a mock whose rig has no DENSO arm (a real controller always names one)
NO_ARM_TYPE_NAME = "tmscal b-CAP mock (no DENSO arm)"
_USER_VAR = re.compile(r"^([IFDSPJV])(\d+)$", re.IGNORECASE)


Handler = Callable[[Session, int, list[Variant]], Any]


def _type_name(rig: SimRig) -> str:
    """The robot's ``@TYPE_NAME``: the model name of the rig's DENSO arm (the arm registry's:
    ``VS-060``, ``COBOTTA``), else ``NO_ARM_TYPE_NAME``."""
    from ...calib.kinematics import ARMS

    arm = rig.arm_nominal
    spec = ARMS.get(arm.name) if arm is not None else None
    return spec.controller_model if spec is not None and spec.vendor == "DENSO" \
        else NO_ARM_TYPE_NAME


class DensoController:
    """The state one RC8 shares between its connections, and the b-CAP functions on it.

    ``rig`` is moved on ``clock`` along a trapezoidal profile (:mod:`tmscal.motion`) at up
    to ``max_linear_speed_mm_s`` and ``max_linear_accel_mm_s2`` (the values at 100 %:
    SPEED=100 and ExtSpeed=100; ACCEL/DECEL=100 and ExtSpeed accel/decel=100);
    ``motion_time_s`` fixes every motion's duration instead; ``robot_names`` are the names
    Controller_GetRobot accepts. ``stats`` counts connections, requests, moves,
    keep-alives, busy replies and dropped connections.
    """

    def __init__(self, rig: SimRig, clock: Clock, max_linear_speed_mm_s: float,
                 faults: DensoFaults | None, motion_time_s: float | None,
                 robot_names: tuple[str, ...],
                 max_linear_accel_mm_s2: float = DEFAULT_MAX_LINEAR_ACCEL_MM_S2) -> None:
        for name, v in (("max_linear_speed_mm_s", max_linear_speed_mm_s),
                        ("max_linear_accel_mm_s2", max_linear_accel_mm_s2)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v}")
        if rig.arm_nominal is not None and rig.arm_nominal.n_joints != 6:
            raise ValueError(f"the DENSO driver reads six arm axes; mock.kinematics.arm "
                             f"{rig.arm_nominal.name} has {rig.arm_nominal.n_joints}")
        self.rig = rig
        self.type_name = _type_name(rig)
        self.clock = clock
        self.max_linear_speed_mm_s = float(max_linear_speed_mm_s)
        self.max_linear_accel_mm_s2 = float(max_linear_accel_mm_s2)
        self.faults = faults or DensoFaults()
        self.motion_time_s = motion_time_s
        self.robot_names = tuple(robot_names)
        self._rng = np.random.default_rng(self.faults.seed)
        self._lock = threading.RLock()
        self._handles = itertools.count(1)
        self.motor_on = False
        self.ext_speed = 100.0
        self.ext_accel = 100.0
        self.ext_decel = 100.0
        #: every accepted ExtSpeed as (speed, accel, decel) percent, oldest first (bounded)
        self.ext_speed_log: list[tuple[float, float, float]] = []
        #: the SPEED percent of every accepted Robot_Move (its option, else Robot_Speed),
        #: oldest first (bounded)
        self.move_speed_log: list[float] = []
        self.move_accel: float | None = None   # ACCEL / DECEL of the last move (percent)
        self.move_decel: float | None = None
        self.robot_speed = 100.0
        #: the controller's latched error (HRESULT) until ClearError; see DensoFaults
        self.latched_error: int | None = self.faults.latched_error
        #: the motion the arm runs (one arm: at most one), and where an arm that replied before
        #: it was still comes to rest: (target, time; inf on the fast clock = the next request)
        self.motion: Job | None = None
        self.coast: tuple[np.ndarray, float] | None = None
        #: real-time clock: the path of the move under way (clock time → commanded
        #: base_from_flange, mm) that the rig's true flange follows until the arm is still
        self.path: Callable[[float], np.ndarray] | None = None
        self._profile = Trapezoid(0.0, 1.0, 1.0)   # the last move's (see _duration)
        #: every move the arm started, oldest first (bounded), with the path and profile it
        #: follows (``Executed.pose_at_time``), for tests of the path and its speed
        self.trajectory: deque[Executed] = deque(maxlen=10_000)
        #: modelled duration (s) of the last move's trapezoidal profile (see ``_duration``),
        #: computed on both clocks (the fast clock does not wait for it)
        self.last_motion_s: float | None = None
        self.fig = -1
        self.variables: dict[str, Any] = {}
        self.stats = {"connections": 0, "requests": 0, "moves": 0, "keepalives": 0,
                      "busy": 0, "dropped": 0, "halts": 0, "clear_errors": 0}
        # function ID → (least number of arguments, handler)
        self._functions: dict[int, tuple[int, Handler]] = {
            Fn.SERVICE_START: (0, self._on_service_start),
            Fn.SERVICE_STOP: (0, self._on_service_stop),
            Fn.CONTROLLER_CONNECT: (2, self._on_controller_connect),
            Fn.CONTROLLER_DISCONNECT: (1, self._on_controller_disconnect),
            Fn.CONTROLLER_GETROBOT: (2, self._on_controller_get_robot),
            Fn.CONTROLLER_GETVARIABLE: (2, self._on_controller_get_variable),
            Fn.CONTROLLER_GETROBOTNAMES: (1, self._on_controller_get_robot_names),
            Fn.CONTROLLER_EXECUTE: (2, self._on_controller_execute),
            Fn.ROBOT_GETVARIABLE: (2, self._on_robot_get_variable),
            Fn.ROBOT_EXECUTE: (2, self._on_robot_execute),
            Fn.ROBOT_HALT: (1, self._on_robot_halt),
            Fn.ROBOT_MOVE: (3, self._on_robot_move),
            Fn.ROBOT_SPEED: (3, self._on_robot_speed),
            Fn.ROBOT_RELEASE: (1, self._on_robot_release),
            Fn.VARIABLE_GETVALUE: (1, self._on_variable_get_value),
            Fn.VARIABLE_PUTVALUE: (2, self._on_variable_put_value),
            Fn.VARIABLE_RELEASE: (1, self._on_variable_release),
        }
        # Robot_Execute command (lower case) → handler(session, parameter)
        self._robot_commands: dict[str, Callable[[Session, Variant], Variant]] = {
            "takearm": self._take_arm, "givearm": self._give_arm, "motor": self._motor,
            "extspeed": self._ext_speed, "curpos": lambda s, p: self._cur_pos(),
            "curjnt": lambda s, p: self._cur_jnt(),
        }

    def _count(self, key: str, at: int | None = None, rate: float = 0.0) -> tuple[int, bool]:
        """Count one more ``stats[key]``; returns the new count k and whether a fault fires
        (k == ``at``, or a draw below ``rate``)."""
        with self._lock:
            self.stats[key] += 1
            k = self.stats[key]
            hit = at == k or (rate > 0 and self._rng.random() < rate)
        return k, hit

    def dispatch(self, sess: Session, serial: int, fid: int, a: list[Variant]) -> Any:
        """Run function ``fid`` with arguments ``a`` for ``sess``; see the module doc."""
        entry = self._functions.get(fid)
        if entry is None:
            raise Refusal(E_NOTIMPL, f"function {fid} is not implemented by the mock")
        need, handler = entry
        if len(a) < need:
            raise Refusal(E_INVALIDARG, f"{function_name(fid)} needs {need} arguments, "
                                        f"got {len(a)}")
        return handler(sess, serial, a + [Variant(VT_EMPTY)] * (4 - len(a)))

    # --- handles -----------------------------------------------------------------------------
    def _new_handle(self, sess: Session, kind: str, obj: Any) -> Variant:
        with self._lock:
            h = next(self._handles)
        sess.handles[h] = (kind, obj)
        return Variant(VT_I4, h)

    def _get(self, sess: Session, v: Variant, kind: str) -> Any:
        x = float(v.value) if v.vt in NUMERIC_VTS else float("nan")
        if not math.isfinite(x) or x != int(x):
            raise Refusal(E_INVALIDARG, f"handle must be an integer, got {v!r}")
        h = int(x)
        ent = sess.handles.get(h)
        if ent is None or ent[0] != kind:
            raise Refusal(E_HANDLE, f"{h} is not a {kind} handle")
        return ent[1]

    def _release(self, sess: Session, v: Variant, kind: str) -> None:
        self._get(sess, v, kind)
        del sess.handles[int(v.value)]

    # --- service and controller ----------------------------------------------------------------
    def _on_service_start(self, sess: Session, serial: int, a: list[Variant]) -> None:
        wdt = args.options(args.text(a[0], "option")).get("WDT")
        try:
            ms = int(wdt) if wdt else 0
        except ValueError:
            raise Refusal(E_INVALIDARG, f"WDT={wdt!r} is not a number of ms") from None
        if ms != 0 and not WDT_MIN_MS <= ms <= WDT_MAX_MS:
            raise Refusal(E_INVALIDARG, f"WDT={ms} ms outside {WDT_MIN_MS}..{WDT_MAX_MS} "
                                        "(0 = off)")
        sess.wdt_s = ms / 1000.0 if ms else None

    def _on_service_stop(self, sess: Session, serial: int, a: list[Variant]) -> None:
        return None

    def _on_controller_connect(self, sess: Session, serial: int, a: list[Variant]) -> Variant:
        provider = args.text(a[1], "provider")
        if not provider.upper().startswith("CAOPROV.DENSO"):
            raise Refusal(E_CAO_OBJECT_NOTFOUND, f"unknown provider {provider!r}")
        return self._new_handle(sess, "controller", provider)

    def _on_controller_disconnect(self, sess: Session, serial: int, a: list[Variant]) -> None:
        self._release(sess, a[0], "controller")

    def _on_controller_get_robot(self, sess: Session, serial: int, a: list[Variant]) -> Variant:
        self._get(sess, a[0], "controller")
        name = args.text(a[1], "robot name")
        if name not in self.robot_names:
            raise Refusal(E_CAO_OBJECT_NOTFOUND, f"no robot {name!r}")
        return self._new_handle(sess, "robot", name)

    def _on_controller_get_robot_names(self, sess: Session, serial: int,
                                       a: list[Variant]) -> Variant:
        self._get(sess, a[0], "controller")
        return Variant(VT_BSTR | VT_ARRAY, list(self.robot_names))

    def _on_controller_get_variable(self, sess: Session, serial: int,
                                    a: list[Variant]) -> Variant:
        self._get(sess, a[0], "controller")
        name = args.text(a[1], "variable name")
        if name.upper() not in _CONTROLLER_VARIABLES and not _USER_VAR.match(name):
            raise Refusal(E_CAO_OBJECT_NOTFOUND, f"no controller variable {name!r}")
        return self._new_handle(sess, "variable", name.upper())

    def _on_controller_execute(self, sess: Session, serial: int, a: list[Variant]) -> Variant:
        self._get(sess, a[0], "controller")
        cmd = args.text(a[1], "command")
        if cmd.lower() == "geterrordescription":
            code = int(args.number(a[2], "error code")) & 0xFFFFFFFF
            return Variant(VT_BSTR, hresult_name(code))
        if cmd.lower() == "clearerror":
            with self._lock:
                self.stats["clear_errors"] += 1
                if self.latched_error is not None:
                    log.info("DENSO mock: ClearError clears 0x%08X", self.latched_error)
                self.latched_error = None
            return Variant(VT_EMPTY)
        if cmd.lower() == "manualreset":  # COBOTTA's safety-state reset; nothing to do here
            return Variant(VT_EMPTY)
        raise Refusal(E_NOTIMPL, f"Controller_Execute {cmd!r} not implemented")

    # --- robot ---------------------------------------------------------------------------------
    def _on_robot_get_variable(self, sess: Session, serial: int, a: list[Variant]) -> Variant:
        self._get(sess, a[0], "robot")
        name = args.text(a[1], "variable name").upper()
        if name not in _ROBOT_VARIABLES:
            raise Refusal(E_CAO_OBJECT_NOTFOUND, f"no robot variable {name!r}")
        return self._new_handle(sess, "variable", name)

    def _on_robot_execute(self, sess: Session, serial: int, a: list[Variant]) -> Variant:
        self._get(sess, a[0], "robot")
        cmd = args.text(a[1], "command")
        run = self._robot_commands.get(cmd.lower())
        if run is None:
            raise Refusal(E_NOTIMPL, f"Robot_Execute {cmd!r} not implemented by the mock")
        return run(sess, a[2])

    def _on_robot_halt(self, sess: Session, serial: int, a: list[Variant]) -> None:
        """Stop the arm's motion, whichever connection runs it (that connection answers its
        blocking move with E_FAIL when it next looks at it, within one poll)."""
        self._get(sess, a[0], "robot")
        with self._lock:
            self.stats["halts"] += 1
            if self.motion is not None:
                self.motion.halted = True
            self.coast = None  # an arm still settling stops where it is (no kinematics)
            if self.path is not None:   # a real-time move stops on its path
                try:
                    self.rig.move_flange(self.path(self.clock.now()))
                except Unreachable as e:
                    log.error("DENSO mock: %s; the arm stays where it was", e)
                self.path = None

    def _on_robot_move(self, sess: Session, serial: int, a: list[Variant]) -> Any:
        self._get(sess, a[0], "robot")
        return self._move(sess, serial, int(args.number(a[1], "comp")), a[2],
                          args.text(a[3], "option"))

    def _on_robot_speed(self, sess: Session, serial: int, a: list[Variant]) -> None:
        self._get(sess, a[0], "robot")
        speed = args.number(a[2], "speed")
        if not math.isfinite(speed) or 0 <= speed < PCT_MIN:
            raise Refusal(E_INVALIDARG, f"Robot_Speed {speed!r} is not a usable percentage")
        if speed > 0:  # negative: keep the current speed
            self.robot_speed = min(speed, 100.0)

    def _on_robot_release(self, sess: Session, serial: int, a: list[Variant]) -> None:
        self._release(sess, a[0], "robot")

    # --- variables -----------------------------------------------------------------------------
    def _on_variable_get_value(self, sess: Session, serial: int, a: list[Variant]) -> Variant:
        return self._var_value(self._get(sess, a[0], "variable"))

    def _on_variable_put_value(self, sess: Session, serial: int, a: list[Variant]) -> None:
        name = self._get(sess, a[0], "variable")
        if name.startswith("@"):
            raise Refusal(E_ACCESSDENIED, f"{name} is read-only")
        self.variables[name] = a[1]

    def _on_variable_release(self, sess: Session, serial: int, a: list[Variant]) -> None:
        self._release(sess, a[0], "variable")

    def _var_value(self, name: str) -> Variant:
        fixed = {"@CURRENT_ANGLE": self._cur_jnt(),
                 "@TYPE_NAME": Variant(VT_BSTR, self.type_name),
                 "@VERSION": Variant(VT_BSTR, "tmscal DENSO b-CAP mock 1.0"),
                 "@MODE": Variant(VT_I4, 3)}
        if name == "@CURRENT_POSITION":
            return self._cur_pos()
        if name in fixed:
            return fixed[name]
        if name in self.variables:
            return self.variables[name]
        kind = name[0]  # a user variable never written: its type's zero
        if kind == "I":
            return Variant(VT_I4, 0)
        if kind in "FD":
            return Variant(VT_R8 if kind == "D" else VT_R4, 0.0)
        if kind == "S":
            return Variant(VT_BSTR, "")
        return Variant(VT_R8 | VT_ARRAY, [0.0] * (7 if kind == "P" else 6))

    # --- Robot_Execute commands ----------------------------------------------------------------
    def _check_no_error(self, what: str) -> None:
        """Refuse ``what`` with the latched error's HRESULT until ClearError."""
        code = self.latched_error
        if code is not None:
            raise Refusal(code, f"{what} refused: error 0x{code:08X} latched (ClearError first)")

    def _take_arm(self, sess: Session, param: Variant) -> Variant:
        args.numbers(param, "TakeArm")
        self._check_no_error("TakeArm")
        sess.arm = True
        return Variant(VT_EMPTY)

    def _give_arm(self, sess: Session, param: Variant) -> Variant:
        sess.arm = False
        return Variant(VT_EMPTY)

    def _motor(self, sess: Session, param: Variant) -> Variant:
        vals = args.numbers(param, "Motor")
        if not vals:
            raise Refusal(E_INVALIDARG, "Motor needs a state (0 or 1)")
        if vals[0] != 0 and not sess.arm:
            raise Refusal(E_ACCESSDENIED, "Motor on without TakeArm")
        if vals[0] != 0:
            self._check_no_error("Motor on")
        self.motor_on = vals[0] != 0
        return Variant(VT_EMPTY)

    def _ext_speed(self, sess: Session, param: Variant) -> Variant:
        vals = args.numbers(param, "ExtSpeed")
        if not 1 <= len(vals) <= 3:
            raise Refusal(E_INVALIDARG, f"ExtSpeed needs [speed, accel, decel], got {vals}")
        speed = args.percent(vals[0], "ExtSpeed speed")
        # omitted accel / decel: speed² / 100, as the RC8 does
        accel = args.percent(vals[1], "ExtSpeed accel") if len(vals) > 1 else max(
            speed * speed / 100.0, PCT_MIN)
        decel = args.percent(vals[2], "ExtSpeed decel") if len(vals) > 2 else accel
        with self._lock:
            self.ext_speed, self.ext_accel, self.ext_decel = speed, accel, decel
            self.ext_speed_log = [*self.ext_speed_log[-999:], (speed, accel, decel)]
        return Variant(VT_EMPTY)

    def _cur_jnt(self) -> Variant:
        """The CurJnt reply: R8 array of eight joint angles (deg): the rig's joints when it
        has an arm (``mock.kinematics``; J7, J8 0), else zeros (no kinematics)."""
        q = self.rig.joints()
        deg = [] if q is None else [math.degrees(float(v)) for v in q]
        return Variant(VT_R8 | VT_ARRAY, (deg + [0.0] * 8)[:max(8, len(deg))])

    def _cur_pos(self) -> Variant:
        """The CurPos reply: R8 array [x, y, z (mm), rx, ry, rz (deg), fig], or the
        configured fault."""
        p = [float(x) for x in denso_p_from_matrix(self.rig.reported_flange())]
        p.append(float(self.fig))
        bad = self.faults.bad_curpos
        if bad is None:
            return Variant(VT_R8 | VT_ARRAY, p)
        log.info("DENSO mock: fault: CurPos reply %s", bad)
        corrupt: dict[str, Callable[[], Variant]] = {
            "nan": lambda: Variant(VT_R8 | VT_ARRAY, [math.nan] + p[1:]),
            "inf": lambda: Variant(VT_R8 | VT_ARRAY, [math.inf] + p[1:]),
            "short": lambda: Variant(VT_R8 | VT_ARRAY, p[:5]),
            "long": lambda: Variant(VT_R8 | VT_ARRAY, p + [0.0, 0.0]),
            "bstr": lambda: Variant(VT_BSTR, "P(" + ", ".join(f"{x:g}" for x in p) + ")"),
            "bool_array": lambda: Variant(VT_BOOL | VT_ARRAY, [True] * 7),
            "empty": lambda: Variant(VT_EMPTY),
            "nested_bstr": lambda: Variant(VT_VARIANT | VT_ARRAY, [
                *(Variant(VT_R8, x) for x in p[:6]), Variant(VT_BSTR, "-1")]),
        }
        return corrupt[bad]()

    # --- motion --------------------------------------------------------------------------------
    def _move(self, sess: Session, serial: int, comp: int, pose: Variant, option: str) -> Any:
        """Robot_Move: check, then move at once (fast clock) or start a :class:`Job`."""
        k, fail = self._count("moves", self.faults.fail_move_at, self.faults.move_fail_rate)
        if comp not in (1, 2):
            raise Refusal(E_NOTIMPL if comp == 3 else E_INVALIDARG,
                          f"Robot_Move comp {comp} (mock supports 1 = MOVE P, 2 = MOVE L)")
        p = args.pose(pose)
        mode = args.pass_mode(pose)
        opts = args.options(option)
        pct = args.option_percent(opts, ("SPEED", "S"), "SPEED", option)
        if pct is None:
            pct = args.percent(self.robot_speed, "Robot_Speed")
        accel = args.option_percent(opts, ("ACCEL", "A"), "ACCEL", option)
        decel = args.option_percent(opts, ("DECEL", "D"), "DECEL", option)
        if not sess.arm:
            raise Refusal(E_ACCESSDENIED, "Robot_Move without TakeArm")
        if not self.motor_on:
            raise Refusal(E_MOTOR_OFF, "Robot_Move with the motor off")
        self._check_no_error("Robot_Move")
        if fail:
            raise Refusal(self.faults.fail_move_hresult, f"fault injected at move {k}")
        target = matrix_from_denso_p(p[:6])
        if not np.isfinite(target).all():
            raise Refusal(E_INVALIDARG, f"pose {p} gives a non-finite target")
        if self.rig.reach(target) is None:   # an arm (mock.kinematics) that cannot get there
            raise Refusal(E_INVALIDARG, f"pose {p}: no inverse kinematics solution within "
                          "the joint limits (out of reach)")
        duration = self._duration(target, pct, accel, decel)
        assert self.last_motion_s is not None
        self.trajectory.append(Executed(self.rig.reported_flange().copy(), target.copy(),
                                        self._profile, self.last_motion_s))
        self.move_accel, self.move_decel = accel, decel
        with self._lock:
            self.move_speed_log = [*self.move_speed_log[-999:], pct]
        if p[6] >= 0:
            self.fig = int(p[6])
        return self._run_move(sess, serial, target, duration, mode, "NEXT" in opts,
                           hold=self.faults.hold_move_at == k)

    def _run_move(self, sess: Session, serial: int, target: np.ndarray, duration: float,
               mode: str, nxt: bool, hold: bool) -> Any:
        """Run a checked move. The arm is still on ``target`` ``duration`` s from now; a
        blocking ``@E`` move replies then, a pass / ``@P`` move up to :data:`SETTLE_S` earlier
        (on the fast clock: at once, and the arm is still only when the next request comes).
        ``hold``: the move lasts until a Robot_Halt."""
        now = self.clock.now()
        still = now + duration
        lead = 0.0 if mode == "@E" or nxt else min(SETTLE_S, duration)
        if not hold and still - lead <= now:
            pending = self.clock.fast and mode != "@E" and not nxt
            self.arrive(target, math.inf if pending else still)
            return None
        job = Job(target=target, start=now, end=math.inf if hold else still - lead,
                  serial=None if nxt else serial, wdt_s=sess.wdt_s,
                  settle_s=0.0 if hold else lead)
        sess.job = job
        with self._lock:
            self.motion = job
            if not hold and duration > 0:
                self._follow(target, now, duration)
        return None if nxt else DEFERRED

    def arrive(self, target: np.ndarray, at: float) -> None:
        """The arm comes to rest on ``target`` at time ``at`` (now or past: at once; ``inf``:
        at the next request)."""
        with self._lock:
            if at <= self.clock.now():
                self.coast = None
                self.path = None
                self.rig.move_flange(target)
            else:
                self.coast = (target, at)

    def settle(self, request: bool) -> None:
        """Bring an arm that replied before it was still to rest when its time has come (or,
        on the fast clock, when ``request``: a request arrived)."""
        with self._lock:
            if self.coast is None:
                return
            target, at = self.coast
            if (request and math.isinf(at)) or at <= self.clock.now():
                self.coast = None
                self.path = None
                self.rig.move_flange(target)

    def end_motion(self, job: Job) -> None:
        with self._lock:
            if self.motion is job:
                self.motion = None

    def _follow(self, target: np.ndarray, t0: float, duration: float) -> None:
        """The rig's true flange follows the move from the reported pose to ``target``
        (straight line and rotation geodesic) on the profile ``_profile`` stretched to
        ``duration`` s, starting at clock time ``t0``."""
        start = self.rig.reported_flange()
        prof = self._profile
        scale = prof.duration / duration if prof.duration > 0 else 0.0

        def path(now: float) -> np.ndarray:
            f = prof.fraction((now - t0) * scale) if scale > 0 else min(1.0, (now - t0)
                                                                        / duration)
            return straight_path(start, target, f)

        clock = self.clock
        self.path = path
        self.rig.follow(lambda: path(clock.now()))

    def _duration(self, target: np.ndarray, pct: float, accel_pct: float | None = None,
                  decel_pct: float | None = None) -> float:
        """Seconds a move to ``target`` (base_from_flange, mm) at SPEED ``pct`` % takes until
        the arm is still: the trapezoidal profile (:mod:`tmscal.motion`) over the distance
        with speed cap SPEED × ExtSpeed × ``max_linear_speed_mm_s`` and acceleration a_eff,
        the harmonic mean of the acceleration ACCEL × ExtSpeed accel and the deceleration
        DECEL × ExtSpeed decel (each × ``max_linear_accel_mm_s2``; an omitted ACCEL/DECEL
        is 100 %), which gives the asymmetric profile's duration exactly; or
        ``motion_time_s``. Recorded in ``last_motion_s`` on both clocks; 0 on the fast one."""
        speed = self.max_linear_speed_mm_s * pct / 100.0 * self.ext_speed / 100.0
        full = self.max_linear_accel_mm_s2
        acc = full * (100.0 if accel_pct is None else accel_pct) / 100.0 * self.ext_accel / 100.0
        dec = full * (100.0 if decel_pct is None else decel_pct) / 100.0 * self.ext_decel / 100.0
        dist = float(np.linalg.norm(target[:3, 3] - self.rig.reported_flange()[:3, 3]))
        try:
            self._profile = Trapezoid(dist, speed, 2.0 / (1.0 / acc + 1.0 / dec))
        except (ValueError, ZeroDivisionError):
            raise Refusal(E_INVALIDARG, f"a move of {dist:g} mm at {speed:g} mm/s and "
                          f"{acc:g}/{dec:g} mm/s² never ends") from None
        modelled = (float(self.motion_time_s) if self.motion_time_s is not None
                    else self._profile.duration)
        if not math.isfinite(modelled):
            raise Refusal(E_INVALIDARG, f"a move of {dist:g} mm at {speed:g} mm/s never ends")
        self.last_motion_s = modelled
        return 0.0 if self.clock.fast else modelled
