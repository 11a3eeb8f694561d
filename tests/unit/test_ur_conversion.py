"""UR pose vectors [x, y, z (m), rx, ry, rz (rotation vector, rad)] ↔ 4×4 poses in mm, against
hand-computed poses; the URRobot TCP-offset conversion; the mock's RTDE type table and
async-progress register against ur_rtde's documented bit layout; the RTDE codec's package
letters and recipes; the fault names."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tmscal.drivers.ur.robot import base_from_flange_from_tcp, tcp_pose_from_base_from_flange
from tmscal.errors import ConfigError
from tmscal.geometry import pose_from_rotvec, rotvec_pose_from_matrix
from tmscal.mocks.ur import PackageType, Recipe, URFaults, URMock, rtde_type
from tmscal.sim.rig import TMS_RIG_P0, Noise, SimRig, tms_rig_truth

S2 = np.sqrt(0.5)

# (UR vector, 4×4 mm) pairs worked out by hand
CASES = [
    # quarter turn about z, translation 0.1, 0.2, 0.3 m
    ([0.1, 0.2, 0.3, 0.0, 0.0, np.pi / 2],
     [[0, -1, 0, 100], [1, 0, 0, 200], [0, 0, 1, 300], [0, 0, 0, 1]]),
    # quarter turn about x, negative translation
    ([-0.25, 0.0, 1.5, np.pi / 2, 0.0, 0.0],
     [[1, 0, 0, -250], [0, 0, -1, 0], [0, 1, 0, 1500], [0, 0, 0, 1]]),
    # 120° about (1, 1, 1)/√3: x → y → z → x
    ([0.0, 0.0, 0.0, *(2 * np.pi / 3 / np.sqrt(3) * np.ones(3))],
     [[0, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]),
    # 45° about y, 2 mm
    ([0.002, 0.0, 0.0, 0.0, np.pi / 4, 0.0],
     [[S2, 0, S2, 2], [0, 1, 0, 0], [-S2, 0, S2, 0], [0, 0, 0, 1]]),
    # the TMS rig's P0: flange down, half turn about x, at (0.5, 0, 0.4) m
    ([0.5, 0.0, 0.4, np.pi, 0.0, 0.0],
     [[1, 0, 0, 500], [0, -1, 0, 0], [0, 0, -1, 400], [0, 0, 0, 1]]),
]


@pytest.mark.parametrize(("vec", "pose"), CASES)
def test_pose_from_rotvec_hand_computed(vec: list[float], pose: list[list[float]]) -> None:
    assert np.allclose(pose_from_rotvec(vec), pose, atol=1e-12)


@pytest.mark.parametrize(("vec", "pose"), CASES[:4])
def test_rotvec_pose_from_matrix_hand_computed(vec: list[float],
                                               pose: list[list[float]]) -> None:
    assert np.allclose(rotvec_pose_from_matrix(np.array(pose, dtype=float)), vec, atol=1e-12)


def test_half_turn_gives_angle_pi() -> None:
    v = rotvec_pose_from_matrix(TMS_RIG_P0)
    assert np.allclose(v[:3], [0.5, 0.0, 0.4], atol=1e-12)
    # ±π about x are the same rotation
    assert np.isclose(abs(v[3]), np.pi, atol=1e-12) and np.allclose(v[4:], 0.0, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
       st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
       st.floats(0.0, 3.1))
def test_round_trip(t_m: list[float], axis: list[float], angle: float) -> None:
    a = np.array(axis)
    if np.linalg.norm(a) < 1e-3:
        a = np.array([0.0, 0.0, 1.0])
    vec = np.concatenate([t_m, a / np.linalg.norm(a) * angle])
    T = pose_from_rotvec(vec)
    assert np.allclose(rotvec_pose_from_matrix(T), vec, atol=1e-9)
    assert np.allclose(pose_from_rotvec(rotvec_pose_from_matrix(T)), T, atol=1e-9)


def test_tcp_offset_conversion_hand_computed() -> None:
    # TCP 100 mm along the flange z axis; flange at P0 (z pointing down) → TCP 100 mm lower
    flange_from_tcp = pose_from_rotvec([0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
    tcp = tcp_pose_from_base_from_flange(TMS_RIG_P0, flange_from_tcp)
    assert np.allclose(tcp[:3], [0.5, 0.0, 0.3], atol=1e-12)
    assert np.allclose(base_from_flange_from_tcp(tcp, flange_from_tcp), TMS_RIG_P0, atol=1e-9)
    # zero offset: TCP = flange
    assert np.allclose(tcp_pose_from_base_from_flange(TMS_RIG_P0, np.eye(4))[:3],
                       [0.5, 0.0, 0.4], atol=1e-12)


@pytest.mark.parametrize(("name", "rtde"), [
    ("actual_TCP_pose", "VECTOR6D"), ("target_q", "VECTOR6D"), ("ft_raw_wrench", "VECTOR6D"),
    ("payload_cog", "VECTOR3D"), ("elbow_position", "VECTOR3D"),
    ("joint_mode", "VECTOR6INT32"), ("robot_mode", "INT32"), ("safety_mode", "INT32"),
    ("output_int_register_2", "INT32"), ("input_int_register_30", "INT32"),
    ("runtime_state", "UINT32"), ("robot_status_bits", "UINT32"),
    ("safety_status_bits", "UINT32"), ("actual_digital_input_bits", "UINT64"),
    ("timestamp", "DOUBLE"), ("output_double_register_5", "DOUBLE"),
    ("input_bit_register_64", "BOOL"), ("no_such_variable", "DOUBLE"),
])
def test_rtde_types_per_protocol_sheet(name: str, rtde: str) -> None:
    assert rtde_type(name) == rtde


def test_async_progress_register_layout() -> None:
    mock = URMock(SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0))
    # constructed with a running program: one "finished" write (change count 1, op id 0)
    assert mock.out_int[2] == 1 << 16
    mock._write_async(0)        # operation started: count 2, op id 1, bit 15, progress 0
    assert mock.out_int[2] == (1 << 24) | (2 << 16) | 0x8000
    mock._write_async(7)        # progress 7
    assert mock.out_int[2] == (1 << 24) | (3 << 16) | 0x8000 | 7
    mock._write_async(-1)       # finished
    assert mock.out_int[2] == (1 << 24) | (4 << 16)


def test_mock_refuses_non_loopback() -> None:
    with pytest.raises(ConfigError, match="loopback"):
        URMock(SimRig(tms_rig_truth()), host="0.0.0.0")


def test_rtde_package_letters() -> None:
    # the letters on the wire, as in UR's RTDE guide
    assert [chr(t) for t in (PackageType.RTDE_REQUEST_PROTOCOL_VERSION,
                             PackageType.RTDE_GET_URCONTROL_VERSION,
                             PackageType.RTDE_TEXT_MESSAGE, PackageType.RTDE_DATA_PACKAGE,
                             PackageType.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS,
                             PackageType.RTDE_CONTROL_PACKAGE_SETUP_INPUTS,
                             PackageType.RTDE_CONTROL_PACKAGE_START,
                             PackageType.RTDE_CONTROL_PACKAGE_PAUSE)] == list("VvMUOISP")


def test_recipe_packs_and_unpacks_in_order() -> None:
    r = Recipe.from_names(["timestamp", "actual_TCP_pose", "output_int_register_0",
                           "input_bit_register_64"])
    assert r.setup_reply(3) == b"\x03DOUBLE,VECTOR6D,INT32,BOOL"
    data = r.pack(3, [1.5, [0.5, 0.0, 0.4, 3.0, 0.0, 0.0], -7, True])
    assert len(data) == 1 + 8 + 48 + 4 + 1 and data[0] == 3
    assert r.unpack(data) == [("timestamp", [1.5]),
                              ("actual_TCP_pose", [0.5, 0.0, 0.4, 3.0, 0.0, 0.0]),
                              ("output_int_register_0", [-7]),
                              ("input_bit_register_64", [True])]


def test_ur_faults_earlier_name_still_accepted() -> None:
    assert URFaults(drop_connection_at_move=2) == URFaults(drop_at_move=2)
    assert URFaults(drop_at_move=4).drop_connection_at_move == 4
    with pytest.raises(ValueError, match="disagree"):
        URFaults(drop_at_move=2, drop_connection_at_move=3)
