"""End to end: tmscal's URRobot (on the real ur_rtde library) drives the UR mock, which moves
the noise-free sim rig.

ur_rtde's constructors hold the GIL while they wait for the controller, so the robot cannot
share a process with the mock's server threads: this file runs the robot side in a child
process (``tests.child.run_child``) and checks the rig here.
Each test uses its own loopback address.
"""

from __future__ import annotations

from typing import Any

import numpy as np

if __name__ != "__main__":
    import pytest

    pytest.importorskip("rtde_control")
    pytestmark = pytest.mark.e2e

from tests.child import child_main, run_child
from tests.rigs import free_port, unique_host
from tmscal.geometry import compose, make_pose, rot_x, rot_y, rot_z
from tmscal.mocks.clock import FAST
from tmscal.mocks.ur import ROBOT_MODE_POWER_OFF, URFaults, URMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth


def _rig() -> SimRig:
    """A noise-free TMS rig; ``rig.moves`` records what the mock commanded."""
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)


def _targets() -> list[np.ndarray]:
    """Four flange targets around P0: translations of tens of mm and rotations of a few
    degrees about each axis (in the flange frame)."""
    return [
        compose(TMS_RIG_P0, make_pose(rot_z(0.10), [10.0, -5.0, 3.0])),
        compose(TMS_RIG_P0, make_pose(rot_x(-0.15), [-20.0, 12.5, 0.0])),
        compose(TMS_RIG_P0, make_pose(rot_y(0.20) @ rot_z(-0.3), [0.0, 30.0, -15.0])),
        compose(TMS_RIG_P0, make_pose(np.eye(3), [40.0, 0.0, 25.0])),
    ]


def _moves(mock: URMock, targets: list[np.ndarray], upload_script: bool) -> dict[str, Any]:
    """URRobot (in a child process) opens on ``mock`` and moves through ``targets``."""
    return run_child(__file__, "moves", mock.host, {"poses": [t.tolist() for t in targets],
                                                    "upload_script": upload_script})


def test_urrobot_moves_rig_to_commanded_poses() -> None:
    rig = _rig()
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST) as mock:
        res = _moves(mock, targets, upload_script=True)
    assert res["error"] is None, res["error"]
    # the rig received exactly the commanded flange poses (through metres and rotvecs)
    assert len(rig.moves) == len(targets)
    for got, want in zip(rig.moves, targets, strict=True):
        assert np.abs(got[:3, 3] - want[:3, 3]).max() < 1e-6
        assert np.abs(got[:3, :3] - want[:3, :3]).max() < 1e-9
    assert np.abs(rig.flange - targets[-1]).max() < 1e-6
    # what the driver read back is what the controller reported
    assert np.abs(np.array(res["initial"]) - TMS_RIG_P0).max() < 1e-6
    for got, want in zip(res["reported"], targets, strict=True):
        assert np.abs(np.array(got) - want).max() < 1e-6
    # identity from the dashboard server; the default flag uploads the control script
    assert res["identity"]["controller_version"] == "5.11.0.108249"
    assert res["identity"]["serial"] == "20185500001"
    assert res["identity"]["tcp_offset_m_rad"] == [0.0] * 6
    assert mock.scripts_received == 1


def test_protective_stop_raises_robot_fault() -> None:
    rig = _rig()
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(protective_stop_at_move=2)) as mock:
        res = _moves(mock, targets, upload_script=True)
        assert mock.protective_stopped
    err = res["error"]
    assert err is not None and err["type"] == "RobotFault"
    assert "DeviceError" in err["mro"]
    assert err["code"] == 3 and err["text"] == "PROTECTIVE_STOP"
    assert "PROTECTIVE_STOP" in err["message"]
    assert err["at"] == 1                      # the second move failed
    # the flange stopped half-way between the first and the second target
    half = 0.5 * (targets[0][:3, 3] + targets[1][:3, 3])
    assert np.abs(rig.flange[:3, 3] - half).max() < 1e-6
    assert "clear it at the pendant" in err["message"]


def test_dropped_connection_raises_connection_lost() -> None:
    rig = _rig()
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(drop_at_move=2)) as mock:
        res = _moves(mock, targets, upload_script=True)
    err = res["error"]
    assert err is not None and err["type"] == "ConnectionLost"
    assert "ConnectionError" in err["mro"] and "DeviceError" in err["mro"]
    # the link drops as the second move's handshake ends: the driver notices it right after
    # that move, or (if the last packages were already on their way) on the third call
    assert err["at"] in (1, 2)
    assert len(rig.moves) == 2                 # the controller finished that move
    assert np.abs(rig.flange - targets[1]).max() < 1e-6


def test_protective_stop_cleared_script_reuploaded_and_run_continues() -> None:
    """After a protective stop the control script no longer runs; once the operator has
    cleared the stop, the next move re-uploads the script and the run goes on."""
    rig = _rig()
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(protective_stop_at_move=2)) as mock:
        res = run_child(__file__, "moves", mock.host, {
            "poses": [t.tolist() for t in targets], "upload_script": True,
            "operator": ["unlock protective stop"]})
        assert mock.scripts_received == 2           # at connect, and after the stop
    assert res["error"]["type"] == "RobotFault" and res["error"]["at"] == 1
    assert res["retry_error"] is None, res["retry_error"]
    # the failed pose was moved to again, then the rest of the plan
    assert len(res["reported"]) == len(targets)
    for got, want in zip(res["reported"], targets, strict=True):
        assert np.abs(np.array(got) - want).max() < 1e-6
    assert np.abs(rig.flange - targets[-1]).max() < 1e-6


