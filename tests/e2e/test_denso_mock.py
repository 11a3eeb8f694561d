"""Our b-CAP client and DensoRobot against our DENSO mock over real loopback sockets,
including the error paths (no TakeArm, motor off, busy, faults, dropped connection), and the
client's handling of keep-alives and foreign serials against a scripted server."""

from __future__ import annotations

import dataclasses
import ipaddress
import socket
import threading
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from tests.rigs import free_port, unique_host
from tmscal.drivers.base import Envelope
from tmscal.drivers.denso.client import BCAPClient
from tmscal.drivers.denso.hresult import (
    E_ACCESSDENIED,
    E_BUSY_PROC,
    E_EMERGENCY_STOP,
    E_HANDLE,
    E_INVALIDPACKET,
    E_MOTOR_OFF,
    S_EXECUTING,
    S_OK,
)
from tmscal.drivers.denso.packet import (
    Fn,
    PacketFramer,
    encode_packet,
)
from tmscal.drivers.denso.robot import DensoRobot
from tmscal.drivers.denso.variant import (
    VT_ARRAY,
    VT_BSTR,
    VT_I2,
    VT_I4,
    VT_R4,
    VT_UI4,
    VT_VARIANT,
    Variant,
    to_variant,
)
from tmscal.errors import (
    ConfigError,
    ConnectionLost,
    DeviceError,
    DeviceTimeout,
    ProtocolError,
    RobotFault,
    SafetyError,
)
from tmscal.geometry import make_pose, rot_x, rot_y, rot_z
from tmscal.mocks.clock import FAST, REAL_TIME
from tmscal.mocks.denso import DensoFaults, DensoMock
from tmscal.motion import trapezoid_duration
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

pytestmark = pytest.mark.e2e


def new_rig() -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)


def port_of(endpoint: str) -> int:
    host, _, port = endpoint.rpartition(":")
    assert host == "127.0.0.1"
    return int(port)


@pytest.fixture
def rig() -> SimRig:
    return new_rig()


@pytest.fixture
def mock(rig: SimRig) -> Iterator[DensoMock]:
    with DensoMock(rig, clock=FAST) as m:
        yield m


@pytest.fixture
def client(mock: DensoMock) -> Iterator[BCAPClient]:
    with BCAPClient("127.0.0.1", port_of(mock.start()), timeout_s=5.0) as c:
        yield c


def open_robot(c: BCAPClient, wdt: str = "") -> int:
    c.service_start(wdt)
    h = c.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
    return c.controller_get_robot(h, "Arm", "")


# expected rotation for P(…, 180, 0, 90): Rz(90)·Rx(180), hand-computed
R_180_0_90 = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def test_move_without_takearm_then_without_motor(client: BCAPClient, rig: SimRig) -> None:
    r = open_robot(client)
    pose = "@E P(400, 50, 300, 180, 0, 90, -1)"
    with pytest.raises(DeviceError) as ei:
        client.robot_move(r, 2, pose, "")
    assert ei.value.code == E_ACCESSDENIED and ei.value.text == "E_ACCESSDENIED"
    client.take_arm(r)
    with pytest.raises(RobotFault) as ei:
        client.robot_move(r, 2, pose, "")
    assert ei.value.code == E_MOTOR_OFF == 0x81501003 and ei.value.text == "motor off"
    assert "Robot_Move" in str(ei.value) and "0x81501003" in str(ei.value)
    assert np.array_equal(rig.commanded, TMS_RIG_P0)  # nothing moved
    client.motor(r, True)
    client.robot_move(r, 1, pose, "SPEED=50")  # MOVE P with a text pose
    assert np.allclose(rig.commanded[:3, :3], R_180_0_90, atol=1e-12)
    assert np.allclose(rig.commanded[:3, 3], [400, 50, 300])


