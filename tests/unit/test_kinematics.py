"""The serial-arm kinematics (tmscal.calib.kinematics): every registered arm's forward
kinematics against the pose its published table implies by hand (q = 0 and one more
configuration), the DENSO tables against the joint origins of DENSO's ROS descriptions they were
derived from, Franka's against the FR3 description franky-sim ships, the analytic pose Jacobian
against central differences in both DH conventions, and the registry's lookups. Poses 4×4 mm,
angles rad."""

from __future__ import annotations

import importlib.util
import math
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tmscal.calib.kinematics import (
    ARM_NAMES,
    ARMS,
    Arm,
    arm_by_name,
    base_from_flange,
    find_arm,
    forward,
    joint_frames,
    joint_jacobian,
    pose_from_rpy,
    pose_jacobian,
)
from tmscal.errors import ConfigError
from tmscal.geometry import invert, make_pose, rot_x, rot_y, rot_z, rotvec_from_matrix

H = math.pi / 2
#: the six lengths (mm) of each UR's published table: d1, a2, a3, d4, d5, d6
UR_TABLE = {"ur3": (151.9, -243.65, -213.25, 112.35, 85.35, 81.9),
            "ur5": (89.159, -425.0, -392.25, 109.15, 94.65, 82.3),
            "ur10": (127.3, -612.0, -572.3, 163.941, 115.7, 92.2),
            "ur3e": (151.85, -243.55, -213.2, 131.05, 85.35, 92.1),
            "ur5e": (162.5, -425.0, -392.2, 133.3, 99.7, 99.6),
            "ur10e": (180.7, -612.7, -571.55, 174.15, 119.85, 116.55),
            "ur16e": (180.7, -478.4, -360.0, 174.15, 119.85, 116.55),
            "ur20": (236.3, -862.0, -728.7, 201.0, 159.3, 154.3)}


def test_the_registry_lists_the_twelve_arms_by_their_vendor_names():
    assert ARM_NAMES == ("ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20",
                         "vs060", "cobotta", "fr3", "panda")
    for name, spec in ARMS.items():
        assert spec.arm.name == name and spec.source and spec.model.lower().replace("-", "") \
            == name
        lim = spec.arm.joint_limits_rad
        assert np.all(lim[:, 0] < lim[:, 1])
    assert {n for n, s in ARMS.items() if s.approximate} == {"vs060", "cobotta"}
    assert {n for n, s in ARMS.items() if s.arm.convention == "modified"} == {"fr3", "panda"}


