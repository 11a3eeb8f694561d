"""Using an identified arm (docs/kinematics.md, "Using it"): ``solve(kinematics=
"estimate")`` on sessions of a simulated rig whose arm has hidden errors; the calibration file
keeps the arm (its kinematics in the kinematics format, the controller frame, the seeds, the
report) through YAML and the json export, and files without one still load; the daily check
recomputes the robot poses with the stored arm; the truth placement runs the truth arm's
controller; the stream commands the coil through the arm; clear errors for a session without
joints or without a named arm.

Poses 4×4 mm (A = base_from_flange, B/C = tracker_from_marker/probe), joints rad.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal import solving
from tmscal.calib import solve
from tmscal.calib.kinematics import arm_by_name, base_from_flange
from tmscal.calib.kinematics import estimate as est
from tmscal.calib.metrics import placement_errors
from tmscal.check import check_calibration
from tmscal.cli import main
from tmscal.errors import CalibrationError
from tmscal.exports.jsonfmt import render as render_json
from tmscal.formats.calibfile import (
    CalibrationFile,
    calibration_yaml,
    parse_calibration,
    read_calibration,
)
from tmscal.formats.kinfile import kinematics_doc, parse_kinematics
from tmscal.geometry import make_pose, pose_mean, random_rotation
from tmscal.poses import eq14_poses
from tmscal.session import PoseRecord, make_header, read_session, write_session
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth
from tmscal.solving.kinematics import coil_placement

HOME = np.array([np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


def _session(path: Path, arm: str = "vs060", n: int = 30, seed: int = 21,
              arm_seed: int = 5, joints: bool = True, recorded_arm: bool = True) -> SimRig:
    """n Eq. 14 poses (±100 mm, ±10°) of a rig whose ``arm`` has hidden errors ("all": every
    geometric parameter, uniform ±2 mm / ±1°, drawn from ``arm_seed``), the paper's noise,
    10 tracker frames per pose; the header records the arm as a driver would."""
    rig = SimRig(tms_rig_truth(), noise=Noise(), rng=np.random.default_rng(seed),
                 start=TMS_RIG_P0, arm=make_arm(arm, "all", arm_seed))
    plan = eq14_poses(TMS_RIG_P0, n, np.random.default_rng(seed + 1), r_mm=100.0, d_deg=10.0)
    recs = []
    for i, P in enumerate(plan):
        rig.move_flange(P)
        recs.append(PoseRecord(
            index=i, A=rig.reported_flange(), B=pose_mean(rig.observe("marker", 10)),
            C=pose_mean(rig.observe("probe", 10)), commanded=P, time=float(i),
            samples={"A": 1, "B": 10, "C": 10}, joints_rad=rig.joints() if joints else None))
    devices = {"robot": {"driver": "sim", **({"arm": arm} if recorded_arm else {})}}
    write_session(path, make_header(["marker", "probe"], truth=rig.truth.as_dict(),
                                    devices=devices), recs)
    return rig


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory):
    """A VS-060 session (its mock mount puts the robot base 150 mm from the rig frame, the
    frame its controller reports in) solved with the arm estimated at level full."""
    d = tmp_path_factory.mktemp("kinuse")
    s = d / "s.jsonl"
    rig = _session(s)
    res = solving.solve(read_session(s), method="ml", kinematics="estimate", level="full",
                             in_sample=True)
    cal = res.calibration
    return d, s, rig, cal, res


def test_the_estimate_finds_the_controller_frame_and_reports_the_arm(solved) -> None:
    _, _, rig, cal, res = solved
    np.testing.assert_allclose(cal.arm.controller_frame, rig.arm.mount, atol=1e-6)
    j = res.to_json()["arm"]
    assert j["nominal"] == "vs060" and j["source"] == "estimated"
    assert j["named_by"] == "the session header (devices.robot.arm)"
    assert j["level"] == "full" and j["identified"] and j["unidentified"]
    assert all(c["reason"] for c in j["unidentified"])
    # the in-sample errors use the identified arm's robot poses: well below what the
    # controller's poses give with the same X, Y, Z
    A, B, C, _ = read_session(solved[1]).arrays(need_probe=True)
    assert res.errors["e_t_mm"] < 0.2 * cal.errors(A, B, C)["e_t_mm"]


def test_the_calibration_file_keeps_the_arm(solved, tmp_path) -> None:
    """YAML of solve -o, and the json export read back: the identified arm (DH, β, base,
    flange), the controller frame, the seeds and the report, so that robot poses and flange
    commands come out the same."""
    d, s, rig, cal, res = solved
    text = calibration_yaml(cal, res.to_json(), str(s), "ab" * 32)
    f = tmp_path / "cal.yaml"
    f.write_text(text)
    js = tmp_path / "cal.json"
    js.write_text(render_json(read_calibration(f)))
    q = np.array([p.joints_rad for p in read_session(s).poses])
    C = read_session(s).arrays(need_probe=True)[2][:3]
    for back in (read_calibration(f).calibration, read_calibration(js).calibration):
        a, b = cal.arm, back.arm
        assert b is not None and b.nominal.name == "vs060"
        np.testing.assert_allclose(b.arm.dh, a.arm.dh, rtol=0, atol=1e-12)
        np.testing.assert_allclose(b.arm.beta, a.arm.beta, rtol=0, atol=1e-15)
        np.testing.assert_allclose(b.arm.flange, a.arm.flange, atol=1e-12)
        np.testing.assert_allclose(b.controller_frame, a.controller_frame, atol=1e-12)
        np.testing.assert_allclose(b.seeds, a.seeds, atol=1e-12)
        assert {k: b.report[k] for k in ("level", "reason", "tolerances")} == \
            {k: a.report[k] for k in ("level", "reason", "tolerances")}
        assert [c["text"] for c in b.report["identified"]] == \
            [c["text"] for c in a.report["identified"]]
        assert b.report["deviations"].keys() == a.report["deviations"].keys()
        for k, v in a.report["deviations"].items():
            assert b.report["deviations"][k] == pytest.approx(v, abs=1e-12), k
            assert b.report["sd"][k] == pytest.approx(a.report["sd"][k], rel=1e-12)
        np.testing.assert_allclose(back.robot_poses(None, q), cal.robot_poses(None, q),
                                   atol=1e-8)
        np.testing.assert_allclose(back.flange_command(C, seeds=q[0]),
                                   cal.flange_command(C, seeds=q[0]), atol=1e-6)
    doc = yaml.safe_load(text)
    assert doc["arm"]["kinematics"]["format"] == "tmscal-kinematics"
    assert doc["arm"]["kinematics"]["identification"]["method"] == "tracker"


def test_files_without_an_arm_still_load(solved, tmp_path) -> None:
    """A calibration file of before (no arm section) is a calibration without an arm; a
    kinematics file of selfcal identify (sensor and tool, no β) is still an ArmModel; one of a
    plain arm (β, no sensor) is an Arm."""
    d, s, _, _, _ = solved
    plain_res = solving.solve(read_session(s), method="qr36", in_sample=True)
    plain_cal = plain_res.calibration
    f = tmp_path / "old.yaml"
    f.write_text(calibration_yaml(plain_cal, plain_res.to_json(), str(s), "cd" * 32))
    cal = read_calibration(f).calibration
    assert cal.arm is None and "arm" not in yaml.safe_load(f.read_text())
    from tmscal.calib.selfcal.model import UR5E, ArmModel
    old = kinematics_doc(UR5E)
    assert "beta_deg" not in old["joints"][0]
    assert isinstance(parse_kinematics(old).model, ArmModel)
    arm = arm_by_name("ur5e").with_deviations(["beta_2", "d_4"], [0.001, 0.3])
    new = parse_kinematics(kinematics_doc(arm)).model
    assert not isinstance(new, ArmModel)
    np.testing.assert_allclose(new.beta, arm.beta, atol=1e-15)
    np.testing.assert_allclose(new.dh, arm.dh, atol=1e-12)


@pytest.mark.parametrize("change, key", [
    (lambda a: a.update(nominal="ur7"), "arm.nominal"),
    (lambda a: a.update(seeds_deg=[[0.0, 1.0]]), "arm.seeds_deg[0]"),
    (lambda a: a.update(colour="red"), "arm.colour"),
    (lambda a: a["kinematics"].update(bias={"force_n": [0, 0, 0], "torque_nm": [0, 0, 0]}),
     "flange_from_sensor"),
    (lambda a: a.update(nominal="ur5e"), "arm.kinematics"),
    (lambda a: a["kinematics"]["identification"]["tolerances"].update(length_mm="x"),
     "arm.kinematics.identification.tolerances.length_mm"),
    (lambda a: a["kinematics"]["identification"].update(cv={"full": {"e_t_mm": -1}}),
     "arm.kinematics.identification.cv.full.e_t_mm"),
])
def test_a_bad_arm_section_names_its_key(solved, change, key) -> None:
    _, s, _, cal, res = solved
    doc = yaml.safe_load(calibration_yaml(cal, res.to_json(), str(s), "ef" * 32))
    change(doc["arm"])
    with pytest.raises(CalibrationError, match=key.replace("[", r"\[").replace("]", r"\]")):
        parse_calibration(doc, "cal.yaml")


def test_the_daily_check_applies_the_stored_arm(solved, tmp_path) -> None:
    """A second session of the same robot: the stored arm recomputes its robot poses from its
    joints (errors at the first session's level, well below the same calibration applied to
    the controller's poses); a session without joints is a clear error."""
    d, s, _, cal, res = solved
    f = tmp_path / "cal.yaml"
    f.write_text(calibration_yaml(cal, res.to_json(), str(s), "ab" * 32))
    t = tmp_path / "t.jsonl"
    _session(t, seed=40)
    cf = read_calibration(f)
    with_arm = check_calibration(read_session(t), cf)
    assert with_arm["arm"]["frame_change_mm"] < 1e-6
    doc = yaml.safe_load(f.read_text())
    del doc["arm"]
    bare = CalibrationFile(parse_calibration(doc, "bare"), tmp_path / "bare.yaml", doc)
    without = check_calibration(read_session(t), bare)
    assert without["arm"] is None
    assert with_arm["errors"]["e_t_mm"] < 0.2 * without["errors"]["e_t_mm"]
    assert with_arm["errors"]["e_t_mm"] < 2 * res.errors["e_t_mm"] + 0.1
    no_joints = tmp_path / "nj.jsonl"
    _session(no_joints, seed=40, joints=False, n=5)
    with pytest.raises(CalibrationError, match="pose 0 has no joint angles.*robot driver "
                                               "that reports joints"):
        check_calibration(read_session(no_joints), cf)


def _solve(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(main, ["solve", *args])
    return r.exit_code, r.output


def test_clear_errors_without_joints_or_an_arm(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    _session(s, n=8, joints=False)
    code, out = _solve(str(s), "--kinematics", "estimate")
    assert code == 1 and "pose 0 has no joint angles ('joints_rad')" in out
    assert "record the session with a robot driver that reports joints" in out
    u = tmp_path / "u.jsonl"
    _session(u, n=8, recorded_arm=False)
    code, out = _solve(str(u), "--kinematics", "estimate")
    assert code == 1 and "name it with --arm" in out and "vs060" in out
    code, out = _solve(str(u), "--kinematics", "estimate", "--arm", "ur7")
    assert code == 1 and "unknown arm 'ur7'" in out
    code, out = _solve(str(u), "--kinematics", "estimate", "--method", "qr24")
    assert code == 1 and "--method qr24 does not estimate an arm" in out
    code, out = _solve(str(u), "--arm", "vs060")
    assert code == 2 and "only with --kinematics estimate" in out


def _controller_rig(seed: int = 7, n: int = 40):
    """Arrays of a rig whose controller reports its nominal UR5e kinematics in a frame M
    (150 mm from the arm's base) while the true arm is off at 0.3 mm / 0.03° per parameter;
    tracker noise 0.02 mm. Returns (truth_arm, (X, Y, Z), q, A, B, C, rng)."""
    rng = np.random.default_rng(seed)
    arm0 = arm_by_name("ur5e")
    names = est.level_parameters(arm0, "full")
    true = arm0.with_deviations(names, rng.normal(0, 1, len(names))
                                * est.prior_sigmas(names, est.Tolerances(0.3, 0.03)))
    M = make_pose(np.eye(3), [150.0, 0.0, 0.0])
    X = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Y = make_pose(np.eye(3), [0.0, 0.0, 150.0])
    Z = make_pose(random_rotation(rng), rng.uniform(500, 1500, 3))
    q = HOME + rng.uniform(-0.5, 0.5, (n, 6))
    At = M @ base_from_flange(true, q)

    def noisy(P):
        P = P.copy()
        P[:, :3, 3] += rng.normal(0, 0.02, (len(P), 3))
        return P
    B = noisy(np.linalg.inv(Z) @ At @ X)
    C = noisy(np.linalg.inv(Z) @ At @ Y)
    truth_arm = {"name": "ur5e", "errors": "test", "nominal": arm0, "true": true, "mount": M}
    return truth_arm, (X, Y, Z), q, M @ base_from_flange(arm0, q), B, C, rng


def test_the_truth_placement_runs_the_true_arms_controller() -> None:
    """On targets the calibration never saw: the estimated arm's commands put the coil far
    closer than QR36's on the nominal poses, once the truth's controller executes them (IK on
    its nominal arm from the joints it had, the true arm moves); with an arm without errors
    the controller's round trip is the command itself."""
    truth_arm, (X, Y, Z), q, A, B, C, rng = _controller_rig()
    truth = {"X": X, "Y": Y, "Z": Z}
    kin = solve(A, B, C, method="ml", joints=q, arm="ur5e", kinematics="estimate",
                level="full")
    qr = solve(A, B, C, method="qr36", orthonormal=True)
    qt = HOME + rng.uniform(-0.5, 0.5, (20, 6))
    Ct = np.linalg.inv(Z) @ (truth_arm["mount"] @ base_from_flange(truth_arm["true"], qt)) @ Y
    e_kin = coil_placement(kin, Ct, truth, truth_arm, qt)
    e_qr = coil_placement(qr, Ct, truth, truth_arm, qt)
    assert e_kin.mean() < 0.3 * e_qr.mean(), (e_kin.mean(), e_qr.mean())
    perfect = {**truth_arm, "true": truth_arm["nominal"]}
    np.testing.assert_allclose(coil_placement(qr, Ct, truth, perfect, qt),
                               placement_errors(qr.flange_command(Ct), Ct, Y, Z), atol=1e-6)


def test_stream_commands_the_coil_through_the_arm() -> None:
    """CoilToRobotBase with an identified arm is A_cmd · Y (the flange command times the
    coil), not Z · C; a probe pose the arm cannot reach gets none."""
    from tmscal.drivers.base import ToolState, TrackerFrame
    from tmscal.stream import frame_transforms

    truth_arm, (X, Y, Z), q, A, B, C, _ = _controller_rig(n=30)
    cal = solve(A, B, C, method="ml", joints=q, arm="ur5e", kinematics="estimate",
                level="offsets")

    def frame(P):
        return TrackerFrame(frame=0, host_time=0.0, tools={"probe": ToolState(pose=P)})
    got = frame_transforms(frame(C[0]), cal, coil_from="probe")
    np.testing.assert_allclose(got["CoilToRobotBase"], cal.flange_command(C[:1])[0] @ cal.Y,
                               atol=1e-9)
    assert np.linalg.norm(got["CoilToRobotBase"][:3, 3] - (cal.Z @ C[0])[:3, 3]) > 1e-3
    far = C[0].copy()
    far[:3, 3] += np.linalg.inv(cal.Z)[:3, :3] @ np.array([5000.0, 0.0, 0.0])
    gone = frame_transforms(frame(far), cal, coil_from="probe")
    assert "CoilToRobotBase" not in gone and "CoilToTracker" in gone


def test_stream_commands_the_coil_on_the_marker_through_the_arm() -> None:
    """The coil from the marker alone (the probe removed): CoilToRobotBase is A_cmd · Y for
    the coil B · X⁻¹ · Y, the same command as for a probe seen exactly there; a marker pose
    whose coil the arm cannot reach gets none, and the coil in the tracker is still sent."""
    from tmscal.drivers.base import ToolState, TrackerFrame
    from tmscal.stream import frame_transforms

    truth_arm, (X, Y, Z), q, A, B, C, _ = _controller_rig(n=30)
    cal = solve(A, B, C, method="ml", joints=q, arm="ur5e", kinematics="estimate",
                level="offsets")

    def frame(P):
        return TrackerFrame(frame=0, host_time=0.0, tools={"marker": ToolState(pose=P)})
    coil = B[0] @ np.linalg.inv(cal.X) @ cal.Y
    got = frame_transforms(frame(B[0]), cal)
    np.testing.assert_allclose(got["CoilToTracker"], coil, atol=1e-9)
    np.testing.assert_allclose(got["CoilToRobotBase"],
                               cal.flange_command(B[:1], body="marker")[0] @ cal.Y, atol=1e-9)
    np.testing.assert_allclose(got["CoilToRobotBase"],
                               cal.flange_command(coil[None])[0] @ cal.Y, atol=1e-6)
    assert np.linalg.norm(got["CoilToRobotBase"][:3, 3] - (cal.Z @ coil)[:3, 3]) > 1e-3
    far = B[0].copy()
    far[:3, 3] += np.linalg.inv(cal.Z)[:3, :3] @ np.array([5000.0, 0.0, 0.0])
    gone = frame_transforms(frame(far), cal)
    assert "CoilToRobotBase" not in gone and "CoilToTracker" in gone


def test_solve_json_and_text_carry_the_arm(tmp_path) -> None:
    s = tmp_path / "s.jsonl"
    _session(s, n=24)
    code, out = _solve(str(s), "--kinematics", "estimate", "--level", "offsets",
                       "--tolerance-angle", "0.2", "--in-sample", "--json")
    assert code == 0, out
    arm = json.loads(out)["arm"]
    assert arm["level"] == "offsets" and arm["reason"] == "level offsets as asked"
    assert arm["tolerances"] == {"length_mm": 0.5, "angle_deg": 0.2}
    code, out = _solve(str(s), "--kinematics", "estimate", "--level", "offsets",
                       "--in-sample")
    assert code == 0, out
    assert "arm: vs060, named by the session header" in out
    assert "level: offsets (level offsets as asked)" in out
    assert "not identifiable" in out
