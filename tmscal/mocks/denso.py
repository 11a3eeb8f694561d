"""A DENSO RC8 b-CAP server (TCP, loopback only) that serves a ``SimRig``.

What it models (enough for tmscal's driver and DENSO's own b-CAP clients):

* Service_Start / Service_Stop (``WDT=<ms>`` in the option turns on S_EXECUTING keep-alives;
  0 turns them off, other values outside 10..3,600,000 ms get E_INVALIDARG),
  Controller_Connect / Disconnect / GetRobot / GetRobotNames / GetVariable / Execute
  (``GetErrorDescription``, ``ClearError``), Robot_Execute (TakeArm, GiveArm, Motor, ExtSpeed,
  CurPos, CurJnt), Robot_Move (comp 1 = MOVE P, 2 = MOVE L; pose as text
  ``"@P P(x, y, z, rx, ry, rz, fig)"`` or VARIANT array ``[[x, …, fig], "P", "@P"]``; options
  ``SPEED=<percent>``, ``ACCEL=<percent>``, ``DECEL=<percent>`` and ``NEXT``), Robot_Halt,
  Robot_Speed, Robot_GetVariable
  (``@CURRENT_POSITION``, ``@CURRENT_ANGLE``), Robot_Release, Variable_GetValue / PutValue /
  Release (controller ``@VERSION``, ``@MODE`` and user variables ``I1``, ``F2``, ``D3``,
  ``S4``, ``P5`` …).
* Handles per connection (released when the connection closes, with the arm); the motor and
  the rig are shared by all connections, like one physical controller.
* A move needs TakeArm (else E_ACCESSDENIED 0x80070005: the real controller's code for this
  is not in the sheet, so the mock uses this stand-in) and the motor on (else 0x81501003).
* Motion takes ``distance / speed`` seconds on the real-time clock (``motion_time_s``
  overrides it), none on the fast clock; ``rig.move_flange(target)`` is called when the
  motion ends. Speed = ``SPEED`` option (percent, default 100) × ExtSpeed (percent) ×
  ``max_linear_speed_mm_s``. ExtSpeed ``[speed, accel, decel]`` (percent; accel and decel
  default to speed² / 100 as on the RC8) and the ACCEL/DECEL move options are recorded
  (``ext_accel``, ``ext_decel``, ``ext_speed_log``, ``move_accel``, ``move_decel``) but do
  not change the timing. Every percentage must be finite and in [0.01, 100] (else
  E_INVALIDARG). The mock has no kinematics: CurJnt returns zeros, and a halted
  motion leaves the rig where it was (the blocking move then answers E_FAIL).
* While a motion runs, any request but Robot_Halt gets E_BUSY_PROC (0x809100AA); with NEXT
  the move answers at once but the connection stays busy until the motion ends. With a
  watchdog, a blocking move sends one S_EXECUTING packet per WDT period it lasts.
* One reply per request, in one ``sendall``, with the request's serial; malformed requests
  get E_INVALIDPACKET, bad arguments E_INVALIDARG (NaN, ±inf and out-of-range numbers
  included), unknown handles E_HANDLE, anything the mock cannot handle E_FAIL; the socket is
  never closed mid-request except by the ``drop_at_request`` fault.

Poses: the rig's ``base_from_flange`` 4×4 mm ↔ P-type via ``tmscal.geometry``.
"""

from __future__ import annotations

import itertools
import logging
import math
import re
import socket
import struct
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..drivers.denso.hresult import (
    E_ACCESSDENIED,
    E_BUSY_PROC,
    E_CAO_OBJECT_NOTFOUND,
    E_EMERGENCY_STOP,
    E_FAIL,
    E_HANDLE,
    E_INVALIDARG,
    E_INVALIDPACKET,
    E_MOTOR_OFF,
    E_NOTIMPL,
    S_EXECUTING,
    S_OK,
    hresult_name,
)
from ..drivers.denso.packet import (
    Fn,
    PacketFramer,
    decode_packet,
    encode_packet,
    function_name,
)
from ..drivers.denso.variant import (
    VT_ARRAY,
    VT_BOOL,
    VT_BSTR,
    VT_EMPTY,
    VT_I2,
    VT_I4,
    VT_I8,
    VT_NULL,
    VT_R4,
    VT_R8,
    VT_UI1,
    VT_UI2,
    VT_UI4,
    VT_UI8,
    VT_VARIANT,
    Variant,
)
from ..errors import ProtocolError
from ..geometry import denso_p_from_matrix, matrix_from_denso_p
from ..sim.rig import SimRig
from .clock import REAL_TIME, Clock
from .net import loopback_family

