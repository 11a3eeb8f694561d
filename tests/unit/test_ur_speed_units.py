"""The UR driver's units at the wire: what the UR mock's control script reads from the RTDE
input registers when URRobot.move_to runs (speed mm/s → m/s, acceleration mm/s² → m/s²,
position mm → m), so that a unit slip fails a fast test, not only a motion test.

ur_rtde's constructors hold the GIL while they wait for the controller, so the robot runs in a
child process (``tests.child.run_child``); the mock and the checks run here, on the fast clock.
"""

from __future__ import annotations

from typing import Any

import numpy as np

if __name__ != "__main__":
    import pytest

    pytest.importorskip("rtde_control")

from tests.child import child_main, run_child
from tests.rigs import unique_host
from tmscal.geometry import make_pose, rot_z
from tmscal.mocks.clock import FAST
from tmscal.mocks.ur import URMock
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth


def test_move_to_hands_ur_rtde_metres_per_second() -> None:
    """speed_mm_s 123 (default) and 87.5 (per move), accel_mm_s2 456 reach the controller as
    0.123 and 0.0875 m/s, 0.456 m/s²; the target's position as metres."""
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    t1 = TMS_RIG_P0 @ make_pose(rot_z(0.05), [12.0, -7.0, 4.0])
    t2 = TMS_RIG_P0 @ make_pose(np.eye(3), [-30.0, 5.0, 20.0])
    with URMock(rig, host=unique_host(), clock=FAST) as mock:
        res = run_child(__file__, "moves", mock.host, {
            "speed_mm_s": 123.0, "accel_mm_s2": 456.0,
            "moves": [[t1.tolist(), None], [t2.tolist(), 87.5]]})
        got = list(mock.received_moves)
    assert res["error"] is None, res["error"]
    assert [m["command"] for m in got] == ["moveL", "moveL"]
    assert np.isclose(got[0]["speed"], 0.123, rtol=1e-12, atol=0)
    assert np.isclose(got[1]["speed"], 0.0875, rtol=1e-12, atol=0)
    assert all(np.isclose(m["accel"], 0.456, rtol=1e-12, atol=0) for m in got)
    for m, t in zip(got, (t1, t2), strict=True):   # TCP = flange on the mock
        assert np.allclose(m["target"][:3], t[:3, 3] / 1000.0, rtol=0, atol=1e-12)


# --- child process ------------------------------------------------------------------------------

def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    from tmscal.drivers.ur.robot import URRobot

    assert scenario == "moves"
    res["error"] = None
    robot = URRobot(host, speed_mm_s=args["speed_mm_s"], accel_mm_s2=args["accel_mm_s2"],
                    timeout_s=10.0)
    try:
        with robot:
            for pose, speed in args["moves"]:
                robot.move_to(np.array(pose), speed_mm_s=speed)
    except Exception as e:  # reported to the parent, which checks it
        res["error"] = f"{type(e).__name__}: {e}"


if __name__ == "__main__":
    child_main(_child)
