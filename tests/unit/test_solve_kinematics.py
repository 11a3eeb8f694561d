"""``tmscal solve SESSION --kinematics KIN``: A recomputed from the recorded joints with an arm
model (tmscal.solving.solve.with_kinematics). Sessions come from a sim rig whose arm has
hidden kinematic errors (tmscal.sim.arm): the controller reports the nominal flange, the
tracker sees the true one. Poses 4×4 mm, joints rad."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.calib.selfcal.model import forward
from tmscal.cli import main
from tmscal.errors import CalibrationError, SessionError
from tmscal.formats.kinfile import kinematics_yaml
from tmscal.geometry import make_pose, pose_mean, rot_x
from tmscal.poses import eq14_poses
from tmscal.session import PoseRecord, Session, make_header, read_session, write_session
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth
from tmscal.solving.solve import with_kinematics


def _session(path: Path, errors: str, n: int = 60, seed: int = 11,
             joints: bool = True) -> SimRig:
    """A session of n Eq. 14 poses (±100 mm, ±10°) from a UR5e rig with hidden ``errors``,
    the paper's noise, 10 tracker frames averaged per pose; returns the rig."""
    rig = SimRig(tms_rig_truth(), noise=Noise(), rng=np.random.default_rng(seed),
                 start=TMS_RIG_P0, arm=make_arm("ur5e", errors, seed))
    plan = eq14_poses(TMS_RIG_P0, n, np.random.default_rng(seed + 1), r_mm=100.0, d_deg=10.0)
    recs = []
    for i, P in enumerate(plan):
        rig.move_flange(P)
        recs.append(PoseRecord(
            index=i, A=rig.reported_flange(), B=pose_mean(rig.observe("marker", 10)),
            C=pose_mean(rig.observe("probe", 10)), commanded=P, time=float(i),
            samples={"A": 1, "B": 10, "C": 10},
            joints_rad=rig.joints() if joints else None))
    write_session(path, make_header(["marker", "probe"], truth=rig.truth.as_dict()), recs)
    return rig