def test_protective_stop_not_cleared_is_robot_fault_on_retry() -> None:
    """Without the operator clearing the stop, the retry is refused naming it; nothing is
    re-uploaded and the flange stays where the stop left it."""
    rig = _rig()
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(protective_stop_at_move=2)) as mock:
        res = run_child(__file__, "moves", mock.host, {
            "poses": [t.tolist() for t in targets], "upload_script": True, "operator": []})
        assert mock.scripts_received == 1
    err = res["retry_error"]
    assert err is not None and err["type"] == "RobotFault" and err["at"] == 1
    assert err["text"] == "PROTECTIVE_STOP" and "clear it" in err["message"]
    half = 0.5 * (targets[0][:3, 3] + targets[1][:3, 3])
    assert np.abs(rig.flange[:3, 3] - half).max() < 1e-6


def test_urcap_path_serves_script_to_external_control() -> None:
    """upload_script false is the External Control URCap (FLAG_USE_EXT_UR_CAP): the pendant
    is in Local Control, nothing goes to the script port; the URCap fetches the script from
    ur_rtde when the operator presses Play, and the moves run."""
    rig = _rig()
    targets = _targets()[:2]
    port = free_port()  # for ur_rtde's URCap script sender
    with URMock(rig, host=unique_host(), clock=FAST, remote_control=False, urcap_port=port,
                play_when_ready=True) as mock:
        assert mock.runtime_state != 2              # nothing runs before Play
        res = run_child(__file__, "moves", mock.host, {
            "poses": [t.tolist() for t in targets], "upload_script": False,
            "ur_cap_port": port})
        assert mock.scripts_received == 0
        assert mock.urcap is not None and mock.urcap.requests == 1
        assert (mock.last_urcap_script or "").startswith("# HEADER_BEGIN")   # the URCap's anchor
    assert res["error"] is None, res["error"]
    assert len(rig.moves) == len(targets)
    assert np.abs(rig.flange - targets[-1]).max() < 1e-6


def _open_error(mock: URMock, **args: Any) -> dict[str, Any]:
    res = run_child(__file__, "open", mock.host, args)
    assert res["error"] is not None, "open succeeded"
    return res["error"]


def test_remote_control_off_is_robot_fault_at_open() -> None:
    rig = _rig()
    with URMock(rig, host=unique_host(), clock=FAST, remote_control=False) as mock:
        err = _open_error(mock, upload_script=True)
        assert mock.scripts_received == 0
    assert err["type"] == "RobotFault"
    assert "remote control is not enabled" in err["message"]
    assert "Remote Control" in err["message"]       # what to do at the pendant


def test_dashboard_reply_not_utf8_is_protocol_error_naming_the_command() -> None:
    """A dashboard reply that is not UTF-8 (ur_rtde cannot hand it to Python) is a
    ProtocolError naming the command and showing the bytes escaped, not a UnicodeDecodeError;
    nothing is uploaded."""
    rig = _rig()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(non_utf8_dashboard_reply="get serial number")) as mock:
        err = _open_error(mock, upload_script=True)
        assert mock.scripts_received == 0
    assert err["type"] == "ProtocolError" and "DeviceError" in err["mro"], err
    assert "'get serial number'" in err["message"] and "not UTF-8" in err["message"]
    assert "\\xff\\xfe" in err["message"] and "\\x80" in err["message"]   # escaped
    assert err["text"] == "get serial number"


_UR_HOLDER = """
import sys, time
from tmscal.drivers.ur.robot import URRobot
robot = URRobot(sys.argv[1], timeout_s=10.0).open()
print("open", flush=True)
time.sleep(600)
"""


def test_second_tmscal_cannot_take_over_a_robot_in_use(mock_config: Any,
                                                       loopback_host: str) -> None:
    """While one tmscal process drives the UR (its control script running), `tmscal robot` on
    the same address is refused, naming the address and that process's pid, before it
    connects: the first run's script is not replaced (nothing more uploaded) and keeps
    running."""
    import os
    import signal
    import subprocess
    import sys

    from tests.child import ROOT

    rig = _rig()
    cfg = mock_config("mock-ur-polaris.yaml", robot={"host": loopback_host})
    with URMock(rig, host=loopback_host, clock=FAST) as mock:
        holder = subprocess.Popen([sys.executable, "-c", _UR_HOLDER, mock.host], cwd=ROOT,
                                  env={**os.environ, "PYTHONPATH": str(ROOT)},
                                  stdout=subprocess.PIPE, text=True)
        try:
            assert holder.stdout is not None and holder.stdout.readline().strip() == "open"
            assert mock.scripts_received == 1 and mock.runtime_state == 2
            out = subprocess.run([sys.executable, "-m", "tmscal.cli", "robot", str(cfg),
                                  "--host", mock.host], capture_output=True, text=True,
                                 timeout=120, cwd=ROOT)
            text = out.stdout + out.stderr
            assert out.returncode == 1, text[-2000:]
            assert "Traceback" not in text
            assert loopback_host in text and f"pid {holder.pid}" in text, text[-2000:]
            assert "in use by another tmscal" in text
            assert mock.scripts_received == 1        # the first run's script stays
            assert mock.runtime_state == 2           # and runs
        finally:
            holder.send_signal(signal.SIGKILL)
            holder.wait(30)
            if holder.stdout is not None:
                holder.stdout.close()