@pytest.mark.parametrize("name", sorted(UR_TABLE))
def test_ur_zero_and_upright_poses_are_the_published_tables(name):
    d1, a2, a3, d4, d5, d6 = UR_TABLE[name]
    arm = arm_by_name(name)
    # q = 0: the arm stretched along −x: x = a2 + a3, y = −(d4 + d6), z = d1 − d5; the tool
    # axis along −y (e.g. the UR5e's tool0 at (−817.2, −232.9, 62.8) mm)
    T = forward(arm, np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [a2 + a3, -(d4 + d6), d1 - d5], atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], rot_x(H), atol=1e-12)
    # shoulder and wrist 1 at −90°: upper arm and forearm straight up, the wrist 2 offset d5
    # on top, the tool axis still along −y
    T = forward(arm, [0.0, -H, 0.0, -H, 0.0, 0.0])
    np.testing.assert_allclose(T[:3, 3], [0.0, -(d4 + d6), d1 - a2 - a3 + d5], atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(T[:3, 0], [-1.0, 0.0, 0.0], atol=1e-12)


def test_ur5e_zero_pose_is_the_one_universal_robots_documents():
    np.testing.assert_allclose(forward(arm_by_name("ur5e"), np.zeros(6))[:3, 3],
                               [-817.2, -232.9, 62.8], atol=1e-9)


def _urdf_fk(chain: list[tuple[tuple[float, ...], tuple[float, ...], str]],
             q: np.ndarray) -> np.ndarray:
    """Product of URDF joints: origin Trans(xyz) · Rz Ry Rx(rpy), then the rotation q_i about
    the joint's axis ("x", "y", "z" or "" for a fixed joint)."""
    T = np.eye(4)
    k = 0
    for xyz, rpy, axis in chain:
        T = T @ make_pose(rot_z(rpy[2]) @ rot_y(rpy[1]) @ rot_x(rpy[0]), xyz)
        if axis:
            T = T @ make_pose({"x": rot_x, "y": rot_y, "z": rot_z}[axis](q[k]))
            k += 1
    return T


#: joint origins (mm) and axes of DENSO's own ROS descriptions: denso_robot_ros vs060.urdf and
#: denso_cobotta_ros cobotta.urdf (every rpy zero; the flange is the J6 frame)
DENSO_URDF = {
    "vs060": [((0, 0, 181.5), (0, 0, 0), "z"), ((0, 0, 163.5), (0, 0, 0), "y"),
              ((0, 0, 305.0), (0, 0, 0), "y"), ((-10, 0, 164.5), (0, 0, 0), "z"),
              ((0, 0, 135.5), (0, 0, 0), "y"), ((0, 0, 70.0), (0, 0, 0), "z")],
    "cobotta": [((0, 0, 0), (0, 0, 0), "z"), ((0, 0, 180.0), (0, 0, 0), "y"),
                ((0, 0, 165.0), (0, 0, 0), "y"), ((-12, 20, 177.5), (0, 0, 0), "z"),
                ((0, -20, 0), (0, 0, 0), "y"), ((0, -44.5, 42.0), (0, 0, 0), "z")],
}


@pytest.mark.parametrize("name", sorted(DENSO_URDF))
def test_denso_tables_reproduce_the_ros_descriptions(name):
    arm = arm_by_name(name)
    rng = np.random.default_rng(4)
    for q in rng.uniform(-3.0, 3.0, (10, 6)):
        np.testing.assert_allclose(forward(arm, q), _urdf_fk(DENSO_URDF[name], q), atol=1e-9)


def test_cobotta_by_hand():
    arm = arm_by_name("cobotta")
    # q = 0: straight up; the flange is 12 mm behind and 44.5 mm beside the J1 axis,
    # 180 + 165 + 177.5 + 42 mm up, parallel to the base
    np.testing.assert_allclose(forward(arm, np.zeros(6)),
                               make_pose(np.eye(3), [-12.0, -44.5, 564.5]), atol=1e-9)
    # J2 +90° about the base y: the part above J2 ((−12, −44.5, 384.5) from (0, 0, 180)) turns
    # to (384.5, −44.5, 12) from it
    T = forward(arm, [0.0, H, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(T, make_pose(rot_y(H), [384.5, -44.5, 192.0]), atol=1e-9)


@pytest.mark.parametrize("name", ["fr3", "panda"])
def test_franka_flange_by_hand(name):
    arm = arm_by_name(name)
    # q = 0 (Franka's zero: straight up, joint 4 at 0, outside its range): the flange F
    # 333 + 316 + 384 − 107 mm up and a4 + a5 + a7 = 88 mm along x, pointing down
    np.testing.assert_allclose(forward(arm, np.zeros(7)),
                               make_pose(np.diag([1.0, -1.0, -1.0]), [88.0, 0.0, 926.0]),
                               atol=1e-9)
    # joint 4 at −90° (its axis −y, through (82.5, 0, 649)): the flange's (5.5, 0, 277) from
    # that point turns by +90° about +y to (277, 0, −5.5)
    T = forward(arm, [0.0, 0.0, 0.0, -H, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(T, make_pose(rot_y(H) @ np.diag([1.0, -1.0, -1.0]),
                                            [359.5, 0.0, 643.5]), atol=1e-9)


def test_franka_matches_the_fr3_description_franky_sim_ships():
    """franky-sim's FR3 URDF (``link8``, the flange, which the Franka mock reports) against
    the modified DH table: read from the file, not imported (franky-sim needs pinocchio)."""
    spec = importlib.util.find_spec("franky_sim")
    if spec is None or not spec.submodule_search_locations:
        pytest.skip("franky-sim (the test extra) is not installed")
    urdf = Path(list(spec.submodule_search_locations)[0]) / "assets" / "fr3_clean.urdf"
    root = ET.parse(urdf).getroot()
    joints = {j.find("parent").get("link"): j for j in root.findall("joint")
              if j.find("child").get("link") in {f"link{i}" for i in range(1, 9)}}
    chain, link = [], "link0"
    while link != "link8":
        j = joints[link]
        o = j.find("origin")
        axis = j.find("axis")
        assert axis is None or axis.get("xyz").split() == ["0", "0", "1"]
        chain.append((tuple(1000.0 * float(v) for v in o.get("xyz").split()),
                      tuple(float(v) for v in o.get("rpy").split()),
                      "z" if j.get("type") == "revolute" else ""))
        link = j.find("child").get("link")
    arm = arm_by_name("fr3")
    rng = np.random.default_rng(9)
    for q in rng.uniform(arm.joint_limits_rad[:, 0], arm.joint_limits_rad[:, 1], (10, 7)):
        np.testing.assert_allclose(forward(arm, q), _urdf_fk(chain, q), atol=1e-9)


def odd(arm: Arm) -> Arm:
    """The arm on a tilted, shifted base with a turned, offset flange."""
    return replace(arm, base=pose_from_rpy([0.1, -0.05, 0.3], [10.0, 20.0, 30.0]),
                   flange=pose_from_rpy([0.2, 0.1, -0.4], [3.0, -5.0, 40.0]))


def _delta(T1: np.ndarray, T0: np.ndarray) -> np.ndarray:
    """(…, 6) [t1 − t0, rotation vector of R1 R0ᵀ] (world frame)."""
    return np.concatenate([T1[..., :3, 3] - T0[..., :3, 3],
                           rotvec_from_matrix(T1[..., :3, :3]
                                              @ np.swapaxes(T0[..., :3, :3], -1, -2))], -1)


@pytest.mark.parametrize("name", ARM_NAMES)
def test_pose_jacobian_matches_central_differences(name):
    arm = odd(arm_by_name(name))
    q = np.random.default_rng(2).uniform(arm.joint_limits_rad[:, 0],
                                         arm.joint_limits_rad[:, 1], (6, arm.n_joints))
    J = pose_jacobian(arm, q)
    p = arm.geometry_vector()
    assert J.shape == (6, 6, len(p)) == (6, 6, 4 * arm.n_joints + 12)
    T0 = forward(arm, q)
    for j, pname in enumerate(arm.geometry_names()):
        h = 1e-6
        up, dn = p.copy(), p.copy()
        up[j] += h
        dn[j] -= h
        fd = (_delta(forward(arm.with_geometry(up), q), T0)
              - _delta(forward(arm.with_geometry(dn), q), T0)) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], fd, atol=2e-6 * max(1.0, np.abs(fd).max()),
                                   err_msg=pname)


@pytest.mark.parametrize("name", ["ur5e", "fr3"])
def test_joint_jacobian_matches_central_differences(name):
    arm = odd(arm_by_name(name))
    q = np.random.default_rng(3).uniform(-2.0, 2.0, (4, arm.n_joints))
    J = joint_jacobian(arm, q)
    T0 = forward(arm, q)
    for i in range(arm.n_joints):
        dq = np.zeros(arm.n_joints)
        dq[i] = 1e-6
        fd = (_delta(forward(arm, q + dq), T0) - _delta(forward(arm, q - dq), T0)) / 2e-6
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_base_and_flange_frames():
    arm = odd(arm_by_name("panda"))
    q = np.random.default_rng(5).uniform(-1.0, 1.0, (3, 7))
    # the controller's view leaves the base out; the world view puts it in
    np.testing.assert_allclose(base_from_flange(arm, q), invert(arm.base) @ forward(arm, q),
                               atol=1e-9)
    # the flange is the last DH frame times ``flange``
    np.testing.assert_allclose(forward(arm, q), joint_frames(arm, q)[:, -1] @ arm.flange,
                               atol=1e-9)
    assert forward(arm, q[0]).shape == (4, 4)


def test_geometry_vector_round_trip_and_plain_dict():
    arm = odd(arm_by_name("fr3"))
    back = arm.with_geometry(arm.geometry_vector())
    for key in ("dh", "base", "flange"):
        np.testing.assert_allclose(getattr(back, key), getattr(arm, key), atol=1e-12)
    assert back.convention == "modified"
    assert len(arm.geometry_names()) == len(arm.geometry_units()) == 4 * 7 + 12
    again = Arm.from_dict(arm.to_dict())
    np.testing.assert_array_equal(again.flange, arm.flange)
    assert again.convention == "modified" and again.name == "fr3"
    # an older dict has neither convention nor flange: standard DH, identity flange
    old = {k: v for k, v in arm_by_name("ur5e").to_dict().items()
           if k not in ("convention", "flange")}
    assert Arm.from_dict(old).convention == "standard"
    with pytest.raises(ValueError, match="missing key 'dh'"):
        Arm.from_dict({"name": "x"})


@pytest.mark.parametrize("kw, match", [({"convention": "craig"}, "convention"),
                                       ({"dh": np.zeros((6, 3))}, "dh"),
                                       ({"flange": np.eye(3)}, "flange"),
                                       ({"joint_limits_rad": [[1.0, -1.0]] * 6}, "limits")])
def test_bad_arms_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        replace(arm_by_name("ur5e"), **kw)
    with pytest.raises(ValueError, match="7 joint values"):
        forward(arm_by_name("fr3"), np.zeros(6))


def test_arm_by_name_names_the_key_and_the_known_arms():
    assert arm_by_name("cobotta").n_joints == 6
    with pytest.raises(ConfigError, match=r"^solve --arm: unknown arm 'ur30'; expected one of: "
                                          r"ur3, ur5, .*, fr3, panda$"):
        arm_by_name("ur30", "solve --arm")
    with pytest.raises(ConfigError, match="unknown arm int value"):
        arm_by_name(5)


@pytest.mark.parametrize("vendor, model, generation, name", [
    ("Universal Robots", "UR5", "e-Series", "ur5e"),
    ("Universal Robots", "UR5", "CB3", "ur5"),
    ("Universal Robots", "UR5", None, None),         # CB3 UR5 or UR5e: not told
    ("Universal Robots", "UR16", None, "ur16e"),      # only an e-Series
    ("Universal Robots", "UR20", "e-Series", "ur20"),
    ("Universal Robots", "ur10e", "e-Series", None),  # the dashboard says UR10, not UR10e
    ("Universal Robots", "UR30", "e-Series", None),
    ("DENSO", "VS-060", None, "vs060"),
    ("DENSO", "vs060", None, "vs060"),
    ("DENSO", "COBOTTA", None, "cobotta"),
    ("Franka", "fr3", None, "fr3"),
    ("Franka", "panda", None, "panda"),
    ("Franka", "", None, None),
])
def test_find_arm_by_what_the_controller_says(vendor, model, generation, name):
    assert find_arm(vendor, model, generation) == name


@pytest.mark.parametrize("name", ARM_NAMES)
def test_home_configuration_is_inside_the_limits(name):
    spec = ARMS[name]
    lim = spec.arm.joint_limits_rad
    assert len(spec.home_q) == spec.arm.n_joints
    assert np.all(np.array(spec.home_q) >= lim[:, 0]) and np.all(np.array(spec.home_q) <= lim[:, 1])