def test_variant_array_pose_with_mixed_number_types(client: BCAPClient, rig: SimRig) -> None:
    r = open_robot(client)
    client.take_arm(r)
    client.motor(r, True)
    nums = Variant(VT_VARIANT | VT_ARRAY, [
        Variant(VT_I2, 400), Variant(VT_I4, -50), Variant(VT_UI4, 300),
        Variant(VT_R4, 90.0), Variant(VT_I4, 0), Variant(VT_I2, 0), Variant(VT_I4, -1)])
    pose = Variant(VT_VARIANT | VT_ARRAY, [nums, Variant(VT_BSTR, "P"), Variant(VT_BSTR, "@P")])
    client.robot_move(r, 2, pose, "SPEED=10,NEXT")
    assert np.allclose(rig.commanded[:3, 3], [400, -50, 300])
    assert np.allclose(rig.commanded[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_curpos_and_current_position_variable(client: BCAPClient) -> None:
    r = open_robot(client)
    p = client.cur_pos(r)
    assert len(p) == 7 and np.allclose(p[:3], [500, 0, 400])
    assert np.isclose(abs(p[3]), 180) and np.allclose(p[4:6], 0, atol=1e-9)
    v = client.robot_get_variable(r, "@CURRENT_POSITION")
    q = client.variable_get_value(v)
    client.variable_release(v)
    assert np.allclose(q, p)
    assert len(client.cur_jnt(r)) == 8


def test_variables_errors_and_descriptions(client: BCAPClient) -> None:
    client.service_start("")
    h = client.controller_connect()
    v = client.controller_get_variable(h, "I1")
    client.variable_put_value(v, 42)
    assert client.variable_get_value(v) == 42
    assert client.controller_execute(h, "GetErrorDescription", 0x81501003) == "motor off"
    with pytest.raises(DeviceError) as ei:
        client.robot_execute(9999, "CurPos")
    assert ei.value.code == E_HANDLE and not isinstance(ei.value, RobotFault)
    assert client.controller_get_robot_names(h) == ["Arm"]
    client.controller_disconnect(h)
    client.service_stop()


def test_busy_connection_refuses_even_halt_which_comes_over_a_second_one(rig: SimRig) -> None:
    # hold_move_at=1: the motion runs until halted, so every request below meets it running
    with DensoMock(rig, clock=FAST, faults=DensoFaults(hold_move_at=1)) as m, \
            BCAPClient("127.0.0.1", port_of(m.start()), timeout_s=5.0) as c, \
            BCAPClient("127.0.0.1", m.port, timeout_s=5.0) as watch:
        r = open_robot(c)
        c.take_arm(r)
        c.motor(r, True)
        c.robot_move(r, 2, "@E P(500, 0, 300, 180, 0, 0)", "NEXT")  # answers at once
        for request in (lambda: c.cur_pos(r), lambda: c.robot_halt(r)):
            with pytest.raises(DeviceError) as ei:
                request()
            assert ei.value.code == E_BUSY_PROC and ei.value.text == "E_BUSY_PROC"
        w = open_robot(watch)  # DENSO's ROS driver halts over its own "watch" connection
        watch.robot_halt(w)
        assert np.allclose(c.cur_pos(r)[:3], [500, 0, 400])  # halted: rig not moved
        assert m.stats["busy"] == 2 and m.stats["halts"] == 1


def test_pass_move_replies_before_the_arm_is_still_end_move_after(client: BCAPClient,
                                                                  rig: SimRig) -> None:
    r = open_robot(client)
    client.take_arm(r)
    client.motor(r, True)
    start = rig.flange.copy()
    client.robot_move(r, 2, "@P P(510, 0, 400, 180, 0, 0)", "")
    assert np.allclose(rig.flange, start)  # replied; the arm is not yet at rest on the target
    assert np.allclose(client.cur_pos(r)[:3], [510, 0, 400])  # still by the next request
    client.robot_move(r, 2, to_variant([[520.0, 0.0, 400.0, 180.0, 0.0, 0.0, -1], "P", "@E"]),
                      "")
    assert np.allclose(rig.flange[:3, 3], [520, 0, 400])  # @E: at rest when it replies


def test_latched_error_blocks_takearm_until_clearerror(rig: SimRig) -> None:
    with DensoMock(rig, clock=FAST, faults=DensoFaults(latched_error=0x84204051)) as m, \
            BCAPClient("127.0.0.1", port_of(m.start()), timeout_s=5.0) as c:
        r = open_robot(c)
        with pytest.raises(RobotFault) as ei:
            c.take_arm(r)
        assert ei.value.code == 0x84204051
        c.controller_execute(1, "ClearError")  # controller handle 1: the first one made
        c.take_arm(r)
        c.motor(r, True)


def test_watchdog_keepalives_are_discarded(rig: SimRig) -> None:
    # a blocking move of 0.22 s with WDT=50 ms: keep-alives at 50, 100, 150, 200 ms
    with DensoMock(rig, clock=REAL_TIME, motion_time_s=0.22) as m, \
            BCAPClient("127.0.0.1", port_of(m.start()), timeout_s=10.0) as c:
        r = open_robot(c, ",WDT=50")
        c.take_arm(r)
        c.motor(r, True)
        c.robot_move(r, 2, "@E P(510, 0, 400, 180, 0, 0)", "")
        # returned only with the final reply: the rig is already at the target
        assert np.allclose(rig.commanded[:3, 3], [510, 0, 400])
        assert m.stats["keepalives"] == 4
        assert np.allclose(c.cur_pos(r)[:3], [510, 0, 400])


def test_dropped_connection_raises_connection_lost(rig: SimRig) -> None:
    with DensoMock(rig, clock=FAST, faults=DensoFaults(drop_at_request=2)) as m, \
            BCAPClient("127.0.0.1", port_of(m.start()), timeout_s=5.0) as c:
        c.service_start("")
        with pytest.raises(ConnectionLost, match="Controller_Connect"):
            c.controller_connect()
        assert not c.connected
        with pytest.raises(ConnectionLost):
            c.service_stop()


def test_malformed_request_gets_invalidpacket_reply(mock: DensoMock) -> None:
    bad = bytearray(encode_packet(5, Fn.SERVICE_START, [""]))
    bad[15] += 1  # argument length no longer matches its VARIANT
    with socket.create_connection(("127.0.0.1", port_of(mock.start())), timeout=5) as s:
        s.sendall(bytes(bad))
        f = PacketFramer()
        while (p := f.next_packet()) is None:
            f.feed(s.recv(4096))
    assert (p.serial, p.code, p.args) == (5, E_INVALIDPACKET, ())


# --- the client against a scripted server -----------------------------------------------------

def scripted_server(replies: Callable[[int], bytes]) -> tuple[int, threading.Thread, socket.socket]:
    """Accept one connection, read one request, send ``replies(serial)`` in one sendall, then
    keep the connection open until the client closes it."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(5)

    def run() -> None:
        conn, _ = srv.accept()
        with conn:
            conn.settimeout(5)
            f = PacketFramer()
            while (p := f.next_packet()) is None:
                f.feed(conn.recv(4096))
            data = replies(p.serial)
            if data:
                conn.sendall(data)
            try:
                conn.recv(1)  # until the client closes
            except OSError:
                pass

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return srv.getsockname()[1], t, srv


def test_client_skips_foreign_serials_and_keepalives() -> None:
    port, t, srv = scripted_server(lambda s: (
        encode_packet((s + 5) & 0xFFFF, S_OK, [Variant(VT_I4, 99)])
        + encode_packet(s, S_EXECUTING) + encode_packet(s, S_EXECUTING)
        + encode_packet(s, S_OK, [Variant(VT_I4, 7)])))
    with srv, BCAPClient("127.0.0.1", port, timeout_s=5.0) as c:
        assert c.controller_connect() == 7
    t.join(5)


def test_client_timeout_names_the_function() -> None:
    port, t, srv = scripted_server(lambda s: b"")
    with srv, BCAPClient("127.0.0.1", port, timeout_s=0.2) as c:
        with pytest.raises(DeviceTimeout, match="Service_Start") as ei:
            c.service_start("")
        assert isinstance(ei.value, TimeoutError)
        assert (ei.value.code, ei.value.text, ei.value.device) == (0x80000900, "E_TIMEOUT",
                                                                   "denso")
    t.join(5)


def test_client_bad_framing_is_a_protocol_error_naming_the_function() -> None:
    port, t, srv = scripted_server(lambda s: b"\x07" + encode_packet(s, S_OK))
    with srv, BCAPClient("127.0.0.1", port, timeout_s=5.0) as c:
        with pytest.raises(ProtocolError, match="Service_Start: b-CAP: wrong SOH") as ei:
            c.service_start("")
        assert (ei.value.code, ei.value.text, ei.value.device) == (E_INVALIDPACKET,
                                                                   "E_INVALIDPACKET", "denso")
    t.join(5)


def test_client_connect_refused() -> None:
    host = unique_host()
    port = free_port(host)   # nothing listens there
    with pytest.raises(ConnectionLost, match=str(port)):
        BCAPClient(host, port, timeout_s=1.0).connect()


# --- DensoRobot ----------------------------------------------------------------------------

def test_denso_robot_moves_the_sim_rig(rig: SimRig, mock: DensoMock) -> None:
    rng = np.random.default_rng(3)
    env = Envelope(center=TMS_RIG_P0, max_offset_mm=200, max_rotation_deg=40)
    with DensoRobot(port=port_of(mock.start()), envelope=env, watchdog_ms=None) as robot:
        ident = robot.identity()
        assert ident["driver"] == "denso" and ident["robot_name"] == "Arm"
        assert ident["provider"] == "CaoProv.DENSO.VRC" and "version" in ident["controller"]
        assert np.allclose(robot.flange_pose(), TMS_RIG_P0, atol=1e-9)
        for _ in range(10):
            ang = np.radians(rng.uniform(-25, 25, 3))
            target = TMS_RIG_P0 @ make_pose(rot_z(ang[2]) @ rot_y(ang[1]) @ rot_x(ang[0]),
                                            rng.uniform(-100, 100, 3))
            robot.move_to(target, speed_mm_s=50.0)
            assert np.allclose(rig.flange, target, atol=1e-9)  # noise-free rig: true pose
            assert np.allclose(robot.flange_pose(), target, atol=1e-9)
        with pytest.raises(SafetyError):
            robot.move_to(TMS_RIG_P0 @ make_pose(t=[0, 0, 500]))
    assert mock.motor_on is False
    assert mock.stats["moves"] == 10


def test_denso_robot_move_fault_and_motor_state(rig: SimRig) -> None:
    faults = DensoFaults(fail_move_at=2, fail_move_hresult=E_EMERGENCY_STOP)
    with DensoMock(rig, clock=FAST, faults=faults) as m, \
            DensoRobot(port=port_of(m.start())) as robot:
        first = TMS_RIG_P0 @ make_pose(t=[10, 0, 0])
        robot.move_to(first)
        with pytest.raises(RobotFault) as ei:
            robot.move_to(TMS_RIG_P0 @ make_pose(t=[20, 0, 0]))
        assert ei.value.code == 0x83500178
        assert ei.value.text == "not executable during emergency stop"
        assert np.allclose(rig.flange, first)
        robot.move_to(TMS_RIG_P0)  # one-shot fault: the next move works
        assert np.allclose(rig.flange, TMS_RIG_P0)


def test_denso_robot_connection_lost_during_move(rig: SimRig) -> None:
    with DensoMock(rig, clock=FAST) as m:
        robot = DensoRobot(port=port_of(m.start()))
        robot.open()
        m.faults = dataclasses.replace(m.faults, drop_at_request=m.stats["requests"] + 1)
        with pytest.raises(ConnectionLost):
            robot.move_to(TMS_RIG_P0 @ make_pose(t=[5, 0, 0]))
        robot.close()  # best effort, does not raise
        assert np.allclose(rig.flange, TMS_RIG_P0)


def test_denso_robot_open_fails_cleanly_on_unknown_robot(rig: SimRig, mock: DensoMock) -> None:
    robot = DensoRobot(port=port_of(mock.start()), robot_name="NoSuchArm")
    with pytest.raises(DeviceError, match="Controller_GetRobot"):
        robot.open()
    assert not robot.is_open


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "8.8.8.8", "192.168.0.1"])
def test_mock_refuses_non_loopback(rig: SimRig, host: str) -> None:
    with pytest.raises(ConfigError, match="loopback") as ei:
        DensoMock(rig, host=host)
    assert repr(host) in str(ei.value)


@pytest.mark.parametrize("host", ["localhost", "127.0.0.1", "::1"])
def test_mock_serves_on_every_loopback_spelling(rig: SimRig, host: str) -> None:
    try:
        m = DensoMock(rig, host=host, clock=FAST)
        endpoint = m.start()
    except OSError as e:  # pragma: no cover - a host without IPv6 loopback
        pytest.skip(f"cannot bind {host}: {e}")
    with m:
        port = int(endpoint.rpartition(":")[2])
        assert ipaddress.ip_address(m._listener.getsockname()[0]).is_loopback
        with BCAPClient(host, port, timeout_s=5.0) as c:
            c.service_start("")


def test_stop_halts_a_running_move_over_a_second_connection(rig: SimRig) -> None:
    from tests.rigs import wait_until

    # hold_move_at=1: the move runs until halted; timeout_s=20 only guards against a hang
    with DensoMock(rig, clock=FAST, faults=DensoFaults(hold_move_at=1)) as m, \
            DensoRobot(port=port_of(m.start()), timeout_s=20.0) as robot:
        errors: list[BaseException] = []
        started = threading.Event()

        def move() -> None:
            started.set()
            try:
                robot.move_to(TMS_RIG_P0 @ make_pose(t=[0, 0, 50]))
            except BaseException as e:  # handed to the test thread
                errors.append(e)

        t = threading.Thread(target=move, daemon=True)
        t.start()
        started.wait(10.0)
        wait_until(lambda: m.motion is not None, 10.0, "the mock to start the move")
        robot.stop()  # returns once the controller acknowledged the halt
        t.join(10.0)
        assert not t.is_alive()
        assert len(errors) == 1 and isinstance(errors[0], RobotFault)
        assert errors[0].code == 0x80004005  # the mock answers a halted move with E_FAIL
        assert m.stats["halts"] == 1 and m.stats["busy"] == 0
        assert np.allclose(robot.flange_pose(), TMS_RIG_P0)


def test_stop_raises_when_the_halt_cannot_reach_the_controller(rig: SimRig) -> None:
    m = DensoMock(rig, clock=FAST)
    robot = DensoRobot(port=port_of(m.start()), halt_timeout_s=2.0)
    with m:
        robot.open()
    # the controller is gone: the halt connection is reopened once, refused, and said so
    with pytest.raises(ConnectionLost, match="cannot connect"):
        robot.stop()
    robot.close()  # best effort, does not raise
    robot.stop()  # a closed robot: never raises


#: how long a test waits for a call that must end within its (much shorter) bound before it
#: calls it hung: a liveness guard, not a timing check
HANG_GUARD_S = 30.0


def _call_in_thread(fn: Callable[[], object]) -> tuple[threading.Thread, list[BaseException]]:
    """Run ``fn`` in a daemon thread; what it raises lands in the returned list."""
    errors: list[BaseException] = []

    def run() -> None:
        try:
            fn()
        except BaseException as e:  # handed to the test thread
            errors.append(e)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t, errors


def test_stop_is_bounded_when_the_controller_keeps_the_halt_alive_for_ever(rig: SimRig) -> None:
    """Robot_Halt answered only by S_EXECUTING keep-alives, for ever: the halt's wait is one
    deadline (halt_timeout_s) that keep-alives do not re-arm, so stop() ends with a
    DeviceTimeout naming Robot_Halt instead of hanging."""
    m = DensoMock(rig, clock=FAST, faults=DensoFaults(stuck_functions=("Robot_Halt",)))
    robot = DensoRobot(port=port_of(m.start()), halt_timeout_s=0.5)
    try:
        robot.open()
        t, errors = _call_in_thread(robot.stop)
        t.join(HANG_GUARD_S)
        assert not t.is_alive(), "stop() still waiting: keep-alives extended the halt's bound"
        assert m.stats["keepalives"] >= 1          # the controller did keep it alive
        assert len(errors) == 1 and isinstance(errors[0], DeviceTimeout), errors
        assert "Robot_Halt" in str(errors[0]) and errors[0].code == 0x80000900
    finally:
        m.close()       # ends a hung stop() (ConnectionLost) before the robot is closed
        robot.close()


def test_open_is_bounded_when_the_controller_keeps_service_start_alive(rig: SimRig) -> None:
    """Service_Start answered only by keep-alives: open() raises DeviceTimeout naming it
    within timeout_s instead of waiting for ever, and leaves nothing open."""
    m = DensoMock(rig, clock=FAST, faults=DensoFaults(stuck_functions=("Service_Start",)))
    robot = DensoRobot(port=port_of(m.start()), timeout_s=0.5)
    try:
        t, errors = _call_in_thread(robot.open)
        t.join(HANG_GUARD_S)
        assert not t.is_alive(), "open() still waiting: keep-alives extended Service_Start"
        assert m.stats["keepalives"] >= 1
        assert len(errors) == 1 and isinstance(errors[0], DeviceTimeout), errors
        assert "Service_Start" in str(errors[0])
        assert not robot.is_open
    finally:
        m.close()
        robot.close()


def test_halt_link_bound_covers_its_reconnect(rig: SimRig) -> None:
    """A halt whose link must be (re)opened first: connect, Service_Start, Controller_Connect,
    Controller_GetRobot and Robot_Halt all share one deadline of timeout_s, so a controller
    stuck in Controller_GetRobot also ends the halt with DeviceTimeout."""
    from tmscal.drivers.denso.halt import HaltLink

    m = DensoMock(rig, clock=FAST, faults=DensoFaults(stuck_functions=("Controller_GetRobot",)))
    link = HaltLink("127.0.0.1", port_of(m.start()), "CaoProv.DENSO.VRC", "localhost", "Arm",
                    timeout_s=0.5)
    try:
        t, errors = _call_in_thread(link.halt)
        t.join(HANG_GUARD_S)
        assert not t.is_alive(), "halt() still waiting for Controller_GetRobot"
        assert len(errors) == 1 and isinstance(errors[0], DeviceTimeout), errors
        assert "Controller_GetRobot" in str(errors[0])
        assert not link.ready
    finally:
        m.close()
        link.close()


def test_keepalives_still_rearm_a_moves_wait(rig: SimRig) -> None:
    """A Robot_Move may outlast the client's timeout as long as keep-alives come (a long
    move): 1.2 s of motion with WDT=50 ms keep-alives under a 0.6 s timeout succeeds."""
    with DensoMock(rig, clock=REAL_TIME, motion_time_s=1.2) as m, \
            BCAPClient("127.0.0.1", port_of(m.start()), timeout_s=0.6) as c:
        r = open_robot(c, ",WDT=50")
        c.take_arm(r)
        c.motor(r, True)
        c.robot_move(r, 2, "@E P(510, 0, 400, 180, 0, 0)", "", timeout_s=0.6)
        assert np.allclose(rig.commanded[:3, 3], [510, 0, 400])
        assert m.stats["keepalives"] >= 1


def test_stuck_functions_fault_refuses_unknown_names() -> None:
    with pytest.raises(ValueError, match="stuck_functions"):
        DensoFaults(stuck_functions=("Robot_Hault",))
    with pytest.raises(ValueError, match="stuck_functions"):
        DensoFaults(stuck_functions="Robot_Halt")  # type: ignore[arg-type]


def test_open_clears_a_latched_error_before_takearm(rig: SimRig) -> None:
    with DensoMock(rig, clock=FAST, faults=DensoFaults(latched_error=0x84204051)) as m, \
            DensoRobot(port=port_of(m.start())) as robot:
        assert m.latched_error is None and m.stats["clear_errors"] == 1
        target = TMS_RIG_P0 @ make_pose(t=[10, 0, 0])
        robot.move_to(target)
        assert np.allclose(rig.flange, target)


def test_open_replaces_a_low_external_speed_left_on_the_controller(rig: SimRig) -> None:
    with DensoMock(rig, clock=FAST, max_linear_speed_mm_s=1000.0) as m:
        m.ext_speed = 10.0  # left by the pendant: every move would take 10 × as long
        with DensoRobot(port=port_of(m.start()), max_linear_speed_mm_s=1000.0) as robot:
            robot.move_to(TMS_RIG_P0 @ make_pose(t=[0, 100, 0]), speed_mm_s=50.0)
            accel = robot.accel_mm_s2
        # 100 mm at 50 mm/s with the driver's acceleration (the trapezoid; ExtSpeed 10 %
        # would make it ten times slower)
        assert m.last_motion_s == pytest.approx(trapezoid_duration(100.0, 50.0, accel))


# --- CurPos integrity (issue 8) and acceleration (issue 2) ------------------------------------

@pytest.mark.parametrize("fault, why", [
    ("nan", "non-finite value nan"), ("inf", "non-finite value inf"),
    ("short", "5 values, expected 6 to 7"), ("long", "9 values, expected 6 to 7"),
    ("bstr", "expected an array of numbers, got BSTR"),
    ("bool_array", "expected an array of numbers, got BOOL|ARRAY"),
    ("empty", "expected an array of numbers, got EMPTY"),
    ("nested_bstr", "element 6 is Variant(BSTR"),
])
def test_bad_curpos_raises_protocol_error_naming_curpos(rig: SimRig, fault: str,
                                                         why: str) -> None:
    with DensoMock(rig, clock=FAST) as m, \
            DensoRobot(port=port_of(m.start()), watchdog_ms=None) as robot:
        m.faults = dataclasses.replace(m.faults, bad_curpos=fault)
        with pytest.raises(ProtocolError) as ei:
            robot.flange_pose()
        assert "CurPos" in str(ei.value) and why in str(ei.value)
        assert ei.value.device == "denso"
        m.faults = dataclasses.replace(m.faults, bad_curpos=None)  # the link is still usable
        # the next read is good
        assert np.allclose(robot.flange_pose(), TMS_RIG_P0, atol=1e-9)


def test_curpos_accepts_a_variant_array_of_numbers() -> None:
    nums = [500.0, 0.0, 400.0, 180.0, 0.0, 0.0]
    port, t, srv = scripted_server(lambda s: encode_packet(s, S_OK, [Variant(
        VT_VARIANT | VT_ARRAY, [Variant(VT_R4, x) for x in nums] + [Variant(VT_I4, -1)])]))
    with srv, BCAPClient("127.0.0.1", port, timeout_s=5.0) as c:
        assert c.cur_pos(1) == [*nums, -1.0]
    t.join(5)


@pytest.mark.parametrize("accel, cap, max_accel, expected", [
    (1234.0, 1500.0, 20000.0, 6.17),    # 6.17 % of 20 m/s² = 1234 mm/s²
    (1200.0, 1500.0, 7000.0, 17.14),    # 17.142… rounded down, never up
    (1200.0, 900.0, 7000.0, 12.85),     # the envelope's cap is smaller: it wins
    (5000.0, 9000.0, 3000.0, 100.0),    # more than the arm can: 100 %
])
def test_denso_robot_sends_accel_never_above_cap(rig: SimRig, accel: float, cap: float,
                                                 max_accel: float, expected: float) -> None:
    env = Envelope(max_accel_mm_s2=cap)
    with DensoMock(rig, clock=FAST) as m, \
            DensoRobot(port=port_of(m.start()), envelope=env, accel_mm_s2=accel,
                       max_linear_accel_mm_s2=max_accel) as robot:
        assert m.ext_speed_log == [(100.0, expected, expected)]
        assert (m.ext_speed, m.ext_accel, m.ext_decel) == (100.0, expected, expected)
        assert m.ext_accel / 100.0 * max_accel <= min(accel, cap) + 1e-9
        target = TMS_RIG_P0 @ make_pose(t=[10, 0, 0])
        if accel > cap:  # the envelope refuses the move itself; the arm was capped anyway
            with pytest.raises(SafetyError):
                robot.move_to(target, speed_mm_s=50.0)
        else:
            robot.move_to(target, speed_mm_s=50.0)
            assert np.allclose(rig.flange, target)


def test_denso_robot_ext_speed_percent_option(rig: SimRig) -> None:
    with DensoMock(rig, clock=FAST) as m, \
            DensoRobot(port=port_of(m.start()), accel_mm_s2=500.0,
                       max_linear_accel_mm_s2=10000.0, ext_speed_percent=25.0):
        assert m.ext_speed_log == [(25.0, 5.0, 5.0)]