def test_powered_off_robot_is_robot_fault_at_open() -> None:
    rig = _rig()
    with URMock(rig, host=unique_host(), clock=FAST, robot_mode=ROBOT_MODE_POWER_OFF) as mock:
        err = _open_error(mock, upload_script=True)
        # refused from the dashboard's robot mode, before ur_rtde uploads a script (and waits
        # its 5 s for the script to start)
        assert "robotmode" in mock.dashboard_log
        assert mock.scripts_received == 0
    assert err["type"] == "RobotFault" and err["text"] == "POWER_OFF"
    assert "power it on" in err["message"]


def test_power_off_during_move_is_robot_fault_naming_it() -> None:
    rig = _rig()
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST,
                faults=URFaults(power_off_at_move=2)) as mock:
        res = _moves(mock, targets, upload_script=True)
        assert mock.robot_mode == ROBOT_MODE_POWER_OFF
    err = res["error"]
    assert err is not None and err["type"] == "RobotFault" and err["at"] == 1
    assert err["text"] == "POWER_OFF" and "power it on" in err["message"]


# --- child process ------------------------------------------------------------------------------

def _error(e: Exception, at: int) -> dict[str, Any]:
    return {"type": type(e).__name__, "message": str(e), "at": at,
            "mro": [c.__name__ for c in type(e).__mro__],
            "code": getattr(e, "code", None), "text": getattr(e, "text", None)}


def _operator(host: str, commands: list[str]) -> None:
    """The operator at the pendant, through the dashboard server (ur_rtde's client)."""
    import dashboard_client

    db = dashboard_client.DashboardClient(host)
    db.connect()
    for cmd in commands:
        db.send(cmd + "\n")
        db.receive()
    db.disconnect()


def _run_poses(robot: Any, poses: list[Any], start: int, res: dict[str, Any], key: str) -> int:
    """Move through ``poses[start:]``; on an error record it under ``key`` and return its
    index (len(poses) when all moved)."""
    for i in range(start, len(poses)):
        try:
            robot.move_to(np.array(poses[i]))
        except Exception as e:  # reported to the parent, which checks the type
            res[key] = _error(e, i)
            return i
        res["reported"].append(robot.flange_pose().tolist())
    return len(poses)


def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    from tmscal.drivers.ur.robot import URRobot

    res.update({"error": None, "retry_error": None, "reported": []})
    kw = {"ur_cap_port": args["ur_cap_port"]} if "ur_cap_port" in args else {}
    robot = URRobot(host, upload_script=args["upload_script"], speed_mm_s=100.0,
                    timeout_s=10.0, **kw)
    if scenario == "open":
        try:
            robot.open()
        except Exception as e:
            res["error"] = _error(e, 0)
        robot.close()
        return
    assert scenario == "moves"
    with robot:
        res["identity"] = robot.identity()
        res["initial"] = robot.flange_pose().tolist()
        failed = _run_poses(robot, args["poses"], 0, res, "error")
        if failed < len(args["poses"]) and "operator" in args:
            _operator(host, args["operator"])
            _run_poses(robot, args["poses"], failed, res, "retry_error")


if __name__ == "__main__":
    child_main(_child)


def test_idle_mock_sleeps_until_a_client_connects() -> None:
    """An idle UR mock (`tmscal mock` with nobody connected) does not run its control
    script's 4 ms loop (250 wake-ups a second kept 2 % of a core busy): no tick before any
    client, ticks while a dashboard client is connected, and none again once it has left.
    The pauses only give a loop that wrongly ticks the time to show it: a correct one ticks
    no more however long they are."""
    import socket
    import time

    from tests.rigs import wait_until
    from tmscal.mocks.ur import DASHBOARD_PORT

    mock = URMock(_rig(), host=unique_host(), clock=FAST)
    ticks: list[float] = []
    tick = mock._tick

    def counted() -> None:
        ticks.append(time.monotonic())
        tick()

    mock._tick = counted  # type: ignore[method-assign]
    with mock:
        time.sleep(0.3)
        assert ticks == []
        with socket.create_connection((mock.host, DASHBOARD_PORT), timeout=5.0):
            wait_until(lambda: len(ticks) >= 3, 10.0, "the script loop to tick for a client")
        wait_until(lambda: not mock._busy(), 10.0, "the dashboard client to be gone")
        n = len(ticks)
        time.sleep(0.3)
        assert len(ticks) - n <= 1  # at most the tick under way when the client left
