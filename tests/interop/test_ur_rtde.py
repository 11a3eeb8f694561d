"""Interop: the unmodified ur_rtde library (RTDEControlInterface, RTDEReceiveInterface,
DashboardClient) against tmscal's UR mock.

ur_rtde's constructors hold the GIL while they wait for the controller, so the library cannot
share a process with the mock's server threads: each scenario runs ur_rtde in a child process
(``tests.child.run_child``) and the checks against the sim rig run here. Each test uses its
own loopback address. Robustness of the mock's parsers against arbitrary bytes is checked with
plain sockets (hypothesis).
"""

from __future__ import annotations

import socket
import struct
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

if __name__ != "__main__":
    pytest.importorskip("rtde_control")
    pytestmark = pytest.mark.interop

from tests.child import child_main, run_child
from tests.rigs import unique_host
from tmscal.geometry import compose, make_pose, pose_from_rotvec, rot_z, rotvec_pose_from_matrix
from tmscal.mocks.clock import FAST, REAL_TIME
from tmscal.mocks.ur import ROBOT_MODE_POWER_OFF, URFaults, URMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth
from tmscal.timing import Deadline


def _rig() -> SimRig:
    """A noise-free TMS rig; ``rig.moves`` records what the mock commanded."""
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)


# Two targets near P0 as UR pose vectors (metres, rotation vector), built by hand from
# P0 = [0.5, 0, 0.4 m, rotation π about x]: 5 mm along x; then 20 mm along y with 0.1 rad
# about the flange z axis.
_T1 = make_pose(TMS_RIG_P0[:3, :3], TMS_RIG_P0[:3, 3] + [5.0, 0.0, 0.0])
_T2 = compose(TMS_RIG_P0, make_pose(rot_z(0.1), [0.0, -20.0, 0.0]))


def _same_pose(ur_vector: list[float], pose_mm: np.ndarray, tol_mm: float = 1e-6) -> bool:
    """A UR pose vector and a 4×4 mm pose describe the same pose (compared as matrices, so
    that rotation vectors near π with either sign compare equal)."""
    P = pose_from_rotvec(ur_vector)
    return bool(np.abs(P[:3, 3] - pose_mm[:3, 3]).max() < tol_mm
                and np.abs(P[:3, :3] - pose_mm[:3, :3]).max() < 1e-9)


def test_default_flags_upload_script_and_move_sync_and_async() -> None:
    """Default flags (script upload), default receive recipe, real-time clock: moveL sync
    and async move the rig; getActualTCPPose reports the rig's pose."""
    rig = _rig()
    t1, t2 = rotvec_pose_from_matrix(_T1).tolist(), rotvec_pose_from_matrix(_T2).tolist()
    with URMock(rig, host=unique_host(), clock=REAL_TIME) as mock:
        res = run_child(__file__, "moves", mock.host,
                        {"flags": None, "t1": t1, "t2": t2, "speed": 0.05, "async_speed": 0.04})
        assert mock.scripts_received == 1
        assert mock.last_script is not None and mock.last_script.startswith("def rtde_control")
        # ur_rtde asked these on the dashboard (version ≥ 5.6, host not 127.0.0.1)
        for q in ("PolyscopeVersion", "get serial number", "is in remote control", "stop"):
            assert q in mock.dashboard_log
        final = rig.reported_flange()
    # start: P0 = [0.5, 0, 0.4] m and a half turn about x (hand-computed)
    p0 = res["initial_pose"]
    assert np.allclose(p0[:3], [0.5, 0.0, 0.4], atol=1e-12)
    assert np.isclose(abs(p0[3]), np.pi, atol=1e-12) and np.allclose(p0[4:], 0.0, atol=1e-12)
    assert res["sync_ok"] is True and res["async_ok"] is True
    assert len(rig.moves) == 2
    assert _same_pose(t1, rig.moves[0]) and _same_pose(t2, rig.moves[1])
    assert _same_pose(res["pose_after_sync"], rig.moves[0])
    assert _same_pose(res["pose_after_async"], final)
    # async: running (bit 15) right after the call, a new operation id, then finished
    assert res["async_running_at_start"] is True
    assert res["async_finished"] is True
    assert res["async_op_id_end"] == res["async_op_id_start"] != 0
    # the default receive recipe decodes with the right types and order
    v = res["values"]
    assert v["robot_mode"] == 7 and v["safety_mode"] == 1 and v["runtime_state"] == 2
    assert v["safety_status_bits"] == 1 and v["robot_status"] == 3
    assert v["joint_mode"] == [253] * 6 and v["joint_temperatures"] == [30.0] * 6
    assert v["main_voltage"] == 48.0 and v["speed_scaling"] == 1.0
    assert v["accelerometer"] == [0.0, 0.0, 9.81]
    assert len(v["actual_q"]) == 6 and v["timestamp"] > 0
    assert res["tcp_offset"] == [0.0] * 6


