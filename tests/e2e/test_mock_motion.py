"""End to end over real sockets and ptys: the robot mocks' trapezoidal motion (UR through the
real ur_rtde library in a child process, DENSO through our b-CAP client), the modelled move
durations they record, the DENSO flange on its path mid-move (the mock's clock injected), and
the settling oscillation as our NDI driver reads it on the fast clock.

No timing assertions: durations are the mocks' recorded modelled durations, compared with the
motion model (tmscal.motion); mid-move checks run on an injected clock."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

if __name__ != "__main__":
    import pytest

    pytestmark = pytest.mark.e2e

from tests.child import child_main, run_child
from tests.rigs import unique_host
from tmscal.geometry import compose, invert, make_pose, rot_x, rot_z, rotation_angle
from tmscal.mocks.clock import FAST, Clock
from tmscal.motion import move_duration, trapezoid_duration
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, straight_path, tms_rig_truth


@dataclass(frozen=True)
class FakeClock(Clock):
    """A real-time clock whose time the test sets (``t[0]``, s)."""

    t: list[float] = field(default_factory=lambda: [0.0])

    def now(self) -> float:
        return self.t[0]


def _rig() -> SimRig:
    return SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)


def _targets() -> list[np.ndarray]:
    return [compose(TMS_RIG_P0, make_pose(rot_z(0.10), [10.0, -5.0, 3.0])),
            compose(TMS_RIG_P0, make_pose(rot_x(-0.15), [-80.0, 12.5, 0.0])),
            compose(TMS_RIG_P0, make_pose(rot_z(1.5), [0.0, 2.0, 0.0])),
            compose(TMS_RIG_P0, make_pose(np.eye(3), [40.0, 150.0, 25.0]))]


def test_ur_mock_move_durations_are_the_trapezoid_at_the_commanded_caps() -> None:
    pytest.importorskip("rtde_control")
    from tmscal.mocks.ur import URMock

    rig = _rig()
    speed, accel = 120.0, 800.0          # mm/s, mm/s² as URRobot is configured
    targets = _targets()
    with URMock(rig, host=unique_host(), clock=FAST) as mock:
        res = run_child(__file__, "ur_moves", mock.host,
                        {"poses": [t.tolist() for t in targets], "speed": speed,
                         "accel": accel})
        durations = list(mock.motion_log)
    assert res["error"] is None, res["error"]
    v, a = speed / 1000.0, accel / 1000.0  # what moveL carries: m/s, m/s²; rotation 4 × that
    starts = [TMS_RIG_P0, *targets[:-1]]
    want = [move_duration(s, t, speed, accel, math.degrees(4 * v), math.degrees(4 * a))
            for s, t in zip(starts, targets, strict=True)]
    assert durations == pytest.approx(want, rel=1e-9)
    # the third move is mostly a rotation: its time comes from the rotation profile
    angle = float(rotation_angle(targets[1][:3, :3].T @ targets[2][:3, :3]))   # rad
    assert durations[2] == pytest.approx(trapezoid_duration(angle, 4 * v, 4 * a), rel=1e-9)


def _bcap(mock: Any) -> tuple[Any, int]:
    from tmscal.drivers.denso.client import BCAPClient

    c = BCAPClient("127.0.0.1", int(mock.start().rsplit(":", 1)[1]), timeout_s=10.0)
    c.connect()
    c.service_start("")
    h = c.controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
    r = c.controller_get_robot(h, "Arm", "")
    c.take_arm(r)
    c.motor(r, True)
    return c, r


def _denso_p(T: np.ndarray) -> str:
    from tmscal.geometry import denso_p_from_matrix

    return "@E P(" + ", ".join(f"{x:.6f}" for x in denso_p_from_matrix(T)) + ")"


def test_denso_mock_durations_use_speed_accel_decel_and_extspeed() -> None:
    from tmscal.mocks.denso import DensoMock

    rig = _rig()
    vmax, amax = 1000.0, 5000.0          # the mock's 100 % values (mm/s, mm/s²)
    with DensoMock(rig, clock=FAST, max_linear_speed_mm_s=vmax,
                   max_linear_accel_mm_s2=amax) as m:
        c, r = _bcap(m)
        try:
            c.robot_execute(r, "ExtSpeed", [50.0, 40.0, 20.0])
            cases = [("SPEED=25", 25, 100, 100), ("SPEED=10,ACCEL=50,DECEL=25", 10, 50, 25),
                     ("SPEED=80,ACCEL=5", 80, 5, 100)]
            prev = TMS_RIG_P0
            for (opt, sp, ac, de), target in zip(cases, _targets()[1:], strict=True):
                c.robot_move(r, 2, _denso_p(target), opt)
                d = float(np.linalg.norm(target[:3, 3] - prev[:3, 3]))
                acc = amax * ac / 100 * 40 / 100
                dec = amax * de / 100 * 20 / 100
                # the asymmetric profile's duration = the symmetric one at the harmonic mean
                want = trapezoid_duration(d, vmax * sp / 100 * 50 / 100,
                                          2 / (1 / acc + 1 / dec))
                assert m.last_motion_s == pytest.approx(want, rel=1e-6), opt
                prev = target
        finally:
            c.close()


def test_denso_flange_is_on_its_path_mid_move_and_at_rest_after() -> None:
    from tests.rigs import wait_until
    from tmscal.mocks.denso import DensoMock

    clock = FakeClock()
    rig = _rig()
    target = TMS_RIG_P0 @ make_pose(np.eye(3), [0.0, 200.0, 0.0])
    with DensoMock(rig, clock=clock, max_linear_speed_mm_s=1000.0,
                   max_linear_accel_mm_s2=1000.0) as m:
        c, r = _bcap(m)
        try:
            c.robot_move(r, 2, _denso_p(target), "SPEED=25, NEXT")   # 250 mm/s, 1 m/s²
            T = m.last_motion_s
            assert T == pytest.approx(0.2 / 0.25 + 0.25 / 1.0)

            def seen() -> np.ndarray:
                return rig.truth.Z @ rig.true_body("marker") @ invert(rig.truth.X)

            for t, s_mm in ((0.1, 0.5 * 1000 * 0.1 ** 2), (T / 2, 100.0)):
                clock.t[0] = t
                np.testing.assert_allclose(seen(), straight_path(TMS_RIG_P0, target,
                                                                 s_mm / 200.0), atol=1e-6)
            clock.t[0] = T + 0.01
            wait_until(lambda: np.allclose(rig.flange, target), 10.0, "the arm at rest")
            np.testing.assert_allclose(seen(), target, atol=1e-6)
        finally:
            c.close()


def test_settling_seen_by_the_ndi_driver_decays_with_frames_not_with_sleep(mock_config) -> None:
    from tests.rigs import NOISE_FREE_MOCK, point_config
    from tmscal.acquisition.devices import make_robot, make_tracker
    from tmscal.config import load_config
    from tmscal.mocks.launch import start_mock_rig

    amp, tau, f = 0.3, 0.25, 4.0
    base = mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                       mock={"noise": NOISE_FREE_MOCK,
                             "settle": {"amplitude_mm": amp, "tau_s": tau, "freq_hz": f}})
    with start_mock_rig(load_config(base), tracker_transport="pty") as mr:
        cfg = load_config(point_config(base, mr.endpoints))
        host, _, port = mr.endpoints["robot"].partition(":")
        with make_tracker(cfg) as tracker, make_robot(cfg, host=host, port=int(port)) as robot:
            target = TMS_RIG_P0 @ make_pose(np.eye(3), [20.0, 0.0, 0.0])
            robot.move_to(target)
            rest = (invert(mr.rig.truth.Z) @ target @ mr.rig.truth.X)[:3, 3]
            time.sleep(0.5)                     # wall time: no fast-clock time passes
            dev = [float(np.linalg.norm(tracker.read().pose("marker")[:3, 3] - rest))
                   for _ in range(90)]
    # fast clock: the k-th frame read after the move is at least k/60 s into the oscillation,
    # sleep or not (k is exact unless the driver read frames of its own; the bound holds then)
    k = np.arange(len(dev)) + 1
    envelope = amp * np.exp(-k / 60.0 / tau)
    assert max(dev[:3]) > 0.1                   # still swinging after the 0.5 s sleep
    assert all(dv <= e + 0.01 for dv, e in zip(dev, envelope, strict=True))  # BX: 0.01 mm
    assert max(dev[-10:]) < 0.01                # 1.5 s = 6 τ later: still


def _child(scenario: str, host: str, args: dict[str, Any], res: dict[str, Any]) -> None:
    from tmscal.drivers.ur.robot import URRobot

    res["error"] = None
    assert scenario == "ur_moves"
    robot = URRobot(host, speed_mm_s=args["speed"], accel_mm_s2=args["accel"], timeout_s=10.0)
    with robot:
        for p in args["poses"]:
            try:
                robot.move_to(np.array(p))
            except Exception as e:  # reported to the parent
                res["error"] = f"{type(e).__name__}: {e}"
                return


if __name__ == "__main__":
    child_main(_child)
