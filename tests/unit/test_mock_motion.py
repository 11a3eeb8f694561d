"""The UR mock's motion model: a trapezoidal velocity profile (tmscal.motion) at movel's speed
and acceleration caps (four times the same numbers as rad/s and rad/s² for the rotation), the
modelled
duration recorded on both clocks, and the flange (what the tracker sees) on the profile
mid-move, checked against the closed-form kinematics on an injected clock."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from tests.rigs import quiet_tms_rig
from tmscal.geometry import invert, make_pose, rot_x, rot_z, rotvec_pose_from_matrix
from tmscal.mocks.clock import FAST, Clock
from tmscal.mocks.ur import CMD_MOVEL
from tmscal.mocks.ur.controller import URController
from tmscal.mocks.ur.motion import Motion
from tmscal.motion import move_duration
from tmscal.sim import TMS_RIG_P0
from tmscal.sim.rig import straight_path


@dataclass(frozen=True)
class FakeClock(Clock):
    """A real-time clock whose time the test sets (``t[0]``, s)."""

    t: list[float] = field(default_factory=lambda: [0.0])

    def now(self) -> float:
        return self.t[0]


def _command(ctl: URController, target: np.ndarray, v: float, a: float) -> None:
    """moveL to ``target`` (base_from_flange mm) at v m/s, a m/s², synchronous, as ur_rtde
    writes it into the input registers, then one cycle of the control script."""
    ctl.in_double[0:8] = [*rotvec_pose_from_matrix(target), v, a]
    ctl.in_int[1] = 0
    ctl.in_int[0] = CMD_MOVEL
    ctl._tick()


def _clear(ctl: URController) -> None:
    ctl.in_int[0] = 0
    ctl._tick()


def _seen_flange(rig) -> np.ndarray:
    """The flange as the tracker sees it: Z · tracker_from_marker · X⁻¹ (noise-free rig)."""
    return rig.truth.Z @ rig.true_body("marker") @ invert(rig.truth.X)


def test_long_translation_takes_the_closed_form_trapezoid_time() -> None:
    # 300 mm at 0.25 m/s, 1.2 m/s²: ramps of v/a, cruise; T = d/v + v/a
    rig = quiet_tms_rig()
    ctl = URController(rig, clock=FAST)
    target = TMS_RIG_P0 @ make_pose(np.eye(3), [300.0, 0.0, 0.0])
    _command(ctl, target, 0.25, 1.2)
    assert ctl.last_motion_s == pytest.approx(0.300 / 0.25 + 0.25 / 1.2, rel=1e-12)
    np.testing.assert_allclose(rig.flange, target, atol=1e-9)   # fast clock: there at once


def test_short_move_is_triangular() -> None:
    # 2 mm at 0.25 m/s, 1.2 m/s²: never reaches the speed cap; T = 2·√(d/a)
    ctl = URController(quiet_tms_rig(), clock=FAST)
    _command(ctl, TMS_RIG_P0 @ make_pose(np.eye(3), [0.0, 2.0, 0.0]), 0.25, 1.2)
    assert ctl.last_motion_s == pytest.approx(2 * math.sqrt(0.002 / 1.2), rel=1e-12)


@pytest.mark.parametrize("target", [
    make_pose(rot_z(1.4), [5.0, 0.0, 0.0]),          # rotation sets the time
    make_pose(rot_x(-0.1), [-60.0, 20.0, 10.0]),     # translation sets the time
    make_pose(rot_z(1.2) @ rot_x(0.3), [0.0, 0.0, 0.0]),
])
def test_durations_follow_the_one_motion_model_for_several_moves(target) -> None:
    rig = quiet_tms_rig()
    ctl = URController(rig, clock=FAST)
    v, a = 0.1, 0.5
    start = rig.reported_flange()
    goal = TMS_RIG_P0 @ target
    _command(ctl, goal, v, a)
    want = move_duration(start, goal, 1000 * v, 1000 * a, math.degrees(4 * v),
                         math.degrees(4 * a))
    assert ctl.last_motion_s == pytest.approx(want, rel=1e-12)
    assert list(ctl.motion_log) == [ctl.last_motion_s]


def test_flange_follows_the_profile_mid_move_then_rests_on_the_target() -> None:
    clock = FakeClock()
    rig = quiet_tms_rig()
    ctl = URController(rig, clock=clock)
    d, v, a = 200.0, 0.25, 1.0                      # mm, m/s, m/s²: ramps of 0.25 s
    start = rig.reported_flange()
    target = TMS_RIG_P0 @ make_pose(np.eye(3), [0.0, d, 0.0])
    _command(ctl, target, v, a)
    T = d / 1000 / v + v / a
    # closed form: ½·a·t² while accelerating, v·(t − v/2a) cruising, symmetric at the end
    for t, s_mm in ((0.1, 0.5 * 1000 * a * 0.1 ** 2), (0.5, 1000 * v * (0.5 - v / (2 * a))),
                    (T - 0.1, d - 0.5 * 1000 * a * 0.1 ** 2)):
        clock.t[0] = t
        ctl._tick()
        want = straight_path(start, target, s_mm / d)
        np.testing.assert_allclose(_seen_flange(rig), want, atol=1e-9)   # the tracker's view
        np.testing.assert_allclose(ctl.tcp_pose()[:3], want[:3, 3] / 1000, atol=1e-12)
        assert ctl.out_int[0] != 2                  # not done yet
    clock.t[0] = 0.5
    speed = np.linalg.norm(ctl._tcp_speed(0.5)[:3])
    assert speed == pytest.approx(v, rel=1e-6)      # cruising at the cap
    clock.t[0] = T + 1e-6
    ctl._tick()
    assert ctl.out_int[0] == 2                       # done when the profile ends
    np.testing.assert_allclose(rig.flange, target, atol=1e-9)
    np.testing.assert_allclose(_seen_flange(rig), target, atol=1e-9)
    _clear(ctl)


def test_a_pause_stops_the_flange_on_its_path() -> None:
    clock = FakeClock()
    rig = quiet_tms_rig()
    ctl = URController(rig, clock=clock)
    start = rig.reported_flange()
    target = TMS_RIG_P0 @ make_pose(np.eye(3), [100.0, 0.0, 0.0])
    _command(ctl, target, 0.1, 0.5)
    clock.t[0] = 0.1                                  # ½·a·t² = 2.5 mm along
    with ctl._lock:
        ctl._pause()
    clock.t[0] = 5.0                                  # nothing moves while paused
    np.testing.assert_allclose(_seen_flange(rig), straight_path(start, target, 2.5 / 100),
                               atol=1e-9)


def test_motion_profile_rotation_caps_are_four_times_the_tool_caps() -> None:
    # a pure rotation of 2 rad at 0.2 m/s, 1 m/s² → 0.8 rad/s, 4 rad/s²: T = θ/ω + ω/α
    m = Motion(TMS_RIG_P0, TMS_RIG_P0 @ make_pose(rot_z(2.0)), 0.0, False, 0.2, 1.0)
    assert m.modelled_s == pytest.approx(2.0 / 0.8 + 0.8 / 4.0, rel=1e-12)
    w = np.linalg.norm(m.velocity(1.0)[3:])
    assert w == pytest.approx(0.8, rel=1e-6)
    assert Motion(TMS_RIG_P0, TMS_RIG_P0, 0.0, False, 0.2, 1.0).fraction(0.0) == 1.0
    assert Motion(TMS_RIG_P0, TMS_RIG_P0 @ make_pose(rot_z(0.5)), 0.0, False, 0.2, 1.0,
                  instant=True).duration == 0.0


@pytest.mark.parametrize("v, a", [(1e307, 1.0), (0.1, 1e308)])
def test_caps_the_profile_cannot_use_are_a_runtime_error_and_nothing_moves(v, a) -> None:
    rig = quiet_tms_rig()
    ctl = URController(rig, clock=FAST)
    _command(ctl, TMS_RIG_P0 @ make_pose(np.eye(3), [300.0, 0.0, 0.0]), v, a)
    assert ctl.runtime_state == 1                        # the program stopped
    np.testing.assert_array_equal(rig.flange, TMS_RIG_P0)
    assert ctl.last_motion_s is None
