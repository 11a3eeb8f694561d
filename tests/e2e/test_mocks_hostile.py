"""The mocks against hostile but well-formed requests, sent as raw bytes over real loopback
sockets: each is refused (an error reply, a refused recipe, a stopped program) without a
crash, a flood or a spin, the mock still serves a normal request afterwards, and nothing
non-finite reaches the shared sim rig."""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from tests.rigs import unique_host, wait_until
from tmscal.drivers.denso.hresult import (
    E_INVALIDARG,
    S_EXECUTING,
    S_OK,
)
from tmscal.drivers.denso.packet import (
    Fn,
    Packet,
    PacketFramer,
    encode_packet,
)
from tmscal.drivers.denso.variant import (
    VT_ARRAY,
    VT_I4,
    VT_R8,
    Variant,
)
from tmscal.geometry import make_pose, rotvec_pose_from_matrix
from tmscal.mocks.clock import FAST, REAL_TIME
from tmscal.mocks.denso import DensoMock
from tmscal.mocks.ur import (
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    URMock,
)
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

pytestmark = pytest.mark.e2e

NAN, INF = float("nan"), float("inf")


def new_rig() -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)


# --- DENSO: a raw b-CAP client built on tmscal's packet codec ---------------------------------

class RawBCAP:
    """One TCP connection; ``call`` sends one request and returns every packet up to and
    including its final reply (keep-alives included), so a flood would show."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10.0)
        self.framer = PacketFramer()
        self.serial = 0

    def call(self, fn: int, *args: Any) -> list[Packet]:
        self.serial += 1
        self.sock.sendall(encode_packet(self.serial, int(fn), args))
        got: list[Packet] = []
        while True:
            p = self.framer.next_packet()
            if p is None:
                data = self.sock.recv(65536)
                assert data, "the mock closed the connection"
                self.framer.feed(data)
                continue
            assert p.serial == self.serial
            got.append(p)
            if p.code != S_EXECUTING:
                return got

    def ok(self, fn: int, *args: Any) -> Variant | None:
        (reply,) = self.call(fn, *args)
        assert reply.code == S_OK, hex(reply.code)
        return reply.args[0] if reply.args else None

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def denso() -> Iterator[tuple[DensoMock, SimRig]]:
    rig = new_rig()
    # real-time clock: motion timing (where 5e-324 % divided by zero) is really computed
    with DensoMock(rig, clock=REAL_TIME) as m:
        m.start()
        yield m, rig


def _robot(c: RawBCAP) -> Variant:
    ctrl = c.ok(Fn.CONTROLLER_CONNECT, "", "CaoProv.DENSO.VRC", "localhost", "")
    assert ctrl is not None
    r = c.ok(Fn.CONTROLLER_GETROBOT, ctrl, "Arm", "")
    assert r is not None
    return Variant(VT_I4, r.value)


def _move_1mm(c: RawBCAP, r: Variant, rig: SimRig) -> None:
    """A normal blocking 1 mm MOVE L (@E: the reply comes when the arm is still) at full
    speed (1 ms of motion); the rig follows."""
    target = [501.0, 0.0, 400.0, 180.0, 0.0, 0.0, -1.0]
    replies = c.call(Fn.ROBOT_MOVE, r, Variant(VT_I4, 2), f"@E P({', '.join(map(str, target))})",
                     "SPEED=100")
    assert replies[-1].code == S_OK
    assert np.allclose(rig.flange[:3, 3], [501.0, 0.0, 400.0], atol=1e-9)


@pytest.mark.parametrize("option", [",WDT=-1", ",WDT=-400", ",WDT=1", ",WDT=99999999999",
                                    ",WDT=nan", ",WDT=1e3"])
def test_denso_wdt_out_of_range_is_refused(denso: tuple[DensoMock, SimRig], option: str) -> None:
    m, rig = denso
    c = RawBCAP(m.port)
    try:
        (reply,) = c.call(Fn.SERVICE_START, option)  # exactly one reply: no S_EXECUTING flood
        assert reply.code == E_INVALIDARG
        c.ok(Fn.SERVICE_START, ",WDT=400")
        r = _robot(c)
        c.ok(Fn.ROBOT_EXECUTE, r, "TakeArm", [0, 0])
        c.ok(Fn.ROBOT_EXECUTE, r, "Motor", [1, 0])
        _move_1mm(c, r, rig)
    finally:
        c.close()
    assert m.stats["keepalives"] < 10


@pytest.mark.parametrize("param", [
    [5e-324], [5e-324, 5e-324, 5e-324], [NAN], [INF], [-INF], [-10.0], [0.0], [100.5],
    [50.0, NAN, 50.0], [50.0, 50.0, INF], [50.0, -1.0, 50.0], [50.0, 0.0, 50.0],
    [50.0, 50.0, 50.0, 50.0], [],
])
def test_denso_ext_speed_hostile_values_are_refused(denso: tuple[DensoMock, SimRig],
                                                    param: list[float]) -> None:
    m, rig = denso
    c = RawBCAP(m.port)
    try:
        c.ok(Fn.SERVICE_START, "")
        r = _robot(c)
        c.ok(Fn.ROBOT_EXECUTE, r, "TakeArm", [0, 0])
        c.ok(Fn.ROBOT_EXECUTE, r, "Motor", [1, 0])
        arg = Variant(VT_R8 | VT_ARRAY, param)
        (reply,) = c.call(Fn.ROBOT_EXECUTE, r, "ExtSpeed", arg)
        assert reply.code == E_INVALIDARG
        assert (m.ext_speed, m.ext_accel, m.ext_decel) == (100.0, 100.0, 100.0)
        assert m.ext_speed_log == []
        _move_1mm(c, r, rig)  # still serving, and the motion timing still works
        c.ok(Fn.ROBOT_EXECUTE, r, "ExtSpeed", [50.0, 20.0, 10.0])
        assert m.ext_speed_log == [(50.0, 20.0, 10.0)]
    finally:
        c.close()
    assert np.isfinite(rig.flange).all()


@pytest.mark.parametrize("option", ["SPEED=5e-324", "SPEED=nan", "SPEED=inf", "SPEED=-5",
                                    "SPEED=0", "SPEED=50,ACCEL=nan", "SPEED=50,DECEL=-1",
                                    "SPEED=50,ACCEL=1e-320"])
def test_denso_move_option_hostile_values_are_refused(denso: tuple[DensoMock, SimRig],
                                                      option: str) -> None:
    m, rig = denso
    c = RawBCAP(m.port)
    try:
        c.ok(Fn.SERVICE_START, "")
        r = _robot(c)
        c.ok(Fn.ROBOT_EXECUTE, r, "TakeArm", [0, 0])
        c.ok(Fn.ROBOT_EXECUTE, r, "Motor", [1, 0])
        (reply,) = c.call(Fn.ROBOT_MOVE, r, Variant(VT_I4, 2),
                          "@P P(600, 0, 400, 180, 0, 0, -1)", option)
        assert reply.code == E_INVALIDARG
        assert np.array_equal(rig.flange, TMS_RIG_P0)
        _move_1mm(c, r, rig)
    finally:
        c.close()


@pytest.mark.parametrize("speed", [NAN, INF, 5e-324, 0.0])
def test_denso_robot_speed_hostile_values_are_refused(denso: tuple[DensoMock, SimRig],
                                                      speed: float) -> None:
    m, rig = denso
    c = RawBCAP(m.port)
    try:
        c.ok(Fn.SERVICE_START, "")
        r = _robot(c)
        (reply,) = c.call(Fn.ROBOT_SPEED, r, Variant(VT_I4, -1), Variant(VT_R8, speed))
        assert reply.code == E_INVALIDARG
        assert m.robot_speed == 100.0
        c.ok(Fn.ROBOT_EXECUTE, r, "TakeArm", [0, 0])
        c.ok(Fn.ROBOT_EXECUTE, r, "Motor", [1, 0])
        _move_1mm(c, r, rig)
    finally:
        c.close()


# --- UR: a raw RTDE client --------------------------------------------------------------------

class RawRTDE:
    """A bare RTDE client: the setup packages, then input packages and streamed outputs."""

    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, 30004), timeout=10.0)
        self.buf = b""

    def send(self, ptype: str, payload: bytes = b"") -> None:
        self.sock.sendall(struct.pack(">HB", 3 + len(payload), ord(ptype)) + payload)

    def recv(self) -> tuple[str, bytes]:
        while True:
            if len(self.buf) >= 3:
                size, ptype = struct.unpack(">HB", self.buf[:3])
                if len(self.buf) >= size:
                    payload, self.buf = self.buf[3:size], self.buf[size:]
                    return chr(ptype), payload
            data = self.sock.recv(65536)
            assert data, "the mock closed the RTDE connection"
            self.buf += data

    def request(self, ptype: str, payload: bytes = b"") -> bytes:
        """A setup request; its reply must be the very next package (nothing streamed)."""
        self.send(ptype, payload)
        got, reply = self.recv()
        assert got == ptype, f"expected the {ptype!r} reply, got {got!r}"
        return reply

    def close(self) -> None:
        self.sock.close()


MOVEL_RECIPE = ("input_int_register_0," + ",".join(f"input_double_register_{i}"
                                                   for i in range(8)) + ",input_int_register_1")


def _move_l(c: RawRTDE, rid: int, cmd: int, pose: list[float], speed: float,
            accel: float) -> None:
    c.send("U", struct.pack(">Bi8di", rid, cmd, *pose, speed, accel, 0))


def _control_client(host: str) -> tuple[RawRTDE, int, int]:
    """A client with the moveL input recipe and a clear-command recipe (ids returned)."""
    c = RawRTDE(host)
    assert c.request("V", struct.pack(">H", 2)) == b"\x01"
    rid = c.request("I", MOVEL_RECIPE.encode())[0]
    clear = c.request("I", b"input_int_register_0")[0]
    return c, rid, clear


@pytest.fixture
def ur() -> Iterator[tuple[URMock, SimRig]]:
    rig = new_rig()
    with URMock(rig, host=unique_host(), clock=FAST) as m:
        yield m, rig


def _dashboard(host: str, line: str) -> str:
    with socket.create_connection((host, 29999), timeout=10.0) as s:
        f = s.makefile("rb")
        assert f.readline().startswith(b"Connected")
        s.sendall(line.encode() + b"\n")
        return f.readline().decode().strip()


_GOOD = [*rotvec_pose_from_matrix(TMS_RIG_P0 @ make_pose(t=[0.0, 0.0, 10.0]))]


@pytest.mark.parametrize("pose, speed, accel", [
    ([NAN, 0, 0.4, 3.14, 0, 0], 0.25, 1.2),
    ([0.5, 0, 0.4, INF, 0, 0], 0.25, 1.2),
    ([1e308, 0, 0.4, 3.14, 0, 0], 0.25, 1.2),      # finite metres, infinite millimetres
    (_GOOD, NAN, 1.2),
    (_GOOD, INF, 1.2),
    (_GOOD, -0.25, 1.2),
    (_GOOD, 0.25, NAN),
    (_GOOD, 0.25, 0.0),
])
def test_ur_non_finite_move_never_reaches_the_rig(ur: tuple[URMock, SimRig], pose: list[float],
                                                  speed: float, accel: float) -> None:
    m, rig = ur
    c, rid, clear = _control_client(m.host)
    try:
        _move_l(c, rid, 3, pose, speed, accel)
        wait_until(lambda: m.runtime_state == RUNTIME_STOPPED, 10.0, "the runtime error")
        assert np.array_equal(rig.flange, TMS_RIG_P0) and np.isfinite(rig.commanded).all()
        assert np.isfinite(m.tcp_pose()).all()
        # the controller still serves: clear, play, and a normal moveL works
        c.send("U", struct.pack(">Bi", clear, 0))
        wait_until(lambda: m.in_int[0] == 0, 10.0, "the clear command")
        assert _dashboard(m.host, "play") == "Starting program"
        wait_until(lambda: m.runtime_state == RUNTIME_PLAYING and m.out_int[0] == 1, 10.0,
                   "the program to run again")
        _move_l(c, rid, 3, _GOOD, 0.25, 1.2)
        wait_until(lambda: m.out_int[0] == 2, 10.0, "the good moveL to finish")
        assert np.allclose(rig.flange, TMS_RIG_P0 @ make_pose(t=[0.0, 0.0, 10.0]), atol=1e-9)
    finally:
        c.close()


def test_ur_non_finite_joint_target_is_refused(ur: tuple[URMock, SimRig]) -> None:
    m, rig = ur
    c, rid, _ = _control_client(m.host)
    try:
        q = list(m.target_q)
        _move_l(c, rid, 1, [NAN, 0, 0, 0, 0, 0], 1.0, 1.0)  # moveJ
        wait_until(lambda: m.runtime_state == RUNTIME_STOPPED, 10.0, "the runtime error")
        assert m.target_q == q and np.array_equal(rig.flange, TMS_RIG_P0)
    finally:
        c.close()


_OUTPUTS = b"timestamp,output_int_register_0,actual_TCP_pose"


@pytest.mark.parametrize("freq", [1e-300, INF, -INF, NAN, -125.0, 0.0, 0.5, 1e6])
def test_ur_rtde_bad_output_frequency_is_refused(ur: tuple[URMock, SimRig], freq: float) -> None:
    m, rig = ur
    c = RawRTDE(m.host)
    try:
        assert c.request("V", struct.pack(">H", 2)) == b"\x01"
        assert c.request("O", struct.pack(">d", freq) + _OUTPUTS) == b"\x00"  # id 0: refused
        assert c.request("S") == b"\x00"                                      # not started
        # nothing streams: the next package is the reply to the next request
        assert c.request("v") == struct.pack(">IIII", *m.version)
        assert c.request("V", struct.pack(">H", 2)) == b"\x01"
        # a valid recipe on the same connection then streams normally
        reply = c.request("O", struct.pack(">d", 125.0) + _OUTPUTS)
        assert reply[:1] == b"\x01" and reply[1:] == b"DOUBLE,INT32,VECTOR6D"
        assert c.request("S") == b"\x01"
        ptype, data = c.recv()
        assert ptype == "U" and len(data) == 1 + 8 + 4 + 48
        tcp = struct.unpack(">6d", data[13:])
        assert np.allclose(tcp, rotvec_pose_from_matrix(TMS_RIG_P0), atol=1e-9)
    finally:
        c.close()
