"""End to end: mock robots with a serial arm (``mock.kinematics``; docs/selfcal.md, "On the
rig") behind the real drivers — UR through ur_rtde (the mock in a child process), DENSO through
b-CAP — record joint angles in the session; the controller reports the nominal model's flange;
``solve --kinematics`` with the true arm corrects what the hidden errors did; an unreachable
target is refused and nothing moves. Poses 4×4 mm, joints rad."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.acquisition.run import acquire
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.drivers.base import Envelope
from tmscal.drivers.denso.robot import DensoRobot
from tmscal.errors import DeviceError
from tmscal.formats.kinfile import kinematics_yaml
from tmscal.geometry import make_pose
from tmscal.mocks.launch import build_sim_rig, spawn_mock_rig, start_mock_rig
from tmscal.session import read_session

from ..rigs import endpoints_kwargs

pytestmark = pytest.mark.e2e

KIN = {"arm": "ur5e", "errors": "paper", "seed": 3}


@pytest.mark.parametrize("base, robot, kin", [
    ("mock-ur-polaris.yaml", {}, KIN),
    ("mock-denso-polaris.yaml", {"port": 0}, {**KIN, "arm": "vs060"})])
def test_joints_reach_the_session_and_true_kinematics_correct_a(tmp_path, mock_config, base,
                                                                 robot, kin):
    if "ur" in base:
        pytest.importorskip("rtde_control")
    cfg_path = mock_config(base, robot=robot, plan={"poses": 16}, sampling={"samples": 5},
                           mock={"kinematics": kin})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert (res.recorded, res.skipped) == (16, 0)
    # the child built its rig from the same config: the same arm, nominal and true
    rig = build_sim_rig(load_config(cfg_path))
    s = read_session(out)
    for p in s.poses:
        assert p.joints_rad is not None and len(p.joints_rad) == 6
        # the controller reported the nominal model's flange for the joints it reported
        A_nominal = rig.arm.reported(np.array(p.joints_rad))
        assert np.linalg.norm(A_nominal[:3, 3] - p.A[:3, 3]) < 1e-3, p.index
        # … which is the commanded pose (IK), not where the true arm put the flange
        assert np.linalg.norm(p.A[:3, 3] - p.commanded[:3, 3]) < 1e-3
    q = np.array([p.joints_rad for p in s.poses])
    assert np.ptp(q, axis=0).max() > 0.05   # the joints moved with the plan
    gap = np.array([np.linalg.norm(rig.arm.actual(qi)[:3, 3] - rig.arm.reported(qi)[:3, 3])
                    for qi in q])
    assert gap.min() > 0.1   # the hidden errors are there to correct (mm)
    kin_file = tmp_path / "true.yaml"
    kin_file.write_text(kinematics_yaml(rig.arm_true))
    runner = CliRunner()
    before = runner.invoke(main, ["solve", str(out), "--json", "--in-sample"])
    after = runner.invoke(main, ["solve", str(out), "--json", "--in-sample",
                                 "--kinematics", str(kin_file)])
    assert before.exit_code == 0 and after.exit_code == 0, (before.output, after.output)
    # the session header carries no truth: compare X, Y, Z with the rig's directly
    b, a = json.loads(before.output), json.loads(after.output)
    Y = rig.truth.Y
    assert Y is not None
    err_b = np.linalg.norm(np.array(b["Y"])[:3, 3] - Y[:3, 3])
    err_a = np.linalg.norm(np.array(a["Y"])[:3, 3] - Y[:3, 3])
    assert err_a < 0.5 * err_b and err_a < 0.5, (err_b, err_a)


def test_denso_unreachable_target_is_refused_and_nothing_moves(mock_config):
    cfg = load_config(mock_config("mock-denso-polaris.yaml", robot={"port": 0},
                                  mock={"kinematics": KIN}))
    with start_mock_rig(cfg, tracker_transport="tcp") as mr:
        host, _, port = mr.endpoints["robot"].partition(":")
        robot = DensoRobot(host=host, port=int(port), envelope=Envelope())
        with robot:
            q0 = robot.joint_positions()
            np.testing.assert_allclose(q0, mr.rig.joints(), atol=1e-9)
            here = robot.flange_pose()
            far = make_pose(here[:3, :3], [2500.0, 0.0, 400.0])
            with pytest.raises(DeviceError, match="(?i)reach|0x80070057"):
                robot.move_to(far)
            np.testing.assert_array_equal(robot.joint_positions(), q0)
            np.testing.assert_allclose(robot.flange_pose(), here, atol=1e-9)
            assert len(mr.rig.moves) == 0


def test_ur_unreachable_target_is_refused_and_nothing_moves(mock_config):
    """ur_rtde's moveL to a pose the arm cannot reach: the mock's control script stops with a
    runtime error (as a controller without an IK solution does); the driver raises and the
    joints and flange stay where they were."""
    pytest.importorskip("rtde_control")
    from tmscal.drivers.ur.robot import URRobot
    cfg_path = mock_config("mock-ur-polaris.yaml", mock={"kinematics": KIN})
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        robot = URRobot(mp.endpoints["robot"], envelope=Envelope())
        with robot:
            q0 = robot.joint_positions()
            here = robot.flange_pose()
            np.testing.assert_allclose(build_sim_rig(load_config(cfg_path)).arm.reported(q0),
                                       here, atol=1e-6)
            with pytest.raises(DeviceError):
                robot.move_to(make_pose(here[:3, :3], [2500.0, 0.0, 400.0]))
        with URRobot(mp.endpoints["robot"], envelope=Envelope()) as again:
            np.testing.assert_array_equal(again.joint_positions(), q0)
            np.testing.assert_allclose(again.flange_pose(), here, atol=1e-9)


# --- realistic arm errors (configs/mock-*-polaris-kin.yaml; docs/kinematics.md) -------------

def test_realistic_ur5e_session_records_joints_and_its_truth_arm_explains_the_tracker(
        tmp_path, mock_config):
    """An acquisition on configs/mock-ur-polaris-kin.yaml through ur_rtde and the Polaris
    protocol (noise-free rig): joints on every pose; the driver names the arm; with the mock
    rig's truth put in the header as the demo puts it (written and read back), its
    ``truth_arm`` is the child's arm: the nominal one gives every reported A, the true one
    every tracked B (to the Polaris' reporting resolution), and the two differ by the arm's
    error."""
    pytest.importorskip("rtde_control")
    from tests.rigs import NOISE_FREE_MOCK
    from tmscal.calib.kinematics import forward
    from tmscal.geometry import invert
    from tmscal.session import write_session

    cfg_path = mock_config("mock-ur-polaris-kin.yaml", plan={"poses": 12}, sampling={"samples": 5},
                           mock={"noise": NOISE_FREE_MOCK})
    out = tmp_path / "s.jsonl"
    with spawn_mock_rig(cfg_path, transport="pty") as mp:
        res = acquire(load_config(cfg_path), out, **endpoints_kwargs(mp.endpoints))
    assert (res.recorded, res.skipped) == (12, 0)
    s = read_session(out)
    assert s.header["devices"]["robot"]["arm"] == "ur5e"
    assert s.truth_arm is None   # an acquisition does not know it ran on a mock
    header = {**s.header, "truth": build_sim_rig(load_config(cfg_path)).truth.as_dict()}
    write_session(tmp_path / "t.jsonl", header, s.poses)
    t = read_session(tmp_path / "t.jsonl")
    ta, truth = t.truth_arm, t.truth
    assert ta is not None and (ta["name"], ta["errors"]) == ("ur5e", "realistic")
    assert ta["name"] == t.header["devices"]["robot"]["arm"]
    fit_true, fit_nominal = [], []
    for p in t.poses:
        assert p.joints_rad is not None and len(p.joints_rad) == 6, p.index
        q = np.array(p.joints_rad)
        A = ta["mount"] @ forward(ta["nominal"], q)
        assert np.linalg.norm(A[:3, 3] - p.A[:3, 3]) < 1e-3, p.index
        for flange, errs in ((ta["mount"] @ forward(ta["true"], q), fit_true),
                             (A, fit_nominal)):
            B = invert(truth["Z"]) @ flange @ truth["X"]
            errs.append(np.linalg.norm(B[:3, 3] - p.B[:3, 3]))
    assert max(fit_true) < 0.02, fit_true
    assert np.median(fit_nominal) > 0.2, fit_nominal


@pytest.mark.parametrize("base, robot", [("mock-ur-polaris-kin.yaml", {}),
                                         ("mock-denso-polaris-kin.yaml", {"port": 0})])
def test_demo_runs_on_the_realistic_arm_configs(mock_config, base, robot):
    import subprocess
    import sys
    if "ur" in base:
        pytest.importorskip("rtde_control")
    cfg = mock_config(base, robot=robot)
    out = subprocess.run([sys.executable, "-m", "tmscal.cli", "demo", "--config", str(cfg),
                          "--poses", "12", "--samples", "5", "--json"],
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["method"] == "qr36" and res["n_solve"] == 12
    assert res["truth"]["coil_placement_mm"] > 0.0