def test_flags_zero_without_upload() -> None:
    """flags=0: no script upload; the running control program executes the moves."""
    rig = _rig()
    t1, t2 = rotvec_pose_from_matrix(_T1).tolist(), rotvec_pose_from_matrix(_T2).tolist()
    with URMock(rig, host=unique_host(), clock=FAST) as mock:
        res = run_child(__file__, "moves", mock.host,
                        {"flags": 0, "t1": t1, "t2": t2, "speed": 0.25, "async_speed": 0.25,
                         "variables": ["timestamp", "actual_TCP_pose"]})
        assert mock.scripts_received == 0
        assert "stop" not in mock.dashboard_log
        final = rig.reported_flange()
    assert res["sync_ok"] is True and res["async_ok"] is True and res["async_finished"]
    assert len(rig.moves) == 2
    assert _same_pose(t2, rig.moves[1])
    assert _same_pose(res["pose_after_sync"], rig.moves[0])
    assert _same_pose(res["pose_after_async"], final)


def test_protective_stop_fails_move_and_unlock_clears_it() -> None:
    rig = _rig()
    t1, t2 = rotvec_pose_from_matrix(_T1).tolist(), rotvec_pose_from_matrix(_T2).tolist()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(protective_stop_at_move=2)) as mock:
        res = run_child(__file__, "protective", mock.host, {"t1": t1, "t2": t2})
        assert "unlock protective stop" in mock.dashboard_log
        assert not mock.protective_stopped
    assert res["first_ok"] is True
    assert res["second_ok"] is False
    assert res["protective_stopped"] is True
    assert res["safety_mode"] == 3
    assert res["safety_status_bits"] & (1 << 2)
    assert res["runtime_state"] == 1            # the control script stopped
    assert res["unlock_error"] is None          # reply was "Protective stop releasing"
    assert res["protective_after_unlock"] is False
    # cleared, the script stays stopped until it is uploaded again (ur_rtde's reuploadScript)
    assert res["running_after_unlock"] is False
    assert res["running_after_reupload"] is True and res["third_ok"] is True
    assert mock.scripts_received == 1
    # the flange stopped half-way to the second target, then went back to the first
    half = 0.5 * (_T1[:3, 3] + _T2[:3, 3])
    assert np.abs(rig.moves[1][:3, 3] - half).max() < 1e-6
    assert np.abs(rig.flange - _T1).max() < 1e-6


# --- parsers against arbitrary bytes -----------------------------------------------------------

@pytest.fixture(scope="module")
def bare_mock():
    with URMock(_rig(), host=unique_host(), clock=FAST) as mock:
        yield mock


def _exchange(host: str, port: int, data: bytes) -> None:
    with socket.create_connection((host, port), timeout=2.0) as s:
        s.sendall(data)
        s.settimeout(0.02)
        try:
            while s.recv(65536):
                pass
        except (TimeoutError, ConnectionError):
            pass