log = logging.getLogger(__name__)

_NUM_VTS = {VT_I2, VT_I4, VT_UI4, VT_R4, VT_R8, VT_UI1, VT_UI2, VT_I8, VT_UI8}
_POLL_S = 0.05
#: Watchdog periods (ms) Service_Start accepts (0 = off).
WDT_MIN_MS, WDT_MAX_MS = 10, 3_600_000
#: Range of every speed / acceleration percentage (SPEED, ACCEL, DECEL, ExtSpeed).
PCT_MIN, PCT_MAX = 0.01, 100.0
#: Values of ``DensoFaults.bad_curpos``.
BAD_CURPOS = ("nan", "inf", "short", "long", "bstr", "bool_array", "empty", "nested_bstr")


@dataclass
class DensoFaults:
    """Injected faults, counted over all connections of one mock (1-based).

    ``fail_move_at``: the k-th Robot_Move is refused with ``fail_move_hresult`` (default
    0x83500178, not executable during emergency stop); ``move_fail_rate``: probability that
    any move is refused the same way. ``drop_at_request``: at the k-th request the mock
    closes that connection instead of answering; ``drop_rate``: probability per request.
    Random faults draw from ``numpy.random.default_rng(seed)``.
    ``bad_curpos``: every CurPos (and ``@CURRENT_POSITION``) reply is corrupted the named way:
    "nan" / "inf" (x is NaN / +inf), "short" (5 values), "long" (9 values), "bstr" (a BSTR),
    "bool_array" (a BOOL array), "empty" (EMPTY), "nested_bstr" (a VARIANT array with a BSTR
    in it). None (default): correct replies.
    """

    fail_move_at: int | None = None
    fail_move_hresult: int = E_EMERGENCY_STOP
    move_fail_rate: float = 0.0
    drop_at_request: int | None = None
    drop_rate: float = 0.0
    seed: int = 0
    bad_curpos: str | None = None

    def __post_init__(self) -> None:
        if self.bad_curpos is not None and self.bad_curpos not in BAD_CURPOS:
            raise ValueError(f"bad_curpos must be one of {', '.join(BAD_CURPOS)} or None, got "
                             f"{self.bad_curpos!r}")


class _Reply(Exception):
    """An error HRESULT to answer (internal)."""

    def __init__(self, code: int, why: str) -> None:
        super().__init__(why)
        self.code = code


@dataclass
class _Job:
    """A motion in progress on one connection."""

    target: np.ndarray
    start: float
    end: float
    serial: int | None  # blocking move: reply pending with this serial; None for NEXT
    wdt_s: float | None
    next_keepalive: float = 0.0

    def __post_init__(self) -> None:
        if self.wdt_s:
            self.next_keepalive = self.start + self.wdt_s


@dataclass
class _Session:
    sock: socket.socket
    peer: str
    handles: dict[int, tuple[str, Any]] = field(default_factory=dict)
    arm: bool = False
    wdt_s: float | None = None
    job: _Job | None = None
    framer: PacketFramer = field(default_factory=PacketFramer)


_P_TEXT = re.compile(r"^\s*(?:@\w+\s+)?P\s*\(([^()]*)\)\s*$", re.IGNORECASE)
_USER_VAR = re.compile(r"^([IFDSPJV])(\d+)$", re.IGNORECASE)


def _num(v: Variant, what: str) -> float:
    if v.vt not in _NUM_VTS:
        raise _Reply(E_INVALIDARG, f"{what}: expected a number, got {v!r}")
    return float(v.value)


