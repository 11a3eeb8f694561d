"""`tmscal import`: a laser-tracker campaign (joints + measured target poses) as a session
(tmscal.formats.campaign; docs/kinematics.md, "Laser trackers and 6D probes").

A campaign written here from a known rig (nominal UR10, a target X on the flange, the
tracker at Z) in each supported way of writing the pose — intrinsic Euler angles with decimal
commas, a scalar-first quaternion in metres, three reflectors — imports to a session that QR24
solves back to that X and Z. On the recorded laser-tracker data of a real UR10 (ipa-robot-
accuracy series C, MIT licence, tests/data/ipa-ur10-leica-C/LICENSE.md), the arm estimated
from 100 poses holds out better than the rigid calibration on the nominal arm. Bad input is
one error naming the file, the line and the column."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tmscal.calib.kinematics import arm_by_name
from tmscal.calib.kinematics.model import base_from_flange
from tmscal.cli import main
from tmscal.errors import SessionError
from tmscal.formats.campaign import Columns, _number, frame_from_points, read_campaign
from tmscal.geometry import invert, make_pose
from tmscal.session import read_session
from tmscal.solving.solve import solve

DATA = Path(__file__).resolve().parents[1] / "data" / "ipa-ur10-leica-C"
JOINTS = [f"q{i}" for i in range(1, 7)]
#: the target on the flange (flange ← target) and the tracker (base ← tracker), mm
X_TRUE = make_pose(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix(), [12.0, -30.0, 85.0])
Z_TRUE = make_pose(Rotation.from_rotvec([0.1, 0.05, 2.0]).as_matrix(), [1500.0, -800.0, 300.0])
#: three reflectors on the target, target frame, mm
REFLECTORS = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [10.0, 45.0, 0.0]])


def _truth(n: int = 40, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Joints (n, 6) rad of a UR10 and the target poses B = Z⁻¹ A(q) X (n, 4, 4) mm."""
    rng = np.random.default_rng(seed)
    q = np.array([0.0, -1.2, 1.4, -1.5, -1.5, 0.0]) + rng.uniform(-0.7, 0.7, (n, 6))
    A = base_from_flange(arm_by_name("ur10"), q)
    return q, np.einsum("ij,njk,kl->nil", invert(Z_TRUE), A, X_TRUE)


def _write(path: Path, header: list[str], rows: list[list[float]], delimiter: str = ",",
           decimal: str = ".") -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f, delimiter=delimiter)
        w.writerow(header)
        for r in rows:
            w.writerow([repr(float(v)).replace(".", decimal) for v in r])
    return path


def _import(csv_path: Path, out: Path, *extra: str) -> str:
    r = CliRunner().invoke(main, ["import", str(csv_path), "-o", str(out), "--arm", "ur10",
                                  "--joints", ",".join(JOINTS), *extra])
    assert r.exit_code == 0, r.output
    return r.output


def _recovered(session_path: Path) -> None:
    res = solve(read_session(session_path), method="qr24", in_sample=True)
    assert res.X is not None and res.Z is not None
    np.testing.assert_allclose(res.X, X_TRUE, atol=1e-6)
    np.testing.assert_allclose(res.Z, Z_TRUE, atol=1e-5)


def test_euler_angles_with_decimal_commas_import_to_the_rig_they_came_from(tmp_path):
    q, B = _truth()
    eul = Rotation.from_matrix(B[:, :3, :3]).as_euler("XYZ", degrees=True)
    rows = [[*q[i], *B[i, :3, 3], *eul[i]] for i in range(len(q))]
    src = _write(tmp_path / "c.csv", [*JOINTS, "x", "y", "z", "rx", "ry", "rz"], rows, ";", ",")
    out = _import(src, tmp_path / "s.jsonl", "--delimiter", ";", "--decimal", ",",
                  "--position", "x,y,z", "--rotation", "rx,ry,rz", "--rotation-kind",
                  "euler:XYZ")
    assert "40 poses" in out and "tmscal solve" in out
    s = read_session(tmp_path / "s.jsonl")
    assert s.header["devices"]["robot"]["arm"] == "ur10" and s.header["bodies"] == ["marker"]
    assert s.header["import"]["rows"] == 40 and len(s.header["import"]["sha256"]) == 64
    np.testing.assert_allclose(s.joints([p.index for p in s.poses]), q)
    _recovered(tmp_path / "s.jsonl")


