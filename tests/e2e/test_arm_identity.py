"""Each robot driver says which arm it drives, as its controller tells it (docs/kinematics.md,
"Which arm the controller is"): UR from the dashboard's ``get robot model``, PolyScope version
and serial (through ur_rtde against the UR mock in a child process), DENSO from the robot's
``@TYPE_NAME`` over b-CAP; the mocks answer as the controller of their configured arm would, the
session header records it (``devices.robot.arm``) and every pose its joints, which put the
registered arm's flange where the controller reported it. Franka: tests/e2e/test_franka_sim.py.
Poses 4×4 mm, joints rad."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.acquisition.devices import make_robot
from tmscal.acquisition.run import acquire
from tmscal.calib.kinematics import ARMS, base_from_flange
from tmscal.config import load_config
from tmscal.errors import ConfigError
from tmscal.mocks.denso.controller import NO_ARM_TYPE_NAME
from tmscal.mocks.launch import spawn_mock_rig, start_mock_rig
from tmscal.session import read_session

from ..rigs import NOISE_FREE_MOCK, endpoints_kwargs

pytestmark = pytest.mark.e2e


def _check_poses(s, arm: str) -> None:
    """Every pose has the arm's joints, and the registered arm (mounted as the mock mounts
    it) puts the flange at those joints where the controller reported it (errors: none)."""
    spec = ARMS[arm]
    assert len(s.poses) >= 2
    for p in s.poses:
        assert p.joints_rad is not None and len(p.joints_rad) == spec.arm.n_joints, p.index
        A = spec.mount @ base_from_flange(spec.arm, np.array(p.joints_rad))
        assert np.linalg.norm(A[:3, 3] - p.A[:3, 3]) < 1e-3, p.index
        assert np.abs(A[:3, :3] - p.A[:3, :3]).max() < 1e-6, p.index


@pytest.mark.parametrize("arm, model, major", [("ur10", "UR10", "3"), ("ur16e", "UR16", "5")])
def test_ur_driver_names_the_arm_the_dashboard_describes(tmp_path, mock_config, arm, model,
                                                          major):
    pytest.importorskip("rtde_control")
    cfg_path = mock_config("mock-ur-polaris.yaml",
                           mock={"kinematics": {"arm": arm, "errors": "none"},
                                 "noise": NOISE_FREE_MOCK})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, poses=3, samples=5,
                      **endpoints_kwargs(mp.endpoints))
    assert res.recorded == 3, res
    s = read_session(out)
    robot = s.header["devices"]["robot"]
    # the mock answers as a CB3 (PolyScope 3.x) or an e-Series (5.x) controller of that size
    assert robot["model"] == model and robot["controller_version"].startswith(major + ".")
    assert robot["arm"] == arm
    _check_poses(s, arm)


def test_ur_mock_without_an_arm_answers_as_a_ur5e(mock_config):
    pytest.importorskip("rtde_control")
    cfg_path = mock_config("mock-ur-polaris.yaml")
    with spawn_mock_rig(cfg_path, transport="pty"):
        with make_robot(load_config(cfg_path)) as robot:
            ident = robot.identity()
    assert (ident["model"], ident["arm"]) == ("UR5", "ur5e")
    assert ident["serial"] == "20185500001"


@pytest.mark.parametrize("arm", ["cobotta", "vs060"])
def test_denso_driver_names_the_arm_its_type_name_describes(tmp_path, mock_config, arm):
    # ±30 mm, ±5°: within the COBOTTA's reach around P0 too
    cfg = load_config(mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                                  plan={"radius_mm": 30, "rotation_deg": 5},
                                  mock={"kinematics": {"arm": arm, "errors": "none"},
                                        "noise": NOISE_FREE_MOCK}))
    out = tmp_path / "s.jsonl"
    with start_mock_rig(cfg, tracker_transport="tcp") as mr:
        res = acquire(cfg, out, poses=3, samples=5, **endpoints_kwargs(mr.endpoints))
    assert res.recorded == 3, res
    s = read_session(out)
    robot = s.header["devices"]["robot"]
    assert robot["type_name"] == ARMS[arm].model and robot["arm"] == arm
    _check_poses(s, arm)


@pytest.mark.parametrize("kinematics, type_name", [(None, NO_ARM_TYPE_NAME),
                                                   ({"arm": "ur5e"}, NO_ARM_TYPE_NAME)])
def test_denso_without_a_denso_arm_names_none(mock_config, kinematics, type_name):
    mock = {} if kinematics is None else {"kinematics": kinematics}
    cfg = load_config(mock_config("mock-denso-polaris.yaml", robot={"port": 0}, mock=mock))
    with start_mock_rig(cfg, tracker_transport="tcp") as mr:
        host, _, port = mr.endpoints["robot"].partition(":")
        with make_robot(cfg, host=host, port=int(port)) as robot:
            ident = robot.identity()
    assert ident["type_name"] == type_name and ident["arm"] is None


@pytest.mark.parametrize("base, robot", [("mock-ur-polaris.yaml", {}),
                                         ("mock-denso-polaris.yaml", {"port": 0})])
def test_a_seven_joint_arm_on_a_six_joint_controller_is_a_config_error(mock_config, base,
                                                                        robot):
    cfg = load_config(mock_config(base, robot=robot, mock={"kinematics": {"arm": "fr3"}}))
    with pytest.raises(ConfigError, match=r"mock\.robot.*six.*fr3 has 7"):
        start_mock_rig(cfg, tracker_transport="tcp")