def _pct(x: float, what: str) -> float:
    """A speed / acceleration percentage: finite and in [PCT_MIN, PCT_MAX]."""
    if not (math.isfinite(x) and PCT_MIN <= x <= PCT_MAX):
        raise _Reply(E_INVALIDARG, f"{what} {x!r} outside [{PCT_MIN}, {PCT_MAX}] %")
    return x


def _opt_pct(opts: dict[str, str], keys: tuple[str, ...], what: str,
             option: str) -> float | None:
    """The percentage of the first of ``keys`` present in a move option, else None."""
    for k in keys:
        if k in opts:
            try:
                x = float(opts[k])
            except ValueError:
                raise _Reply(E_INVALIDARG, f"bad {what} in option {option!r}") from None
            return _pct(x, what)
    return None


def _numbers(v: Variant, what: str) -> list[float]:
    """Numbers from a numeric scalar, a numeric array or a VARIANT array of numbers;
    EMPTY → []."""
    if v.vt in (VT_EMPTY, VT_NULL):
        return []
    if v.vt in _NUM_VTS:
        return [float(v.value)]
    if v.vt & VT_ARRAY and (v.vt & ~VT_ARRAY) in _NUM_VTS:
        return [float(x) for x in v.value]
    if v.vt == VT_VARIANT | VT_ARRAY:
        return [_num(e, what) for e in v.value]
    raise _Reply(E_INVALIDARG, f"{what}: expected numbers, got {v!r}")


def _text(v: Variant, what: str) -> str:
    if v.vt in (VT_EMPTY, VT_NULL):
        return ""
    if v.vt != VT_BSTR:
        raise _Reply(E_INVALIDARG, f"{what}: expected a BSTR, got {v!r}")
    return v.value


def _parse_pose(v: Variant) -> list[float]:
    """P-type [x, y, z, rx, ry, rz, fig] from a pose argument of Robot_Move."""
    if v.vt == VT_BSTR:
        m = _P_TEXT.match(v.value)
        if not m:
            raise _Reply(E_INVALIDARG, f"pose text {v.value!r} is not '@P P(x, y, z, rx, "
                                       "ry, rz, fig)' (J/T poses are not supported)")
        try:
            vals = [float(s) for s in m.group(1).split(",")]
        except ValueError:
            raise _Reply(E_INVALIDARG, f"pose text {v.value!r} has a non-number") from None
    elif v.vt == VT_VARIANT | VT_ARRAY and v.value and v.value[0].vt & VT_ARRAY:
        items = v.value
        if len(items) > 1 and _text(items[1], "pose type").upper() not in ("P", ""):
            raise _Reply(E_NOTIMPL, f"pose type {items[1].value!r} not supported (only P)")
        vals = _numbers(items[0], "pose values")
    else:
        vals = _numbers(v, "pose")
    if len(vals) == 6:
        vals.append(-1.0)
    if len(vals) != 7 or not np.isfinite(vals).all():
        raise _Reply(E_INVALIDARG, f"pose needs 6 or 7 finite values, got {vals}")
    return vals


