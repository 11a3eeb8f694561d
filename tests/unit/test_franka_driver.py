"""The Franka driver without a robot: the frames at its edge (flange versus end effector, with
a non-identity end effector), the speed and acceleration caps as franky's relative dynamics,
franky's exceptions as tmscal's errors, and the reflex / user-stop / recovery rules (on a
stand-in for franky's ``Robot`` object: what it reports is set by each test)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tests.rigs import unique_host
from tmscal.drivers.franka.frames import (
    MIN_FACTOR,
    base_from_flange,
    dynamics_factors,
    ee_target,
    matrix_m,
)
from tmscal.drivers.franka.robot import COMMUNICATION_TEXT, FrankaRobot, fault_from_exception
from tmscal.errors import ConnectionLost, DeviceError, RobotFault
from tmscal.geometry import make_pose, random_rotation, rot_z

franky = pytest.importorskip("franky", reason="the franka extra (franky-control) is not "
                             "installed")

DOWN = np.diag([1.0, -1.0, -1.0])  # a flange pointing down, its x along the base x
#: the Franka Hand as franky-sim and Desk set it: F_T_NE = 103.4 mm along z, −45° about z (m)
HAND_M = make_pose(rot_z(np.radians(-45.0)), [0.0, 0.0, 0.1034])


def test_flange_is_103_mm_above_a_hand_that_points_down():
    # worked by hand: the flange at (500, 0, 400) mm pointing down puts the hand's origin
    # 103.4 mm lower, at z = 296.6 mm, rotated −45° about the flange's z (= +45° about base z)
    ee_R = DOWN @ rot_z(np.radians(-45.0))
    O_T_EE = make_pose(ee_R, [0.5, 0.0, 0.2966])
    F = base_from_flange(O_T_EE, HAND_M)
    np.testing.assert_allclose(F[:3, 3], [500.0, 0.0, 400.0], atol=1e-9)
    np.testing.assert_allclose(F[:3, :3], DOWN, atol=1e-12)


def test_a_client_end_effector_adds_to_the_desk_one():
    # NE_T_EE = 50 mm along the hand's x; F_T_EE = F_T_NE · NE_T_EE: the end effector sits
    # 50 mm along the hand's x axis, i.e. along (cos 45°, −sin 45°) of the flange's x/y
    ne_t_ee = make_pose(np.eye(3), [0.05, 0.0, 0.0])
    F_T_EE = HAND_M @ ne_t_ee
    flange = make_pose(np.eye(3), [400.0, 100.0, 500.0])  # flange axes = base axes
    O_T_EE = ee_target(flange, F_T_EE)
    d = 50.0 / math.sqrt(2.0)
    np.testing.assert_allclose(O_T_EE[:3, 3] * 1000.0, [400.0 + d, 100.0 - d, 603.4], atol=1e-9)
    np.testing.assert_allclose(base_from_flange(O_T_EE, F_T_EE), flange, atol=1e-9)


def test_libfranka_column_major_values_are_read_as_such():
    T = make_pose(rot_z(0.3), [0.1, 0.2, 0.3])
    col_major = T.flatten(order="F").tolist()  # libfranka's std::array<double, 16>
    np.testing.assert_array_equal(matrix_m(col_major, "O_T_EE"), T)
    np.testing.assert_array_equal(matrix_m(franky.Affine(T), "O_T_EE"), T)
    with pytest.raises(ValueError, match="O_T_EE"):
        matrix_m(T.flatten(order="C").tolist(), "O_T_EE")  # row-major: not a rigid pose
    with pytest.raises(ValueError, match="F_T_EE: expected a 4×4 pose or 16 values"):
        matrix_m([1.0] * 12, "F_T_EE")


@fuzz_settings(200)
@given(st.integers(0, 2**32 - 1))
def test_commanding_the_end_effector_puts_the_flange_at_the_target(seed):
    rng = np.random.default_rng(seed)
    flange = make_pose(random_rotation(rng), rng.uniform(-800, 800, 3))
    F_T_EE = make_pose(random_rotation(rng), rng.uniform(-0.3, 0.3, 3))
    np.testing.assert_allclose(base_from_flange(ee_target(flange, F_T_EE), F_T_EE), flange,
                               atol=1e-9)


def test_dynamics_factors_worked_example():
    # 250 mm/s against FR3's 1.7 m/s per axis: 0.25 / (√3 · 1.7); 1500 mm/s² against 9 m/s²
    fv, fa, fj = dynamics_factors(250.0, 1500.0, 1.7, 9.0)
    assert fv == pytest.approx(0.25 / (math.sqrt(3) * 1.7), rel=1e-12)
    assert fa == pytest.approx(1.5 / (math.sqrt(3) * 9.0), rel=1e-12) and fj == fa
    assert dynamics_factors(1e9, 1e9, 1.7, 9.0) == (1.0, 1.0, 1.0)  # the robot's own limits


_pos = st.floats(min_value=1e-2, max_value=1e6, allow_nan=False, allow_infinity=False)


@fuzz_settings(300)
@given(_pos, _pos, st.floats(0.05, 5.0), st.floats(0.5, 50.0))
def test_no_direction_exceeds_the_caps(speed, accel, vlim, alim):
    try:
        fv, fa, fj = dynamics_factors(speed, accel, vlim, alim)
    except ValueError as e:
        assert "below" in str(e)
        assert min(speed / 1000 / vlim, accel / 1000 / alim) < MIN_FACTOR * math.sqrt(3) + 1e-12
        return
    assert 0 < fv <= 1 and 0 < fa <= 1 and 0 < fj <= 1
    # franky limits x, y and z separately: the worst direction (a diagonal) is √3 times that
    assert math.sqrt(3) * fv * vlim * 1000 <= speed * (1 + 1e-12)
    assert math.sqrt(3) * fa * alim * 1000 <= accel * (1 + 1e-12)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, True, "1"])
def test_dynamics_factors_refuse_unusable_values(bad):
    for i in range(4):
        args = [250.0, 1500.0, 1.7, 9.0]
        args[i] = bad
        with pytest.raises(ValueError, match="must be a finite number > 0"):
            dynamics_factors(*args)


def test_franky_exceptions_become_typed_errors():
    reflex = franky.ControlException("libfranka: Move command aborted: motion aborted by "
                                     f"reflex! [\"{COMMUNICATION_TEXT}\"]")
    e = fault_from_exception(reflex, "move_to", "172.16.0.2")
    assert type(e) is RobotFault and COMMUNICATION_TEXT in str(e)
    assert "real-time kernel" in str(e) and "172.16.0.2" in str(e)
    e = fault_from_exception(franky.CommandException("command rejected"), "open", "h")
    assert type(e) is RobotFault and "command rejected" in str(e)
    e = fault_from_exception(franky.NetworkException("Connection refused"), "connect", "h")
    assert type(e) is ConnectionLost and "Connection refused" in str(e)
    e = fault_from_exception(franky.IncompatibleVersionException("server version 5"), "c", "h")
    assert type(e) is DeviceError and "libfranka 0.9" in str(e)
    e = fault_from_exception(franky.RealtimeException("no rtprio"), "connect", "h")
    assert type(e) is DeviceError and "realtime" in str(e)


# --- the reflex and recovery rules, on a stand-in for franky's Robot ---------------------------

class FakeFranky:
    """What the driver reads from franky's ``Robot``: ``state`` (mode, errors, poses),
    ``has_errors``; ``recover_from_errors`` counts its calls; ``move`` raises ``raises``."""

    def __init__(self, mode: str = "Idle", errors: str = "[]", raises=None) -> None:
        flange = make_pose(DOWN, [0.5, 0.0, 0.4])
        self.state = SimpleNamespace(robot_mode=SimpleNamespace(name=mode),
                                     current_errors=errors, O_T_EE=flange @ HAND_M,
                                     F_T_EE=HAND_M, q=[0.0] * 7)
        self.has_errors = errors != "[]"
        self.recovered = 0
        self.raises = raises
        self.moved = []
        self.translation_velocity_limit = SimpleNamespace(get=lambda: 1.7)
        self.translation_acceleration_limit = SimpleNamespace(get=lambda: 9.0)
        self.rotation_velocity_limit = SimpleNamespace(get=lambda: 2.5)
        self.rotation_acceleration_limit = SimpleNamespace(get=lambda: 17.0)

    def recover_from_errors(self) -> bool:
        self.recovered += 1
        self.state.robot_mode = SimpleNamespace(name="Idle")
        self.has_errors = False
        return True

    def move(self, motion, asynchronous=False):
        self.moved.append(motion)
        if self.raises is not None:
            raise self.raises

    def join_motion(self, timeout=None):
        return True


def _robot(fake: FakeFranky, **kw) -> FrankaRobot:
    r = FrankaRobot("172.16.0.2", **kw)
    r._robot = fake      # as _open leaves it, without a controller
    r._opened = True
    return r


def test_flange_pose_reads_through_the_end_effector():
    r = _robot(FakeFranky())
    np.testing.assert_allclose(r.flange_pose(), make_pose(DOWN, [500.0, 0.0, 400.0]),
                               atol=1e-9)


def test_reflex_is_a_fault_unless_recovery_is_allowed():
    fake = FakeFranky("Reflex", "[\"cartesian_reflex\"]")
    target = make_pose(DOWN, [510.0, 0.0, 400.0])
    with pytest.raises(RobotFault, match=r"Reflex with errors \[\"cartesian_reflex\"\].*"
                                         r"auto_recover: true"):
        _robot(fake).move_to(target)
    assert fake.recovered == 0 and fake.moved == []
    _robot(fake, auto_recover=True).move_to(target)
    assert fake.recovered == 1 and len(fake.moved) == 1
    expected = ee_target(target, HAND_M)
    np.testing.assert_allclose(fake.moved[0].target.pose.end_effector_pose.matrix, expected,
                               atol=1e-12)


def test_a_turn_sends_factors_that_keep_the_coil_under_the_speed_cap():
    # franky runs each axis at most at factor × its limit: the flange at most at
    # √3·fv·1.7 m/s, the rotation at most at √3·fv·2.5 rad/s; a coil point 300 mm from the
    # end effector then moves at most at √3·fv·(1700 + 2.5·300) mm/s, which must stay at or
    # under the 250 mm/s cap (the flange alone would allow fv = 0.25 / (√3·1.7))
    from tmscal.drivers.base import Envelope

    fake = FakeFranky()
    here = make_pose(DOWN, [500.0, 0.0, 400.0])
    coil = np.array([0.0, 0.0, 300.0])                       # flange frame
    env = Envelope(max_speed_mm_s=250.0, max_accel_mm_s2=1500.0, tool_points_mm=[coil])
    r = _robot(fake, envelope=env, speed_mm_s=250.0, accel_mm_s2=1500.0)
    r.move_to(here @ make_pose(rot_z(0.5), [20.0, 0.0, 0.0]))
    fv = fake.moved[0].relative_dynamics_factor.velocity
    ee = np.linalg.norm(np.linalg.inv(HAND_M) @ [0.0, 0.0, 0.3, 1.0] - [0, 0, 0, 1]) * 1000
    assert ee == pytest.approx(300.0 - 103.4, abs=1e-9)      # the coil from the hand's origin
    flange_from_ee = np.linalg.norm(HAND_M[:3, 3]) * 1000    # the flange origin from it
    fastest = math.sqrt(3) * fv * (1700.0 + 2.5 * max(ee, flange_from_ee))
    assert fastest <= 250.0 * (1 + 1e-9)
    assert fv < 0.25 / (math.sqrt(3) * 1.7)                  # lowered for the coil


def test_user_stop_is_a_fault_even_with_recovery():
    fake = FakeFranky("UserStopped")
    with pytest.raises(RobotFault, match="user stop is pressed: release it"):
        _robot(fake, auto_recover=True).move_to(make_pose(DOWN, [510.0, 0.0, 400.0]))
    assert fake.recovered == 0 and fake.moved == []


@pytest.mark.parametrize("auto_recover", [False, True])
def test_a_reflex_during_a_move_is_a_fault_and_recovered_only_if_allowed(auto_recover):
    fake = FakeFranky(raises=franky.ControlException("motion aborted by reflex! "
                                                     "[\"joint_velocity_violation\"]"))
    with pytest.raises(RobotFault, match="joint_velocity_violation"):
        _robot(fake, auto_recover=auto_recover).move_to(make_pose(DOWN, [510.0, 0.0, 400.0]))
    assert fake.recovered == (1 if auto_recover else 0)


@pytest.mark.parametrize("kw, match", [({"host": ""}, "host"),
                                       ({"auto_recover": "yes"}, "auto_recover"),
                                       ({"timeout_s": 0}, "timeout_s")])
def test_constructor_refuses_bad_options(kw, match):
    args = {"host": "172.16.0.2", **kw}
    with pytest.raises(ValueError, match=match):
        FrankaRobot(**args)


# --- without the extra; the mock's start pose and its refusals (no simulator running) -------

def test_a_franka_config_without_franky_names_the_extra(monkeypatch, tmp_path):
    import importlib.util

    from tests.rigs import write_config
    from tmscal.acquisition.devices import make_robot
    from tmscal.config import load_config
    from tmscal.errors import MissingExtraError

    cfg = load_config(write_config(tmp_path, "mock-franka-polaris.yaml"))
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "franky" else real(name, *a))
    with pytest.raises(MissingExtraError) as ei:
        make_robot(cfg)
    msg = str(ei.value)
    assert "\n" not in msg and "driver 'franka'" in msg and "pip install 'tmscal[franka]'" in msg


def test_mock_start_pose_by_inverse_kinematics_on_the_urdf():
    pin = pytest.importorskip("pinocchio", reason="franky-sim (the test extra) is missing")
    franky_sim = pytest.importorskip("franky_sim", reason="franky-sim is not installed")
    from tmscal.mocks.franka import flange_ik
    from tmscal.sim import TMS_RIG_P0

    q = flange_ik(TMS_RIG_P0, franky_sim.DEFAULT_INITIAL_JOINT_POS)
    model = pin.buildModelFromXML(franky_sim.FR3_URDF)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    T = np.array(data.oMf[model.getFrameId("link8")].homogeneous)
    T[:3, 3] *= 1000.0
    np.testing.assert_allclose(T, TMS_RIG_P0, atol=1e-3)
    with pytest.raises(ValueError, match="cannot reach the start pose"):
        flange_ik(make_pose(DOWN, [500.0, 0.0, 2000.0]), franky_sim.DEFAULT_INITIAL_JOINT_POS)


def test_mock_refuses_the_fast_clock_and_a_public_host():
    pytest.importorskip("franky_sim", reason="franky-sim is not installed")
    from tmscal.errors import ConfigError
    from tmscal.mocks.clock import FAST
    from tmscal.mocks.franka import FrankaMock
    from tmscal.sim import SimRig, tms_rig_truth

    rig = SimRig(tms_rig_truth())
    with pytest.raises(ValueError, match="mock.clock: real"):
        FrankaMock(rig, host=unique_host(), clock=FAST)
    with pytest.raises(ConfigError, match="not a loopback address"):
        FrankaMock(rig, host="0.0.0.0")
    with pytest.raises(ValueError, match="initial_q must be 7 finite joint angles"):
        FrankaMock(rig, host=unique_host(), initial_q=[0.0] * 6)