def _solve(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(main, ["solve", *args])
    return r.exit_code, r.output


@pytest.mark.skipif(not hasattr(Session, "truth_arm"),
                    reason="the coil placement against a truth whose arm has errors runs that "
                           "arm's controller: needs the header's truth.arm (Session.truth_arm)")
@pytest.mark.parametrize("errors", ["paper", "all"])
def test_true_kinematics_lower_the_truth_errors(tmp_path, errors) -> None:
    """With the true arm's parameters, A is the flange the tracker saw (up to the robot's
    0.05 mm / 0.05° repeatability), so the coil placement and X, Y errors against the truth
    fall well below the uncorrected solve's, which carries the arm's millimetres: the
    calibration carries the arm and commands the flange through it, and the truth's
    controller (its nominal inverse kinematics, the true arm moving) executes the commands."""
    s = tmp_path / "s.jsonl"
    rig = _session(s, errors)
    kin = tmp_path / "kin.yaml"
    kin.write_text(kinematics_yaml(rig.arm_true))
    code, out = _solve(str(s), "--json")
    assert code == 0, out
    before = json.loads(out)["truth"]
    code, out = _solve(str(s), "--json", "--kinematics", str(kin))
    assert code == 0, out
    got = json.loads(out)
    after = got["truth"]
    assert got["kinematics"] == str(kin)
    assert after["coil_placement_mm"] < 0.3 * before["coil_placement_mm"], (before, after)
    assert after["coil_placement_mm"] < 0.2
    assert after["Y"]["trans_mm"] < before["Y"]["trans_mm"]


def test_nominal_kinematics_change_nothing_beyond_ik_tolerance(tmp_path) -> None:
    """The nominal DH chain at the recorded joints is what the controller reported (the
    IK tolerance apart), so the recomputed A equal the recorded ones; with a tilted base in
    the model, A stays in the robot's frame (base⁻¹ · forward)."""
    s = tmp_path / "s.jsonl"
    rig = _session(s, "paper", n=8)
    sess = read_session(s)
    again = with_kinematics(sess, rig.arm_nominal)
    for p, q in zip(sess.poses, again.poses, strict=True):
        np.testing.assert_allclose(q.A, p.A, atol=1e-6)
        np.testing.assert_array_equal(q.B, p.B)
        np.testing.assert_allclose(q.A, forward(rig.arm_nominal, p.joints_rad), atol=1e-12)
    tilted = replace(rig.arm_nominal, base=make_pose(rot_x(0.02), [5.0, -3.0, 1.0]))
    for p, q in zip(sess.poses, with_kinematics(sess, tilted).poses, strict=True):
        np.testing.assert_allclose(q.A, p.A, atol=1e-6)


def test_session_without_joints_is_refused_naming_the_first_pose(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    rig = _session(s, "paper", n=6, joints=False)
    kin = tmp_path / "kin.yaml"
    kin.write_text(kinematics_yaml(rig.arm_true))
    code, out = _solve(str(s), "--kinematics", str(kin))
    assert code != 0
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert len(lines) == 1 and "pose 0" in lines[0] and "joints_rad" in lines[0], out
    assert "Traceback" not in out


def test_joint_count_mismatch_names_pose_and_model(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    _session(s, "none", n=5)
    sess = read_session(s)
    sess.poses[2].joints_rad = sess.poses[2].joints_rad[:5]
    with pytest.raises(CalibrationError, match=r"pose 2 has 5 joint angles.*ur5e.*6"):
        with_kinematics(sess, make_arm("ur5e", "none", 0).nominal, "kin.yaml")


def test_skipped_poses_need_no_joints(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    rig = _session(s, "none", n=5)
    sess = read_session(s)
    sess.poses[1] = PoseRecord(index=1, A=None, B=None, skipped="tool not seen")
    out = with_kinematics(sess, rig.arm_nominal)
    assert out.poses[1].skipped == "tool not seen" and out.poses[1].A is None


def test_bad_kinematics_file_is_one_line(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    _session(s, "none", n=5)
    kin = tmp_path / "kin.yaml"
    kin.write_text("format: tmscal-kinematics\nversion: 1\narm: ur5e\n")
    code, out = _solve(str(s), "--kinematics", str(kin))
    assert code != 0 and "kin.yaml" in out and "Traceback" not in out
    assert len([ln for ln in out.splitlines() if ln.strip()]) == 1, out


def test_session_joints_in_the_order_asked_or_the_first_pose_without(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    rig = _session(s, "none", n=4)
    sess = read_session(s)
    q = sess.joints([2, 0])
    assert q.shape == (2, 6)
    np.testing.assert_array_equal(q[0], sess.poses[2].joints_rad)
    np.testing.assert_array_equal(q[1], sess.poses[0].joints_rad)
    # the reported flange is the nominal chain at the recorded joints
    np.testing.assert_allclose(rig.arm.reported(q[0]), sess.poses[2].A, atol=1e-6)
    sess.poses[3].joints_rad = None
    with pytest.raises(SessionError, match="pose 3 has no joint angles"):
        sess.joints([0, 3, 1])
    sess.poses[1].joints_rad = [0.0] * 5
    with pytest.raises(SessionError, match="pose 1 has 5 joint angles, pose 0 has 6"):
        sess.joints([0, 1])


def test_calib_check_on_recomputed_poses(tmp_path) -> None:
    """A calibration solved with --kinematics KIN carries that arm (docs/kinematics.md,
    "Using it"): checked on the same session it recomputes the robot poses from the joints
    by itself (hold-out errors at the noise level), the same file without its arm section
    checks badly on the controller's poses (the hidden errors are back in A), and --calib
    with --kinematics is refused (the file says which arm applies)."""
    s = tmp_path / "s.jsonl"
    rig = _session(s, "paper", n=30)
    kin = tmp_path / "kin.yaml"
    kin.write_text(kinematics_yaml(rig.arm_true))
    cal = tmp_path / "calib.yaml"
    code, out = _solve(str(s), "--kinematics", str(kin), "-o", str(cal))
    assert code == 0, out
    code, with_arm = _solve(str(s), "--calib", str(cal), "--json")
    assert code == 0, with_arm
    doc = yaml.safe_load(cal.read_text())
    assert doc["arm"]["source"] == str(kin) and doc["arm"]["nominal"] == "ur5e"
    del doc["arm"]
    bare = tmp_path / "bare.yaml"
    bare.write_text(yaml.safe_dump(doc))
    code, without = _solve(str(s), "--calib", str(bare), "--json")
    assert code == 0, without
    e_t = [json.loads(o)["errors"]["e_t_mm"] for o in (with_arm, without)]
    assert e_t[0] < 0.5 and e_t[1] > 10 * e_t[0], e_t
    code, both = _solve(str(s), "--calib", str(cal), "--kinematics", str(kin))
    assert code == 2 and "carries its own identified arm" in both


def test_kinematics_file_shows_before_and_after(tmp_path) -> None:
    """--kinematics KIN reports the same solve on the controller's poses beside the one with
    the arm: "before" is what solve without --kinematics gives (errors and truth), and with the
    true arm's parameters "after" is well below it (the arm's millimetres gone)."""
    s = tmp_path / "s.jsonl"
    rig = _session(s, "paper", n=40)
    kin = tmp_path / "kin.yaml"
    kin.write_text(kinematics_yaml(rig.arm_true))
    code, out = _solve(str(s), "--json", "--folds", "4")
    assert code == 0, out
    plain = json.loads(out)
    code, out = _solve(str(s), "--json", "--folds", "4", "--kinematics", str(kin))
    assert code == 0, out
    got = json.loads(out)
    before = got["nominal"]
    assert before["errors"] == plain["errors"] and before["errors_on"] == plain["errors_on"]
    assert before["truth"]["coil_placement_mm"] == plain["truth"]["coil_placement_mm"]
    assert got["errors"]["e_t_mm"] < 0.5 * before["errors"]["e_t_mm"]
    code, text = _solve(str(s), "--folds", "4", "--kinematics", str(kin))
    assert code == 0, text
    rows = text[text.index("before → after"):].splitlines()
    total = next(r for r in rows if r.strip().startswith("total"))
    b_mm, a_mm = (float(v) for v in total.split()[-4:-2])
    assert (b_mm, a_mm) == (round(before["errors"]["e_t_mm"], 4),
                            round(got["errors"]["e_t_mm"], 4))
    assert any(r.strip().startswith("coil placement vs the truth") for r in rows)


def test_without_kinematics_no_before_and_after(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    _session(s, "none", n=12)
    code, out = _solve(str(s), "--json", "--folds", "3")
    assert code == 0 and "nominal" not in json.loads(out), out
    code, out = _solve(str(s), "--folds", "3")
    assert code == 0 and "before → after" not in out