def _options(text: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for part in text.split(","):
        part = part.strip()
        if part:
            k, _, val = part.partition("=")
            out[k.strip().upper()] = val.strip()
    return out


class DensoMock:
    """A b-CAP server on ``host:port`` (loopback only; port 0 → ephemeral, a real RC8 uses
    5007) serving ``rig``.

    ``clock``: REAL_TIME (motions take distance / speed seconds) or FAST (immediate).
    ``max_linear_speed_mm_s``: the linear speed at SPEED=100 and ExtSpeed=100 (mm/s).
    ``faults``: :class:`DensoFaults`. ``motion_time_s``: a fixed duration for every motion
    on the real-time clock (None: distance / speed). ``robot_names``: names GetRobot accepts.
    ``start()`` returns ``"127.0.0.1:PORT"``; ``close()`` stops it; usable as a context
    manager. ``stats`` counts requests, moves, keep-alives and busy replies.
    """

    def __init__(self, rig: SimRig, host: str = "127.0.0.1", port: int = 0,
                 clock: Clock = REAL_TIME, max_linear_speed_mm_s: float = 1000.0,
                 faults: DensoFaults | None = None, motion_time_s: float | None = None,
                 robot_names: tuple[str, ...] = ("Arm",)) -> None:
        self._family = loopback_family(host, "DensoMock host")
        if not (math.isfinite(max_linear_speed_mm_s) and max_linear_speed_mm_s > 0):
            raise ValueError(f"max_linear_speed_mm_s must be finite and > 0, got "
                             f"{max_linear_speed_mm_s}")
        self.rig = rig
        self.host = host
        self.port = int(port)
        self.clock = clock
        self.max_linear_speed_mm_s = float(max_linear_speed_mm_s)
        self.faults = faults or DensoFaults()
        self.motion_time_s = motion_time_s
        self.robot_names = tuple(robot_names)
        self._rng = np.random.default_rng(self.faults.seed)
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._listener: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._sessions: list[_Session] = []
        self._handles = itertools.count(1)
        self.motor_on = False
        self.ext_speed = 100.0
        self.ext_accel = 100.0
        self.ext_decel = 100.0
        #: every accepted ExtSpeed as (speed, accel, decel) percent, oldest first (bounded)
        self.ext_speed_log: list[tuple[float, float, float]] = []
        self.move_accel: float | None = None   # ACCEL / DECEL of the last move (percent)
        self.move_decel: float | None = None
        self.robot_speed = 100.0
        self.fig = -1
        self.variables: dict[str, Any] = {}
        self.stats = {"connections": 0, "requests": 0, "moves": 0, "keepalives": 0,
                      "busy": 0, "dropped": 0}

    # --- lifecycle ---------------------------------------------------------------------------
    def start(self) -> str:
        """Bind, listen and serve in daemon threads; returns ``"host:port"``."""
        if self._listener is not None:
            return f"{self.host}:{self.port}"
        s = socket.socket(self._family, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.host, self.port))
        s.listen(8)
        s.settimeout(_POLL_S)
        self._listener = s
        self.port = s.getsockname()[1]
        t = threading.Thread(target=self._accept_loop, name=f"denso-mock:{self.port}",
                             daemon=True)
        t.start()
        self._threads.append(t)
        log.info("DENSO b-CAP mock listening on %s:%d", self.host, self.port)
        return f"{self.host}:{self.port}"

    def close(self) -> None:
        """Stop serving and close every connection (safe twice)."""
        self._stop.set()
        if self._listener is not None:
            try:
                self._listener.close()
            except OSError:  # pragma: no cover
                pass
        with self._lock:
            sessions = list(self._sessions)
        for sess in sessions:
            try:
                sess.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2.0)

    def __enter__(self) -> DensoMock:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- serving -----------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        assert self._listener is not None
        while not self._stop.is_set():
            try:
                conn, addr = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sess = _Session(sock=conn, peer=f"{addr[0]}:{addr[1]}")
            with self._lock:
                self._sessions.append(sess)
                self.stats["connections"] += 1
            t = threading.Thread(target=self._serve, args=(sess,), daemon=True,
                                 name=f"denso-mock-conn:{sess.peer}")
            t.start()
            self._threads.append(t)

    def _serve(self, sess: _Session) -> None:
        try:
            self._loop(sess)
        except OSError as e:
            log.info("DENSO mock: connection %s ended: %s", sess.peer, e)
        finally:
            self._end_session(sess)

    def _loop(self, sess: _Session) -> None:
        while not self._stop.is_set():
            self._advance(sess)
            wait = _POLL_S
            if sess.job is not None:
                nxt = sess.job.end
                if sess.job.serial is not None and sess.job.wdt_s:
                    nxt = min(nxt, sess.job.next_keepalive)
                wait = min(wait, max(nxt - self.clock.now(), 0.001))
            sess.sock.settimeout(wait)
            try:
                data = sess.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            sess.framer.feed(data)
            if not self._drain(sess):
                break

    def _end_session(self, sess: _Session) -> None:
        job = sess.job
        if job is not None and job.serial is None:  # a NEXT motion carries on to its end
            self.rig.move_flange(job.target)
        sess.job = None
        sess.arm = False
        sess.handles.clear()
        with self._lock:
            if sess in self._sessions:
                self._sessions.remove(sess)
        try:
            sess.sock.close()
        except OSError:  # pragma: no cover
            pass

    def _send(self, sess: _Session, serial: int, code: int, value: Variant | None = None) -> None:
        sess.sock.sendall(encode_packet(serial, code, [] if value is None else [value]))

    def _advance(self, sess: _Session) -> None:
        """Send the keep-alives that are due and finish the motion when its time is up."""
        job = sess.job
        if job is None:
            return
        now = self.clock.now()
        if job.serial is not None and job.wdt_s:
            while job.next_keepalive < job.end and job.next_keepalive <= now:
                self._send(sess, job.serial, S_EXECUTING)
                with self._lock:
                    self.stats["keepalives"] += 1
                job.next_keepalive += job.wdt_s
        if now >= job.end:
            sess.job = None
            self.rig.move_flange(job.target)
            if job.serial is not None:
                self._send(sess, job.serial, S_OK)

    def _drain(self, sess: _Session) -> bool:
        """Answer every complete request in the buffer; False when the connection must end."""
        while True:
            try:
                frame = sess.framer.next_frame()
            except ProtocolError as e:
                log.warning("DENSO mock: bad framing from %s: %s", sess.peer, e)
                continue
            if frame is None:
                return True
            (serial,) = struct.unpack_from("<H", frame, 5)
            with self._lock:
                self.stats["requests"] += 1
                k = self.stats["requests"]
                drop = (self.faults.drop_at_request == k
                        or (self.faults.drop_rate > 0
                            and self._rng.random() < self.faults.drop_rate))
            if drop:
                log.info("DENSO mock: fault: dropping the connection at request %d", k)
                with self._lock:
                    self.stats["dropped"] += 1
                return False
            try:
                pkt = decode_packet(frame)
            except ProtocolError as e:
                log.warning("DENSO mock: malformed request from %s: %s", sess.peer, e)
                self._send(sess, serial, E_INVALIDPACKET)
                continue
            self._advance(sess)
            if sess.job is not None and pkt.code != Fn.ROBOT_HALT:
                with self._lock:
                    self.stats["busy"] += 1
                self._send(sess, serial, E_BUSY_PROC)
                continue
            try:
                result = self._dispatch(sess, pkt.serial, pkt.code, list(pkt.args))
            except _Reply as r:
                log.info("DENSO mock: %s → 0x%08X (%s): %s", function_name(pkt.code), r.code,
                         hresult_name(r.code), r)
                self._send(sess, serial, r.code)
                continue
            except (ValueError, ArithmeticError, TypeError) as e:  # a value it cannot use
                log.warning("DENSO mock: %s rejected: %s", function_name(pkt.code), e)
                self._send(sess, serial, E_INVALIDARG)
                continue
            except OSError:
                raise
            except Exception:  # a mock bug must not end the connection without a reply
                log.exception("DENSO mock: %s failed", function_name(pkt.code))
                self._send(sess, serial, E_FAIL)
                continue
            if result is not _DEFERRED:
                self._send(sess, serial, S_OK, result)

    # --- functions ---------------------------------------------------------------------------
    def _new_handle(self, sess: _Session, kind: str, obj: Any) -> Variant:
        with self._lock:
            h = next(self._handles)
        sess.handles[h] = (kind, obj)
        return Variant(VT_I4, h)

    def _get(self, sess: _Session, v: Variant, kind: str) -> Any:
        x = float(v.value) if v.vt in _NUM_VTS else float("nan")
        if not math.isfinite(x) or x != int(x):
            raise _Reply(E_INVALIDARG, f"handle must be an integer, got {v!r}")
        h = int(x)
        ent = sess.handles.get(h)
        if ent is None or ent[0] != kind:
            raise _Reply(E_HANDLE, f"{h} is not a {kind} handle")
        return ent[1]

    def _dispatch(self, sess: _Session, serial: int, fid: int, a: list[Variant]) -> Any:
        need = {Fn.SERVICE_START: 0, Fn.SERVICE_STOP: 0, Fn.CONTROLLER_CONNECT: 2,
                Fn.CONTROLLER_DISCONNECT: 1, Fn.CONTROLLER_GETROBOT: 2,
                Fn.CONTROLLER_GETVARIABLE: 2, Fn.CONTROLLER_GETROBOTNAMES: 1,
                Fn.CONTROLLER_EXECUTE: 2, Fn.ROBOT_GETVARIABLE: 2, Fn.ROBOT_EXECUTE: 2,
                Fn.ROBOT_HALT: 1, Fn.ROBOT_MOVE: 3, Fn.ROBOT_SPEED: 3, Fn.ROBOT_RELEASE: 1,
                Fn.VARIABLE_GETVALUE: 1, Fn.VARIABLE_PUTVALUE: 2, Fn.VARIABLE_RELEASE: 1}
        if fid not in need:
            raise _Reply(E_NOTIMPL, f"function {fid} is not implemented by the mock")
        if len(a) < need[fid]:
            raise _Reply(E_INVALIDARG, f"{function_name(fid)} needs {need[fid]} arguments, "
                                       f"got {len(a)}")
        a = a + [Variant(VT_EMPTY)] * (4 - len(a))
        if fid == Fn.SERVICE_START:
            opts = _options(_text(a[0], "option"))
            wdt = opts.get("WDT")
            try:
                ms = int(wdt) if wdt else 0
            except ValueError:
                raise _Reply(E_INVALIDARG, f"WDT={wdt!r} is not a number of ms") from None
            if ms != 0 and not WDT_MIN_MS <= ms <= WDT_MAX_MS:
                raise _Reply(E_INVALIDARG, f"WDT={ms} ms outside {WDT_MIN_MS}..{WDT_MAX_MS} "
                                           "(0 = off)")
            sess.wdt_s = ms / 1000.0 if ms else None
            return None
        if fid == Fn.SERVICE_STOP:
            return None
        if fid == Fn.CONTROLLER_CONNECT:
            provider = _text(a[1], "provider")
            if not provider.upper().startswith("CAOPROV.DENSO"):
                raise _Reply(E_CAO_OBJECT_NOTFOUND, f"unknown provider {provider!r}")
            return self._new_handle(sess, "controller", provider)
        if fid == Fn.CONTROLLER_DISCONNECT:
            self._get(sess, a[0], "controller")
            del sess.handles[int(a[0].value)]
            return None
        if fid == Fn.CONTROLLER_GETROBOT:
            self._get(sess, a[0], "controller")
            name = _text(a[1], "robot name")
            if name not in self.robot_names:
                raise _Reply(E_CAO_OBJECT_NOTFOUND, f"no robot {name!r}")
            return self._new_handle(sess, "robot", name)
        if fid == Fn.CONTROLLER_GETROBOTNAMES:
            self._get(sess, a[0], "controller")
            return Variant(VT_BSTR | VT_ARRAY, list(self.robot_names))
        if fid == Fn.CONTROLLER_GETVARIABLE:
            self._get(sess, a[0], "controller")
            name = _text(a[1], "variable name")
            if name.upper() not in ("@VERSION", "@MODE") and not _USER_VAR.match(name):
                raise _Reply(E_CAO_OBJECT_NOTFOUND, f"no controller variable {name!r}")
            return self._new_handle(sess, "variable", name.upper())
        if fid == Fn.CONTROLLER_EXECUTE:
            self._get(sess, a[0], "controller")
            cmd = _text(a[1], "command")
            if cmd.lower() == "geterrordescription":
                code = int(_num(a[2], "error code")) & 0xFFFFFFFF
                return Variant(VT_BSTR, hresult_name(code))
            if cmd.lower() == "clearerror":
                return Variant(VT_EMPTY)
            raise _Reply(E_NOTIMPL, f"Controller_Execute {cmd!r} not implemented")
        if fid == Fn.ROBOT_GETVARIABLE:
            self._get(sess, a[0], "robot")
            name = _text(a[1], "variable name").upper()
            if name not in ("@CURRENT_POSITION", "@CURRENT_ANGLE"):
                raise _Reply(E_CAO_OBJECT_NOTFOUND, f"no robot variable {name!r}")
            return self._new_handle(sess, "variable", name)
        if fid == Fn.ROBOT_EXECUTE:
            self._get(sess, a[0], "robot")
            return self._robot_execute(sess, _text(a[1], "command"), a[2])
        if fid == Fn.ROBOT_HALT:
            self._get(sess, a[0], "robot")
            job, sess.job = sess.job, None
            if job is not None and job.serial is not None:
                self._send(sess, job.serial, E_FAIL)  # the halted blocking move fails
            return None
        if fid == Fn.ROBOT_MOVE:
            self._get(sess, a[0], "robot")
            return self._move(sess, serial, int(_num(a[1], "comp")), a[2],
                              _text(a[3], "option"))
        if fid == Fn.ROBOT_SPEED:
            self._get(sess, a[0], "robot")
            speed = _num(a[2], "speed")
            if not math.isfinite(speed) or 0 <= speed < PCT_MIN:
                raise _Reply(E_INVALIDARG, f"Robot_Speed {speed!r} is not a usable percentage")
            if speed > 0:  # negative: keep the current speed
                self.robot_speed = min(speed, 100.0)
            return None
        if fid == Fn.ROBOT_RELEASE:
            self._get(sess, a[0], "robot")
            del sess.handles[int(a[0].value)]
            return None
        name = self._get(sess, a[0], "variable")
        if fid == Fn.VARIABLE_GETVALUE:
            return self._var_value(name)
        if fid == Fn.VARIABLE_PUTVALUE:
            if name.startswith("@"):
                raise _Reply(E_ACCESSDENIED, f"{name} is read-only")
            self.variables[name] = a[1]
            return None
        del sess.handles[int(a[0].value)]  # VARIABLE_RELEASE
        return None

    def _p_now(self) -> list[float]:
        p = denso_p_from_matrix(self.rig.reported_flange())
        return [float(x) for x in p] + [float(self.fig)]

    def _cur_pos(self) -> Variant:
        """The CurPos reply: R8 array [x, y, z, rx, ry, rz, fig], or the configured fault."""
        p = self._p_now()
        bad = self.faults.bad_curpos
        if bad is None:
            return Variant(VT_R8 | VT_ARRAY, p)
        log.info("DENSO mock: fault: CurPos reply %s", bad)
        if bad in ("nan", "inf"):
            return Variant(VT_R8 | VT_ARRAY, [float(bad)] + p[1:])
        if bad == "short":
            return Variant(VT_R8 | VT_ARRAY, p[:5])
        if bad == "long":
            return Variant(VT_R8 | VT_ARRAY, p + [0.0, 0.0])
        if bad == "bstr":
            return Variant(VT_BSTR, "P(" + ", ".join(f"{x:g}" for x in p) + ")")
        if bad == "bool_array":
            return Variant(VT_BOOL | VT_ARRAY, [True] * 7)
        if bad == "empty":
            return Variant(VT_EMPTY)
        return Variant(VT_VARIANT | VT_ARRAY,
                       [Variant(VT_R8, x) for x in p[:6]] + [Variant(VT_BSTR, "-1")])

    def _var_value(self, name: str) -> Variant:
        if name == "@CURRENT_POSITION":
            return self._cur_pos()
        if name == "@CURRENT_ANGLE":
            return Variant(VT_R8 | VT_ARRAY, [0.0] * 8)
        if name == "@VERSION":
            return Variant(VT_BSTR, "tmscal DENSO b-CAP mock 1.0")
        if name == "@MODE":
            return Variant(VT_I4, 3)
        if name in self.variables:
            return self.variables[name]
        kind = name[0]
        if kind == "I":
            return Variant(VT_I4, 0)
        if kind in "FD":
            return Variant(VT_R8 if kind == "D" else VT_R4, 0.0)
        if kind == "S":
            return Variant(VT_BSTR, "")
        return Variant(VT_R8 | VT_ARRAY, [0.0] * (7 if kind == "P" else 6))

    def _robot_execute(self, sess: _Session, cmd: str, param: Variant) -> Variant:
        c = cmd.lower()
        if c == "takearm":
            _numbers(param, "TakeArm")
            sess.arm = True
            return Variant(VT_EMPTY)
        if c == "givearm":
            sess.arm = False
            return Variant(VT_EMPTY)
        if c == "motor":
            vals = _numbers(param, "Motor")
            if not vals:
                raise _Reply(E_INVALIDARG, "Motor needs a state (0 or 1)")
            if vals[0] != 0 and not sess.arm:
                raise _Reply(E_ACCESSDENIED, "Motor on without TakeArm")
            self.motor_on = vals[0] != 0
            return Variant(VT_EMPTY)
        if c == "extspeed":
            vals = _numbers(param, "ExtSpeed")
            if not 1 <= len(vals) <= 3:
                raise _Reply(E_INVALIDARG, f"ExtSpeed needs [speed, accel, decel], got {vals}")
            speed = _pct(vals[0], "ExtSpeed speed")
            # omitted accel / decel: speed² / 100, as the RC8 does
            accel = _pct(vals[1], "ExtSpeed accel") if len(vals) > 1 else max(
                speed * speed / 100.0, PCT_MIN)
            decel = _pct(vals[2], "ExtSpeed decel") if len(vals) > 2 else accel
            with self._lock:
                self.ext_speed, self.ext_accel, self.ext_decel = speed, accel, decel
                self.ext_speed_log = [*self.ext_speed_log[-999:], (speed, accel, decel)]
            return Variant(VT_EMPTY)
        if c == "curpos":
            return self._cur_pos()
        if c == "curjnt":
            return Variant(VT_R8 | VT_ARRAY, [0.0] * 8)
        raise _Reply(E_NOTIMPL, f"Robot_Execute {cmd!r} not implemented by the mock")

    def _move(self, sess: _Session, serial: int, comp: int, pose: Variant,
              option: str) -> Any:
        with self._lock:
            self.stats["moves"] += 1
            k = self.stats["moves"]
            fail = (self.faults.fail_move_at == k
                    or (self.faults.move_fail_rate > 0
                        and self._rng.random() < self.faults.move_fail_rate))
        if comp not in (1, 2):
            raise _Reply(E_NOTIMPL if comp == 3 else E_INVALIDARG,
                         f"Robot_Move comp {comp} (mock supports 1 = MOVE P, 2 = MOVE L)")
        p = _parse_pose(pose)
        opts = _options(option)
        pct = _opt_pct(opts, ("SPEED", "S"), "SPEED", option)
        if pct is None:
            pct = _pct(self.robot_speed, "Robot_Speed")
        accel = _opt_pct(opts, ("ACCEL", "A"), "ACCEL", option)
        decel = _opt_pct(opts, ("DECEL", "D"), "DECEL", option)
        if not sess.arm:
            raise _Reply(E_ACCESSDENIED, "Robot_Move without TakeArm")
        if not self.motor_on:
            raise _Reply(E_MOTOR_OFF, "Robot_Move with the motor off")
        if fail:
            raise _Reply(self.faults.fail_move_hresult, f"fault injected at move {k}")
        target = matrix_from_denso_p(p[:6])
        if not np.isfinite(target).all():
            raise _Reply(E_INVALIDARG, f"pose {p} gives a non-finite target")
        speed = self.max_linear_speed_mm_s * pct / 100.0 * self.ext_speed / 100.0
        dist = float(np.linalg.norm(target[:3, 3] - self.rig.reported_flange()[:3, 3]))
        if self.clock.fast:
            duration = 0.0
        elif self.motion_time_s is not None:
            duration = float(self.motion_time_s)
        else:
            duration = dist / speed if speed > 0 else math.inf
        if not math.isfinite(duration):
            raise _Reply(E_INVALIDARG, f"a move of {dist:g} mm at {speed:g} mm/s never ends")
        self.move_accel, self.move_decel = accel, decel
        if p[6] >= 0:
            self.fig = int(p[6])
        if duration <= 0:
            self.rig.move_flange(target)
            return None
        now = self.clock.now()
        nxt = "NEXT" in opts
        sess.job = _Job(target=target, start=now, end=now + duration,
                        serial=None if nxt else serial, wdt_s=sess.wdt_s)
        return None if nxt else _DEFERRED


_DEFERRED = object()

__all__ = ["DensoMock", "DensoFaults"]