def _still_serves(host: str) -> None:
    """A fresh RTDE client still gets the protocol and version replies."""
    with socket.create_connection((host, 30004), timeout=2.0) as s:
        s.sendall(struct.pack(">HBH", 5, ord("V"), 2))
        assert s.recv(4) == struct.pack(">HBB", 4, ord("V"), 1)
        s.sendall(struct.pack(">HB", 3, ord("v")))
        reply = b""
        while len(reply) < 19:
            reply += s.recv(19 - len(reply))
        assert struct.unpack(">HBIIII", reply) == (19, ord("v"), 5, 11, 0, 108249)


def test_local_control_and_power_off_as_a_controller_answers() -> None:
    """Remote control off: ur_rtde's constructor refuses (its own check); powered off: the
    dashboard says so and an uploaded script does not start (the library times out)."""
    with URMock(_rig(), host=unique_host(), clock=FAST, remote_control=False) as mock:
        res = run_child(__file__, "states", mock.host, {})
    assert "remote control" in res["ctor_error"].lower()
    assert res["remote"] is False
    assert res["play"].startswith("Command is not allowed due to safety reasons")
    with URMock(_rig(), host=unique_host(), clock=FAST,
                robot_mode=ROBOT_MODE_POWER_OFF) as mock:
        res = run_child(__file__, "states", mock.host, {})
        assert mock.runtime_state == 1 and mock.scripts_received == 1
    assert res["robotmode"] == "Robotmode: POWER_OFF" and res["remote"] is True
    assert "control script" in res["ctor_error"]


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.one_of(
    st.binary(max_size=300),
    st.builds(lambda t, body: struct.pack(">HB", 3 + len(body), t) + body,
              st.sampled_from(b"VvOISPUM?"), st.binary(max_size=120))))
def test_rtde_port_survives_arbitrary_bytes(bare_mock: URMock, data: bytes) -> None:
    _exchange(bare_mock.host, 30004, data)
    _still_serves(bare_mock.host)


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lines=st.lists(st.text(alphabet=st.characters(blacklist_characters="\n\r\x00"),
                              max_size=40), min_size=1, max_size=4))
@example(lines=["\ud800"])  # a lone surrogate: bytes that are not UTF-8
def test_dashboard_answers_every_line(bare_mock: URMock, lines: list[str]) -> None:
    sent = [ln for ln in lines if ln.strip()]
    with socket.create_connection((bare_mock.host, 29999), timeout=2.0) as s:
        f = s.makefile("rb")
        assert f.readline().startswith(b"Connected: Universal Robots Dashboard Server")
        for ln in sent:
            s.sendall(ln.encode("utf-8", "surrogatepass") + b"\n")  # lone surrogates: bad UTF-8
            reply = f.readline()
            assert reply.endswith(b"\n")
            if ln.strip().lower() in ("quit", "shutdown"):
                return
    _still_serves(bare_mock.host)


# --- child process ------------------------------------------------------------------------------

def _wait_while(pred: Any, timeout_s: float, period_s: float) -> None:
    """Poll ``pred()`` every ``period_s`` while it is true, for at most ``timeout_s``."""
    deadline = Deadline(timeout_s)
    while pred() and not deadline.expired():
        time.sleep(period_s)


def _wait_fresh(r: Any) -> None:
    """Wait for two new data packages (bounded), so the next read postdates the last event."""
    last, seen = r.getTimestamp(), 0
    deadline = Deadline(5.0)
    while seen < 2 and not deadline.expired():
        t = r.getTimestamp()
        if t != last:
            seen, last = seen + 1, t
        time.sleep(0.0005)


def _receive_values(r: Any) -> dict[str, Any]:
    """The default receive recipe's values, through ur_rtde's getters."""
    return {
        "robot_mode": r.getRobotMode(), "safety_mode": r.getSafetyMode(),
        "runtime_state": r.getRuntimeState(), "safety_status_bits": r.getSafetyStatusBits(),
        "robot_status": r.getRobotStatus(), "joint_mode": list(r.getJointMode()),
        "joint_temperatures": list(r.getJointTemperatures()),
        "main_voltage": r.getActualMainVoltage(), "speed_scaling": r.getSpeedScaling(),
        "accelerometer": list(r.getActualToolAccelerometer()),
        "actual_q": list(r.getActualQ()), "timestamp": r.getTimestamp()}