def test_a_scalar_first_quaternion_in_metres_and_degrees_of_joints(tmp_path):
    q, B = _truth()
    quat = Rotation.from_matrix(B[:, :3, :3]).as_quat()[:, [3, 0, 1, 2]]   # w, x, y, z
    rows = [[*np.degrees(q[i]), *(B[i, :3, 3] / 1000.0), *quat[i]] for i in range(len(q))]
    src = _write(tmp_path / "c.csv", [*JOINTS, "x", "y", "z", "qw", "qx", "qy", "qz"], rows)
    _import(src, tmp_path / "s.jsonl", "--joint-unit", "deg", "--length-unit", "m",
            "--position", "x,y,z", "--rotation", "qw,qx,qy,qz", "--rotation-kind", "quat:wxyz")
    _recovered(tmp_path / "s.jsonl")


def test_three_reflectors_give_a_rigid_target_frame(tmp_path):
    q, B = _truth()
    P = np.einsum("nij,kj->nki", B[:, :3, :3], REFLECTORS) + B[:, None, :3, 3]   # (n, 3, 3)
    cols = [f"p{k}{c}" for k in (1, 2, 3) for c in "xyz"]
    src = _write(tmp_path / "c.csv", [*JOINTS, *cols], [[*q[i], *P[i].ravel()]
                                                        for i in range(len(q))])
    _import(src, tmp_path / "s.jsonl", "--points", ",".join(cols))
    res = solve(read_session(tmp_path / "s.jsonl"), method="qr24", in_sample=True)
    # the frame of the reflectors differs from the target's by a fixed transform, which X takes
    F = frame_from_points(REFLECTORS)
    np.testing.assert_allclose(res.X, X_TRUE @ F, atol=1e-6)
    np.testing.assert_allclose(res.Z, Z_TRUE, atol=1e-5)


def test_the_estimated_arm_holds_out_better_on_a_real_ur10_with_a_laser_tracker(tmp_path):
    """Recorded data of a real arm: 100 training poses, 300 held out."""
    src = DATA / "measurements_random_poses.csv"
    lines = src.read_text().splitlines()
    sub = tmp_path / "c.csv"
    sub.write_text("\n".join(lines[:401]) + "\n")
    out = tmp_path / "s.jsonl"
    r = CliRunner().invoke(main, [
        "import", str(sub), "-o", str(out), "--arm", "ur10", "--delimiter", ";", "--decimal",
        ",", "--joints", "shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,"
        "wrist_2_joint,wrist_3_joint", "--position", "measurement_x,measurement_y,measurement_z",
        "--rotation", "measurement_rx,measurement_ry,measurement_rz"])
    assert r.exit_code == 0, r.output
    s = read_session(out)
    rigid = solve(s, method="ml", train=100)
    est = solve(s, method="ml", kinematics="estimate", train=100)
    assert rigid.n_test == est.n_test == 300
    assert est.errors["e_t_mm"] < 0.9 * rigid.errors["e_t_mm"], (est.errors, rigid.errors)


