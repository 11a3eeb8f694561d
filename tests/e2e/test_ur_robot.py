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
from tmscal.geometry import compose, make_pose, rot_x, rot_y, rot_z
from tmscal.mocks.clock import FAST
from tmscal.mocks.ur import URFaults, URMock
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
    with URMock(rig, host="127.0.0.21", clock=FAST) as mock:
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
    with URMock(rig, host="127.0.0.22", clock=FAST,
                faults=URFaults(protective_stop_at_move=2)) as mock:
        res = _moves(mock, targets, upload_script=False)
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
    assert mock.scripts_received == 0          # flags=0: nothing uploaded


def test_dropped_connection_raises_connection_lost() -> None:
    rig = _rig()
    targets = _targets()
    with URMock(rig, host="127.0.0.23", clock=FAST,
                faults=URFaults(drop_at_move=2)) as mock:
        res = _moves(mock, targets, upload_script=False)
    err = res["error"]
    assert err is not None and err["type"] == "ConnectionLost"
    assert "ConnectionError" in err["mro"] and "DeviceError" in err["mro"]
    # the link drops as the second move's handshake ends: the driver notices it right after
    # that move, or (if the last packages were already on their way) on the third call
    assert err["at"] in (1, 2)
    assert len(rig.moves) == 2                 # the controller finished that move
    assert np.abs(rig.flange - targets[1]).max() < 1e-6


# --- child process ------------------------------------------------------------------------------

def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    from tmscal.drivers.ur.robot import URRobot

    res.update({"error": None, "reported": []})
    assert scenario == "moves"
    robot = URRobot(host, upload_script=args["upload_script"], speed_mm_s=100.0,
                    timeout_s=10.0)
    with robot:
        res["identity"] = robot.identity()
        res["initial"] = robot.flange_pose().tolist()
        for i, pose in enumerate(args["poses"]):
            try:
                robot.move_to(np.array(pose))
            except Exception as e:  # reported to the parent, which checks the type
                res["error"] = {"type": type(e).__name__, "message": str(e), "at": i,
                                "mro": [c.__name__ for c in type(e).__mro__],
                                "code": getattr(e, "code", None),
                                "text": getattr(e, "text", None)}
                break
            res["reported"].append(robot.flange_pose().tolist())


if __name__ == "__main__":
    child_main(_child)