def _moves(host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    """A synchronous and an asynchronous moveL, with the poses and progress seen."""
    import rtde_control
    import rtde_receive

    variables = args.get("variables") or []
    r = rtde_receive.RTDEReceiveInterface(host, -1.0, variables)
    if args["flags"] is None:
        c = rtde_control.RTDEControlInterface(host)
    else:
        c = rtde_control.RTDEControlInterface(host, -1.0, args["flags"])
    res["initial_pose"] = list(r.getActualTCPPose())
    if not variables:
        res["values"] = _receive_values(r)
        res["tcp_offset"] = list(c.getTCPOffset())
    res["sync_ok"] = c.moveL(args["t1"], args["speed"], 1.2)
    _wait_fresh(r)
    res["pose_after_sync"] = list(r.getActualTCPPose())
    res["async_ok"] = c.moveL(args["t2"], args["async_speed"], 1.2, True)
    st0 = c.getAsyncOperationProgressEx()
    res["async_running_at_start"] = st0.isAsyncOperationRunning()
    res["async_op_id_start"] = st0.operationId()
    _wait_while(lambda: c.getAsyncOperationProgressEx().isAsyncOperationRunning(), 10.0, 0.01)
    st1 = c.getAsyncOperationProgressEx()
    res["async_finished"] = not st1.isAsyncOperationRunning()
    res["async_op_id_end"] = st1.operationId()
    _wait_fresh(r)
    res["pose_after_async"] = list(r.getActualTCPPose())
    c.disconnect()
    r.disconnect()


def _protective(host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    """The second moveL meets a protective stop; the dashboard unlocks it."""
    import dashboard_client
    import rtde_control
    import rtde_receive

    r = rtde_receive.RTDEReceiveInterface(host, -1.0, [])
    c = rtde_control.RTDEControlInterface(host, -1.0, 0)
    res["first_ok"] = c.moveL(args["t1"], 0.25, 1.2)
    res["second_ok"] = c.moveL(args["t2"], 0.25, 1.2)
    _wait_while(lambda: not r.isProtectiveStopped(), 5.0, 0.002)
    _wait_fresh(r)
    res["protective_stopped"] = r.isProtectiveStopped()
    res["safety_mode"] = r.getSafetyMode()
    res["safety_status_bits"] = r.getSafetyStatusBits()
    res["runtime_state"] = r.getRuntimeState()
    db = dashboard_client.DashboardClient(host)
    db.connect()
    try:
        db.unlockProtectiveStop()
        res["unlock_error"] = None
    except RuntimeError as e:
        res["unlock_error"] = str(e)
    db.disconnect()
    _wait_while(r.isProtectiveStopped, 5.0, 0.002)
    res["protective_after_unlock"] = r.isProtectiveStopped()
    _wait_fresh(r)
    res["running_after_unlock"] = c.isProgramRunning()
    c.reuploadScript()
    _wait_while(lambda: not c.isProgramRunning(), 5.0, 0.002)
    res["running_after_reupload"] = c.isProgramRunning()
    res["third_ok"] = c.moveL(args["t1"], 0.25, 1.2)
    c.disconnect()
    r.disconnect()


def _states(host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    """The dashboard's answers, then ur_rtde's constructor with the default flags."""
    import dashboard_client
    import rtde_control

    db = dashboard_client.DashboardClient(host)
    db.connect()
    res["robotmode"] = db.robotmode().strip()
    res["remote"] = db.isInRemoteControl()
    db.send("play\n")
    res["play"] = db.receive().strip()
    db.disconnect()
    try:
        rtde_control.RTDEControlInterface(host)
        res["ctor_error"] = None
    except RuntimeError as e:
        res["ctor_error"] = str(e)


def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    {"moves": _moves, "protective": _protective, "states": _states}[scenario](host, args, res)


if __name__ == "__main__":
    child_main(_child)