@pytest.mark.parametrize("edit, said", [
    (lambda h, r: (h[:-1], r), "line 1: no column 'rz'"),
    (lambda h, r: (h, [r[0], [*r[1][:7], "abc", *r[1][8:]], *r[2:]]), "line 3: column 'y'"),
    (lambda h, r: (h, [r[0], r[1], [*r[2][:9], "nan", *r[2][10:]], *r[3:]]),
     "line 4: column 'rx': 'nan' is not a finite number"),
    (lambda h, r: (h, [r[0], r[1][:5]]), "line 3: column 'q6': missing"),
    (lambda h, r: (h, r[:2]), "2 rows of data"),
])
def test_bad_rows_name_the_file_the_line_and_the_column(tmp_path, edit, said):
    q, B = _truth(5)
    eul = Rotation.from_matrix(B[:, :3, :3]).as_euler("XYZ", degrees=True)
    header = [*JOINTS, "x", "y", "z", "rx", "ry", "rz"]
    rows = [[repr(float(v)) for v in [*q[i], *B[i, :3, 3], *eul[i]]] for i in range(5)]
    header, rows = edit(header, rows)
    src = tmp_path / "c.csv"
    src.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    cols = Columns(joints=tuple(JOINTS), position=("x", "y", "z"), rotation=("rx", "ry", "rz"))
    with pytest.raises(SessionError) as e:
        read_campaign(src, cols)
    assert str(e.value).startswith(str(src)) and said in str(e.value), str(e.value)


def test_a_row_of_another_arm_and_bad_column_choices_are_refused(tmp_path):
    q, B = _truth(5)
    eul = Rotation.from_matrix(B[:, :3, :3]).as_euler("XYZ", degrees=True)
    src = _write(tmp_path / "c.csv", [*JOINTS, "x", "y", "z", "rx", "ry", "rz"],
                 [[*q[i], *B[i, :3, 3], *eul[i]] for i in range(5)])
    r = CliRunner().invoke(main, ["import", str(src), "-o", str(tmp_path / "s.jsonl"), "--arm",
                                  "fr3", "--joints", ",".join(JOINTS), "--position", "x,y,z",
                                  "--rotation", "rx,ry,rz"])
    assert r.exit_code != 0 and "6 joint columns; arm fr3 has 7 joints" in r.output
    assert not (tmp_path / "s.jsonl").exists()
    for kw, said in (({"points": ("x",) * 9}, "not both"),
                     ({}, "not both and not neither"),
                     ({"position": ("x", "y", "z"), "rotation": ("rx", "ry")}, "takes 3"),
                     ({"position": ("x", "y", "z"), "rotation": ("rx", "ry", "rz"),
                       "rotation_kind": "euler:XyZ"}, "rotation_kind must be"),
                     ({"position": ("q1", "y", "z"), "rotation": ("rx", "ry", "rz")},
                      "named twice: q1")):
        base = {"position": ("x", "y", "z"), "rotation": ("rx", "ry", "rz")} \
            if "points" in kw else {}
        with pytest.raises(SessionError, match=said):
            Columns(joints=tuple(JOINTS), **{**base, **kw})


def test_reflectors_on_one_line_or_at_one_place_give_no_frame():
    with pytest.raises(ValueError, match="on one line"):
        frame_from_points([[0, 0, 0], [50, 0, 0], [100, 0, 0]])
    with pytest.raises(ValueError, match="at one place"):
        frame_from_points([[0, 0, 0], [0.2, 0, 0], [0, 40, 0]])


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e6, 1e6, allow_nan=False), st.sampled_from([".", ","]))
def test_a_number_reads_back_in_either_decimal_mark(x, mark):
    text = repr(x).replace(".", mark) if mark == "," else repr(x)
    assert _number(text, mark, "here") == pytest.approx(x, rel=1e-15, abs=0.0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=9, max_size=9))
def test_three_points_give_a_proper_frame_at_the_first_or_a_clear_refusal(v):
    p = np.array(v).reshape(3, 3)
    try:
        F = frame_from_points(p)
    except ValueError as e:
        assert "one line" in str(e) or "one place" in str(e)
        return
    R = F[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_array_equal(F[:3, 3], p[0])
    x_dir = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
    np.testing.assert_allclose(R[:, 0], x_dir, atol=1e-9)
    assert abs(R[:, 2] @ (p[2] - p[0])) < 1e-6 * max(1.0, np.linalg.norm(p[2] - p[0]))
