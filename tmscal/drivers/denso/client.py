"""b-CAP client over TCP: connection, request/reply matched by serial, keep-alives, and
the one place where a failure HRESULT becomes an exception (:meth:`BCAPClient.call`).

Errors (all with ``device="denso"``): a failure HRESULT raises ``RobotFault`` for controller
errors (≥ 0x81000000, and for every failed Robot_Move) and ``DeviceError`` otherwise, with
``code`` the HRESULT and ``text`` its name; no reply in time raises ``DeviceTimeout`` (code
E_TIMEOUT); bytes that do not decode raise ``ProtocolError`` (code E_INVALIDPACKET); a dropped
connection raises ``ConnectionLost``.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
from typing import Any

from ...errors import ConnectionLost, DeviceError, DeviceTimeout, ProtocolError, RobotFault
from ...net import connect_problem
from ...timing import Deadline
from .hresult import (
    DEVICE,
    E_TIMEOUT,
    S_EXECUTING,
    hresult_name,
    invalid_packet,
    is_controller_error,
)
from .packet import Fn, Packet, PacketFramer, encode_packet, function_name, next_serial
from .variant import NUMERIC_VTS, VT_ARRAY, VT_I4, VT_R4, VT_VARIANT, Variant, vt_name

log = logging.getLogger(__name__)

#: The TCP port of b-CAP on an RC8 controller.
DEFAULT_PORT = 5007
#: Longest single socket wait while a reply is awaited (s); the deadline is checked between.
_RECV_POLL_S = 1.0


def finite_numbers(v: Variant | None, what: str, min_len: int, max_len: int) -> list[float]:
    """The values of a reply that must be an array of ``min_len``..``max_len`` finite numbers:
    a numeric typed array (I2, I4, I8, R4, R8, UI1–UI8) or a VARIANT array whose elements are
    numeric scalars. Anything else raises ``ProtocolError`` naming ``what`` and the fault."""
    where = f"b-CAP {what}"
    if v is None:
        raise invalid_packet("the reply carries no value (expected an array of numbers)", where)
    if v.vt == VT_VARIANT | VT_ARRAY:
        for i, e in enumerate(v.value):
            if e.vt not in NUMERIC_VTS:
                raise invalid_packet(f"element {i} is {e!r}, not a number", where)
        raw = [e.value for e in v.value]
    elif v.vt & VT_ARRAY and (v.vt & ~VT_ARRAY) in NUMERIC_VTS:
        raw = list(v.value)
    else:
        raise invalid_packet(f"expected an array of numbers, got {vt_name(v.vt)}", where)
    if not min_len <= len(raw) <= max_len:
        want = f"{min_len}" if min_len == max_len else f"{min_len} to {max_len}"
        raise invalid_packet(f"{len(raw)} values, expected {want}", where)
    vals = [float(x) for x in raw]
    bad_idx = [i for i, x in enumerate(vals) if not math.isfinite(x)]
    if bad_idx:
        raise invalid_packet(f"non-finite value {vals[bad_idx[0]]} at index {bad_idx[0]} in "
                             f"{vals}", where)
    return vals


#: The functions whose wait for a reply each S_EXECUTING keep-alive re-arms: a Robot_Move
#: lasts as long as its path takes, and the controller's WDT keep-alives say it still runs.
#: Every other request (Service_Start, Robot_Halt, …) has one overall deadline that
#: keep-alives cannot extend, so a controller that keeps answering "still executing" cannot
#: hold a caller (a stop, a connect) beyond its bound.
KEEPALIVE_REARMS: frozenset[int] = frozenset({Fn.ROBOT_MOVE})


class BCAPClient:
    """A b-CAP client over TCP: one request at a time, replies matched by serial.

    ``timeout_s`` bounds the TCP connect and the wait for each reply: for a Robot_Move, the
    wait after the request was sent or after the last S_EXECUTING keep-alive for it (the
    controller sends those while a command runs when Service_Start set ``WDT=<ms>``); for
    every other function (:data:`KEEPALIVE_REARMS`), the whole wait from the request,
    keep-alives or not. Packets with a foreign serial and keep-alives are discarded. Errors
    as in the module doc; a failed call names the function.
    """

    #: The ``device`` of every error this client raises.
    name = DEVICE

    def __init__(self, host: str, port: int = DEFAULT_PORT, timeout_s: float = 5.0) -> None:
        self.host = host
        self.port = int(port)
        self.timeout_s = float(timeout_s)
        self._sock: socket.socket | None = None
        self._framer = PacketFramer()
        self._serial = 0
        self._call_lock = threading.Lock()
        self._send_lock = threading.Lock()

    # lifecycle
    def connect(self, timeout_s: float | None = None) -> BCAPClient:
        """Open the TCP connection (idempotent), waiting at most ``timeout_s`` (default the
        client's ``timeout_s``)."""
        if self._sock is not None:
            return self
        wait = self.timeout_s if timeout_s is None else timeout_s
        try:
            s = socket.create_connection((self.host, self.port), timeout=wait)
        except OSError as e:
            why = connect_problem(e, self.host, self.port, "robot.host, robot.port", wait,
                                  service="b-CAP")
            raise ConnectionLost(f"b-CAP: cannot connect to {self._where()}: {why or e}",
                                 device=self.name) from e
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = s
        self._framer = PacketFramer()
        return self

    def close(self) -> None:
        """Close the TCP connection (safe twice). The controller releases every object."""
        s, self._sock = self._sock, None
        if s is not None:
            try:
                s.close()
            except OSError:  # pragma: no cover
                pass

    @property
    def connected(self) -> bool:
        return self._sock is not None

    @property
    def busy(self) -> bool:
        """True while a call waits for its reply (another thread may only ``send_only``)."""
        return self._call_lock.locked()

    def __enter__(self) -> BCAPClient:
        return self.connect()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # core
    def _where(self) -> str:
        return f"{self.host}:{self.port}"

    def _lost(self, fname: str, what: str) -> ConnectionLost:
        """Close the connection and return the error saying so (``what`` ends the message)."""
        self.close()
        return ConnectionLost(f"b-CAP {fname}: {what}", device=self.name)

    def _send(self, data: bytes, fname: str) -> None:
        if self._sock is None:
            raise ConnectionLost(f"b-CAP {fname}: not connected to {self._where()}",
                                 device=self.name)
        try:
            with self._send_lock:
                self._sock.sendall(data)
        except OSError as e:
            raise self._lost(fname, f"send to {self._where()} failed: {e}") from e

    def _next_serial(self) -> int:
        self._serial = next_serial(self._serial)
        return self._serial

    def send_only(self, func: int, *args: Any) -> int:
        """Send a request without waiting for its reply (its reply is later discarded as a
        foreign serial). For Robot_Halt while another thread waits on a move. Returns the
        serial."""
        serial = self._next_serial()
        self._send(encode_packet(serial, int(func), args), function_name(func))
        return serial

    def call(self, func: int, *args: Any, timeout_s: float | None = None) -> Variant | None:
        """Send ``func(*args)`` (Variants or Python values) and wait for its reply, at most
        ``timeout_s`` (default the client's; re-armed by keep-alives only for the functions in
        :data:`KEEPALIVE_REARMS`). Returns the reply's value (a Variant) or None when the
        reply carries none."""
        fname = function_name(func)
        with self._call_lock:
            serial = self._next_serial()
            self._send(encode_packet(serial, int(func), args), fname)
            reply = self._wait_reply(serial, fname,
                                     self.timeout_s if timeout_s is None else timeout_s,
                                     rearm=func in KEEPALIVE_REARMS)
        if reply.failed:
            raise self._failure(func, reply.code)
        return reply.args[0] if reply.args else None

    def _failure(self, func: int, code: int) -> DeviceError:
        """The exception for a failure HRESULT ``code`` in reply to ``func``: ``RobotFault``
        for controller errors and failed moves, ``DeviceError`` otherwise; ``code`` is the
        HRESULT, ``text`` its name."""
        name = hresult_name(code)
        cls = RobotFault if is_controller_error(code) or func == Fn.ROBOT_MOVE else DeviceError
        return cls(f"b-CAP {function_name(func)} failed: 0x{code:08X} ({name})", code=code,
                   text=name, device=self.name)

    def _wait_reply(self, serial: int, fname: str, timeout_s: float, rearm: bool) -> Packet:
        """The reply with ``serial`` within ``timeout_s``: foreign serials are discarded;
        an S_EXECUTING keep-alive restarts the wait when ``rearm``, and is only discarded
        otherwise (one overall deadline)."""
        deadline = Deadline(max(timeout_s, 0.0))
        while True:
            try:
                pkt = self._framer.next_packet()
            except ProtocolError as e:  # the framer's own error, named after the call
                raise ProtocolError(f"b-CAP {fname}: {e.args[0]}", code=e.code, text=e.text,
                                    device=self.name) from e
            if pkt is None:
                self._receive(fname, deadline)
            elif pkt.serial != serial:
                log.debug("b-CAP %s: discarding packet with foreign serial %d (expected %d)",
                          fname, pkt.serial, serial)
            elif pkt.code == S_EXECUTING:
                log.debug("b-CAP %s: S_EXECUTING keep-alive", fname)
                if rearm:
                    deadline.restart()
            else:
                return pkt

    def _receive(self, fname: str, deadline: Deadline) -> None:
        """Feed the framer what arrives within ``_RECV_POLL_S`` (nothing on a quiet link);
        ``DeviceTimeout`` once ``deadline`` has passed, ``ConnectionLost`` on a drop."""
        remaining = deadline.remaining()
        if remaining <= 0:
            raise DeviceTimeout(f"b-CAP {fname}: no reply from {self._where()} within "
                                f"{deadline.timeout_s:g} s", code=E_TIMEOUT,
                                text=hresult_name(E_TIMEOUT), device=self.name)
        sock = self._sock
        if sock is None:
            raise ConnectionLost(f"b-CAP {fname}: connection to {self._where()} closed",
                                 device=self.name)
        try:
            sock.settimeout(min(remaining, _RECV_POLL_S))
            data = sock.recv(65536)
        except TimeoutError:
            return
        except OSError as e:
            raise self._lost(fname, f"connection to {self._where()} dropped: {e}") from e
        if not data:
            raise self._lost(fname, f"{self._where()} closed the connection while a reply "
                                    "was awaited")
        self._framer.feed(data)

    def _value(self, func: int, *args: Any, timeout_s: float | None = None) -> Any:
        v = self.call(func, *args, timeout_s=timeout_s)
        return None if v is None else v.to_python()

    def _handle(self, func: int, *args: Any, timeout_s: float | None = None) -> int:
        v = self.call(func, *args, timeout_s=timeout_s)
        if v is None or v.vt not in NUMERIC_VTS or isinstance(v.value, float):
            raise invalid_packet(f"expected a handle (I4), got {v!r}",
                                 f"b-CAP {function_name(func)}")
        return int(v.value)

    # functions
    def service_start(self, option: str = "", timeout_s: float | None = None) -> None:
        """Service_Start; ``option`` e.g. ``",WDT=400,InvokeTimeout=180000"``."""
        self.call(Fn.SERVICE_START, option, timeout_s=timeout_s)

    def service_stop(self) -> None:
        self.call(Fn.SERVICE_STOP)

    def controller_connect(self, name: str = "", provider: str = "CaoProv.DENSO.VRC",
                           machine: str = "localhost", option: str = "",
                           timeout_s: float | None = None) -> int:
        """Controller_Connect → controller handle."""
        return self._handle(Fn.CONTROLLER_CONNECT, name, provider, machine, option,
                            timeout_s=timeout_s)

    def controller_disconnect(self, handle: int) -> None:
        self.call(Fn.CONTROLLER_DISCONNECT, Variant(VT_I4, handle))

    def controller_get_robot(self, handle: int, name: str = "Arm", option: str = "",
                             timeout_s: float | None = None) -> int:
        """Controller_GetRobot → robot handle."""
        return self._handle(Fn.CONTROLLER_GETROBOT, Variant(VT_I4, handle), name, option,
                            timeout_s=timeout_s)

    def controller_get_variable(self, handle: int, name: str, option: str = "") -> int:
        """Controller_GetVariable → variable handle."""
        return self._handle(Fn.CONTROLLER_GETVARIABLE, Variant(VT_I4, handle), name, option)

    def controller_get_robot_names(self, handle: int, option: str = "") -> list[str]:
        return self._value(Fn.CONTROLLER_GETROBOTNAMES, Variant(VT_I4, handle), option) or []

    def controller_execute(self, handle: int, command: str, param: Any = None) -> Any:
        """Controller_Execute → plain Python value (None for EMPTY)."""
        return self._value(Fn.CONTROLLER_EXECUTE, Variant(VT_I4, handle), command, param)

    def robot_execute(self, handle: int, command: str, param: Any = None,
                      timeout_s: float | None = None) -> Any:
        """Robot_Execute (TakeArm, GiveArm, Motor, ExtSpeed, CurPos, CurJnt …) → plain Python
        value (None for EMPTY)."""
        return self._value(Fn.ROBOT_EXECUTE, Variant(VT_I4, handle), command, param,
                           timeout_s=timeout_s)

    def take_arm(self, handle: int, group: int = 0, keep: int = 0) -> None:
        self.robot_execute(handle, "TakeArm", [group, keep])

    def give_arm(self, handle: int) -> None:
        self.robot_execute(handle, "GiveArm", None)

    def motor(self, handle: int, on: bool) -> None:
        """Motor on/off; waits until the controller confirms (``[state, 0]``)."""
        self.robot_execute(handle, "Motor", [1 if on else 0, 0])

    def ext_speed(self, handle: int, speed: float, accel: float, decel: float) -> None:
        """ExtSpeed in percent."""
        self.robot_execute(handle, "ExtSpeed", [float(speed), float(accel), float(decel)])

    def cur_pos(self, handle: int) -> list[float]:
        """CurPos: P-type [x, y, z (mm), rx, ry, rz (deg)] plus fig when the controller sends
        it (6 or 7 finite numbers). A reply that is not an array of numbers (a numeric typed
        array such as VT_R8|VT_ARRAY, or a VARIANT array of numbers), has another length, or
        holds NaN/±inf raises ``ProtocolError`` naming CurPos and the fault."""
        v = self.call(Fn.ROBOT_EXECUTE, Variant(VT_I4, handle), "CurPos", None)
        return finite_numbers(v, "Robot_Execute CurPos", 6, 7)

    def cur_jnt(self, handle: int) -> list[float]:
        """CurJnt: joint angles in degrees (1 to 32 finite numbers; otherwise
        ``ProtocolError`` as for :meth:`cur_pos`)."""
        v = self.call(Fn.ROBOT_EXECUTE, Variant(VT_I4, handle), "CurJnt", None)
        return finite_numbers(v, "Robot_Execute CurJnt", 1, 32)

    def robot_move(self, handle: int, comp: int, pose: Any, option: str = "",
                   timeout_s: float | None = None) -> None:
        """Robot_Move; comp 1 = MOVE P, 2 = MOVE L; ``pose`` a text like ``"@P P(…)"`` or a
        VARIANT array ``[[x, y, z, rx, ry, rz, fig], "P", "@E"]`` (mm, deg; ``@E``: the reply
        comes when the arm has reached the target and settled, ``@P`` / ``@0`` may reply
        before). Without NEXT in ``option`` the reply comes when the motion is done. The
        connection is busy meanwhile (E_BUSY_PROC to anything else, Robot_Halt included):
        halt over another connection. Failures raise ``RobotFault``."""
        self.call(Fn.ROBOT_MOVE, Variant(VT_I4, handle), Variant(VT_I4, comp), pose, option,
                  timeout_s=timeout_s)

    def robot_halt(self, handle: int, option: str = "", wait: bool = True,
                   timeout_s: float | None = None) -> None:
        """Robot_Halt; ``wait=False`` sends it without waiting for the reply. A controller
        answers it with E_BUSY_PROC on a connection that runs a move: send it over another
        connection (:class:`~tmscal.drivers.denso.halt.HaltLink`)."""
        if wait:
            self.call(Fn.ROBOT_HALT, Variant(VT_I4, handle), option, timeout_s=timeout_s)
        else:
            self.send_only(Fn.ROBOT_HALT, Variant(VT_I4, handle), option)

    def robot_speed(self, handle: int, axis: int, speed: float) -> None:
        self.call(Fn.ROBOT_SPEED, Variant(VT_I4, handle), Variant(VT_I4, axis),
                  Variant(VT_R4, float(speed)))

    def robot_get_variable(self, handle: int, name: str, option: str = "") -> int:
        """Robot_GetVariable → variable handle (e.g. ``"@CURRENT_POSITION"``)."""
        return self._handle(Fn.ROBOT_GETVARIABLE, Variant(VT_I4, handle), name, option)

    def robot_release(self, handle: int) -> None:
        self.call(Fn.ROBOT_RELEASE, Variant(VT_I4, handle))

    def variable_get_value(self, handle: int) -> Any:
        """Variable_GetValue → plain Python value."""
        return self._value(Fn.VARIABLE_GETVALUE, Variant(VT_I4, handle))

    def variable_put_value(self, handle: int, value: Any) -> None:
        self.call(Fn.VARIABLE_PUTVALUE, Variant(VT_I4, handle), value)

    def variable_release(self, handle: int) -> None:
        self.call(Fn.VARIABLE_RELEASE, Variant(VT_I4, handle))


def close_down(client: BCAPClient, steps: list[tuple[str, Any]], what: str) -> None:
    """Run ``steps`` ((name, call) pairs: Robot_Release, Controller_Disconnect, Service_Stop
    …) while the link is up, best effort: a failed step is logged (naming ``what``), not
    raised, so the rest still run; then close the connection."""
    for name, fn in steps:
        if not client.connected:
            break
        try:
            fn()
        except (DeviceError, OSError) as e:
            log.warning("%s: %s failed: %s", what, name, e)
    client.close()


__all__ = ["BCAPClient", "DEFAULT_PORT", "KEEPALIVE_REARMS", "close_down",
           "finite_numbers"]
