"""Any serial arm (docs/kinematics.md, "Arm files"): a URDF chain and a tmscal arm file give the
registry's forward kinematics (1e-9 mm) for the arms both describe; a URDF with a prismatic
joint and one with a coupled (mimic) joint against a URDF evaluated independently here; joint
signs and couplings (FANUC's J2/J3) in an arm file; the shipped arm files; the definition a
session or a calibration keeps; the Jacobians of the new joint kinds against finite
differences; bad input as one clear error naming the file and the element or key.

Poses 4×4 mm, joints rad (mm for a prismatic one).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from tmscal.calib.kinematics import ARMS, Arm, arm_by_name, base_from_flange
from tmscal.calib.kinematics.jacobian import deviation_twists, joint_jacobian
from tmscal.calib.kinematics.model import pose_from_rpy
from tmscal.errors import CalibrationError, ConfigError
from tmscal.formats.armdef import (
    arm_from_record,
    registry_arm_yaml,
    resolve_arm,
    shipped_arm_names,
    shipped_arm_text,
)
from tmscal.formats.kinfile import kinematics_yaml, parse_kinematics, read_kinematics
from tmscal.formats.urdf import parse_urdf, read_urdf
from tmscal.session import Session

H = math.pi / 2
RNG = np.random.default_rng(20261204)

# --- an independent URDF evaluator (the URDF specification's semantics, nothing of tmscal) ----


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), \
        math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def urdf_fk(joints: list[dict], q: dict[str, float]) -> np.ndarray:
    """base ← flange (mm) of a chain of joint dicts {name, type, xyz (m), rpy, axis, mimic:
    (joint, multiplier, offset) or None} at joint values q (rad, or m for prismatic)."""
    T = np.eye(4)
    for j in joints:
        O = np.eye(4)
        O[:3, :3] = _rpy(*j["rpy"])
        O[:3, 3] = np.asarray(j["xyz"]) * 1000.0
        T = T @ O
        if j["type"] == "fixed":
            continue
        v = q[j["name"]] if j.get("mimic") is None else \
            j["mimic"][1] * q[j["mimic"][0]] + j["mimic"][2]
        u = np.asarray(j["axis"], dtype=float)
        u = u / np.linalg.norm(u)
        M = np.eye(4)
        if j["type"] == "prismatic":
            M[:3, 3] = u * v * 1000.0
        else:
            K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
            M[:3, :3] = np.eye(3) + math.sin(v) * K + (1 - math.cos(v)) * K @ K
        T = T @ M
    return T


def urdf_text(joints: list[dict], name: str = "test_arm", base: str = "base_link",
              flange: str = "tool0", extra: str = "") -> str:
    """A URDF of the chain ``joints`` from ``base`` to ``flange``."""
    links = [base] + [f"l{i}" for i in range(len(joints) - 1)] + [flange]
    out = [f'<?xml version="1.0"?>\n<robot name="{name}">']
    out += [f'  <link name="{ln}"/>' for ln in links]
    for i, j in enumerate(joints):
        lim = f'<limit lower="{j.get("lo", -3)}" upper="{j.get("hi", 3)}"/>' \
            if j["type"] in ("revolute", "prismatic") else ""
        mim = "" if j.get("mimic") is None else \
            f'<mimic joint="{j["mimic"][0]}" multiplier="{j["mimic"][1]!r}" ' \
            f'offset="{j["mimic"][2]!r}"/>'
        out.append(
            f'  <joint name="{j["name"]}" type="{j["type"]}"><parent link="{links[i]}"/>'
            f'<child link="{links[i + 1]}"/><origin xyz="{" ".join(map(repr, j["xyz"]))}" '
            f'rpy="{" ".join(map(repr, j["rpy"]))}"/><axis xyz="{" ".join(map(repr, j["axis"]))}"/>'
            f"{lim}{mim}</joint>")
    out.append(extra + "</robot>")
    return "\n".join(out)


# --- the arms both describe ----------------------------------------------------------------

#: UR5e as a URDF whose joint origins are UR's published DH rows (Tz(d) Tx(a) Rx(α) of the row
#: before), written out by hand here
UR5E = [
    {"name": "shoulder_pan", "type": "revolute", "xyz": [0, 0, 0.1625], "rpy": [0, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "shoulder_lift", "type": "revolute", "xyz": [0, 0, 0], "rpy": [H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "elbow", "type": "revolute", "xyz": [-0.425, 0, 0], "rpy": [0, 0, 0],
     "axis": [0, 0, 1], "lo": -3.14159, "hi": 3.14159},
    {"name": "wrist_1", "type": "revolute", "xyz": [-0.3922, 0, 0.1333], "rpy": [0, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "wrist_2", "type": "revolute", "xyz": [0, -0.0997, 0], "rpy": [H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "wrist_3", "type": "revolute", "xyz": [0, 0.0996, 0], "rpy": [-H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "flange", "type": "fixed", "xyz": [0, 0, 0], "rpy": [0, 0, 0], "axis": [1, 0, 0]},
]
for _j in UR5E:   # UR's ranges: ±360°, the elbow ±180° (as the registry has them)
    _j.setdefault("lo", -2 * math.pi)
    _j.setdefault("hi", 2 * math.pi)

#: Franka's arm as franka_description writes it (panda_link0 … panda_link8, Craig's DH)
FRANKA = [
    {"name": "j1", "type": "revolute", "xyz": [0, 0, 0.333], "rpy": [0, 0, 0], "axis": [0, 0, 1]},
    {"name": "j2", "type": "revolute", "xyz": [0, 0, 0], "rpy": [-H, 0, 0], "axis": [0, 0, 1]},
    {"name": "j3", "type": "revolute", "xyz": [0, -0.316, 0], "rpy": [H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "j4", "type": "revolute", "xyz": [0.0825, 0, 0], "rpy": [H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "j5", "type": "revolute", "xyz": [-0.0825, 0.384, 0], "rpy": [-H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "j6", "type": "revolute", "xyz": [0, 0, 0], "rpy": [H, 0, 0], "axis": [0, 0, 1]},
    {"name": "j7", "type": "revolute", "xyz": [0.088, 0, 0], "rpy": [H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "j8", "type": "fixed", "xyz": [0, 0, 0.107], "rpy": [0, 0, 0], "axis": [1, 0, 0]},
]

UR5E_ARM_FILE = """\
format: tmscal-kinematics
version: 1
arm: my_ur5e
convention: standard
joints:
  - {theta_offset_deg: 0, d_mm: 162.5, a_mm: 0,      alpha_deg: 90,  min_deg: -360, max_deg: 360}
  - {theta_offset_deg: 0, d_mm: 0,     a_mm: -425,   alpha_deg: 0,   min_deg: -360, max_deg: 360}
  - {theta_offset_deg: 0, d_mm: 0,     a_mm: -392.2, alpha_deg: 0,   min_deg: -180, max_deg: 180}
  - {theta_offset_deg: 0, d_mm: 133.3, a_mm: 0,      alpha_deg: 90,  min_deg: -360, max_deg: 360}
  - {theta_offset_deg: 0, d_mm: 99.7,  a_mm: 0,      alpha_deg: -90, min_deg: -360, max_deg: 360}
  - {theta_offset_deg: 0, d_mm: 99.6,  a_mm: 0,      alpha_deg: 0,   min_deg: -360, max_deg: 360}
"""


def _q(arm: Arm, m: int = 200) -> np.ndarray:
    lim = arm.joint_limits_rad
    return RNG.uniform(lim[:, 0], lim[:, 1], (m, arm.n_joints))


def test_urdf_and_arm_file_give_the_registry_forward_kinematics(tmp_path: Path) -> None:
    for joints, reg, base, flange in ((UR5E, "ur5e", "base_link", "tool0"),
                                      (FRANKA, "fr3", "panda_link0", "panda_link8")):
        p = tmp_path / f"{reg}.urdf"
        p.write_text(urdf_text(joints, base=base, flange=flange))
        arm = read_urdf(p, base, flange)
        ref = arm_by_name(reg)
        q = _q(ref)
        assert np.abs(base_from_flange(arm, q) - base_from_flange(ref, q)).max() < 1e-9
        assert arm.n_joints == ref.n_joints
    f = tmp_path / "ur5e.yaml"
    f.write_text(UR5E_ARM_FILE)
    arm = read_kinematics(f).model
    ref = arm_by_name("ur5e")
    q = _q(ref)
    assert np.abs(base_from_flange(arm, q) - base_from_flange(ref, q)).max() < 1e-9
    assert np.allclose(arm.joint_limits_rad, ref.joint_limits_rad, atol=1e-12)


def test_shipped_registry_arm_files_are_the_registry() -> None:
    names = shipped_arm_names()
    for name, spec in ARMS.items():
        assert name in names
        text = shipped_arm_text(name)
        assert text == registry_arm_yaml(name), f"{name}: run python -m tmscal.formats.armdef"
        d = resolve_arm(name)
        assert d.kind == "registry" and d.arm is spec.arm   # a registry name is the registry's
        arm = parse_kinematics(yaml.safe_load(text), name).model
        q = _q(spec.arm, 50)
        assert np.abs(base_from_flange(arm, q) - base_from_flange(spec.arm, q)).max() < 1e-9
        doc = yaml.safe_load(text)
        assert doc["description"]["source"] == spec.source
        assert np.allclose(np.radians(doc["mock"]["home_deg"]), spec.home_q, atol=1e-12)


@pytest.mark.parametrize("name", ["xarm6", "xarm7", "kuka_lbr_iiwa7", "kuka_lbr_iiwa14",
                                  "kinova_gen3", "doosan_m1013"])
def test_the_new_arms_resolve_by_name_and_cite_their_source(name: str) -> None:
    d = resolve_arm(name)
    assert d.kind == "arm-file" and d.arm.name == name and d.sha256
    doc = yaml.safe_load(d.content)
    assert len(doc["description"]["source"]) > 40
    assert d.arm.n_joints == (6 if name in ("xarm6", "doosan_m1013") else 7)


def test_the_xarm_tables_reach_the_vendors_zero_pose() -> None:
    """UFACTORY gives the xArm 6's standard DH table beside the modified one; both put the
    flange at the same place for every joint vector (the flange frames differ)."""
    std = Arm(name="xarm6_std", dh=np.array([
        [0.0, 267.0, 0.0, -H], [-1.3849179, 0.0, 289.48661454374707, 0.0],
        [1.3849179, 0.0, 77.5, -H], [0.0, 342.5, 0.0, H], [0.0, 0.0, 76.0, -H],
        [0.0, 97.0, 0.0, 0.0]]))
    mod = resolve_arm("xarm6").arm
    q = _q(mod, 100)
    d = base_from_flange(mod, q)[:, :3, 3] - base_from_flange(std, q)[:, :3, 3]
    assert np.abs(d).max() < 1e-5      # the vendor's offsets are given to 1e-7 rad


# --- prismatic and coupled joints ----------------------------------------------------------

PRISMATIC = [
    {"name": "rail", "type": "prismatic", "xyz": [0.1, 0.2, 0.05], "rpy": [0.1, -0.2, 0.3],
     "axis": [1, 0.5, 0], "lo": -0.5, "hi": 0.5},
    {"name": "turn", "type": "revolute", "xyz": [0, 0, 0.3], "rpy": [0, 0.4, 0],
     "axis": [0, 0, 1]},
    {"name": "lift", "type": "prismatic", "xyz": [0.2, 0, 0], "rpy": [H, 0, 0],
     "axis": [0, 0, -1], "lo": 0.0, "hi": 0.4},
    {"name": "wrist", "type": "continuous", "xyz": [0, 0.1, 0.1], "rpy": [0, 0, 0],
     "axis": [0.3, 0, 1]},
    {"name": "tool", "type": "fixed", "xyz": [0, 0, 0.12], "rpy": [0.2, 0.1, 0],
     "axis": [1, 0, 0]},
]

#: a palletizer-like arm: the passive joint keeps the flange level, −(q2 + q3) by two mimics is
#: not URDF; one mimic of the shoulder plus an offset
MIMIC = [
    {"name": "base", "type": "revolute", "xyz": [0, 0, 0.4], "rpy": [0, 0, 0], "axis": [0, 0, 1]},
    {"name": "shoulder", "type": "revolute", "xyz": [0.1, 0, 0.2], "rpy": [H, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "elbow", "type": "revolute", "xyz": [0.6, 0, 0], "rpy": [0, 0, 0],
     "axis": [0, 0, 1]},
    {"name": "passive", "type": "revolute", "xyz": [0.5, 0, 0], "rpy": [0, 0, 0],
     "axis": [0, 0, 1], "mimic": ("shoulder", -1.0, 0.25)},
    {"name": "flange", "type": "fixed", "xyz": [0.1, 0, 0], "rpy": [0, H, 0], "axis": [1, 0, 0]},
]


def _compare_urdf(joints: list[dict], arm: Arm, m: int = 100) -> float:
    moving = [j for j in joints if j["type"] != "fixed" and j.get("mimic") is None]
    q = _q(arm, m)
    worst = 0.0
    for row in q:
        vals = {j["name"]: (v / 1000.0 if j["type"] == "prismatic" else v)
                for j, v in zip(moving, row, strict=True)}
        worst = max(worst, float(np.abs(urdf_fk(joints, vals) -
                                        base_from_flange(arm, row)).max()))
    return worst


def test_a_urdf_with_prismatic_joints() -> None:
    arm = parse_urdf(urdf_text(PRISMATIC), "prismatic.urdf")
    assert arm.types == ("prismatic", "revolute", "prismatic", "revolute")
    assert np.allclose(arm.joint_limits_rad[0], [-500.0, 500.0])      # mm
    assert np.allclose(arm.joint_limits_rad[3], [-2 * math.pi, 2 * math.pi])
    assert _compare_urdf(PRISMATIC, arm) < 1e-9


def test_a_urdf_with_a_coupled_joint() -> None:
    arm = parse_urdf(urdf_text(MIMIC), "mimic.urdf")
    assert (arm.n_rows, arm.n_joints) == (4, 3)
    assert arm.joint_map[3].tolist() == [0.0, -1.0, 0.0]
    assert _compare_urdf(MIMIC, arm) < 1e-9


def test_signs_and_a_fanuc_coupling_in_an_arm_file(tmp_path: Path) -> None:
    """θ3 = q3 − q2 (FANUC reports J3 against the horizon) and a reversed J1: the file's arm at
    q equals the plain arm at the DH values M q."""
    doc = yaml.safe_load(UR5E_ARM_FILE)
    doc["joints"][0]["sign"] = -1
    doc["joints"][2]["coupling"] = [{"joint": 2, "factor": -1.0}]
    f = tmp_path / "fanuc_like.yaml"
    f.write_text(yaml.safe_dump(doc))
    arm = read_kinematics(f).model
    plain = arm_by_name("ur5e")
    q = _q(plain)
    x = q.copy()
    x[:, 0] = -q[:, 0]
    x[:, 2] = q[:, 2] - q[:, 1]
    assert np.abs(base_from_flange(arm, q) - base_from_flange(plain, x)).max() < 1e-9
    back = parse_kinematics(yaml.safe_load(kinematics_yaml(arm))).model    # written back
    assert np.array_equal(back.joint_map, arm.joint_map)


def _num_jac(arm: Arm, q: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    T0 = base_from_flange(arm, q)
    cols = []
    for j in range(arm.n_joints):
        dq = np.zeros_like(q)
        dq[j] = eps
        T1 = base_from_flange(arm, q + dq)
        dR = T1[:3, :3] @ T0[:3, :3].T
        w = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / 2
        cols.append(np.concatenate([(T1[:3, 3] - T0[:3, 3]), w]) / eps)
    return np.array(cols).T


def test_jacobians_of_prismatic_coupled_and_rooted_chains() -> None:
    for joints in (PRISMATIC, MIMIC):
        arm = parse_urdf(urdf_text(joints), "x.urdf")
        for q in _q(arm, 5):
            assert np.allclose(joint_jacobian(arm, q)[0], _num_jac(arm, q), atol=1e-4)
        names = [f"{k}_{i}" for i in range(1, arm.n_rows + 1) for k in ("theta0", "d", "a",
                                                                          "alpha")]
        q = _q(arm, 3)
        A, J = deviation_twists(arm, q, names)
        assert np.allclose(A, base_from_flange(arm, q))
        eps = 1e-6
        for c, nm in enumerate(names):
            A1 = base_from_flange(arm.with_deviations([nm], [eps]), q)
            D = np.linalg.solve(A, A1)          # A⁻¹ A' ≈ exp(ξ^ ε)
            xi = np.concatenate([[D[:, 2, 1], D[:, 0, 2], D[:, 1, 0]]], axis=0).T / eps
            assert np.allclose(xi, J[:, :3, c], atol=1e-4), nm
            assert np.allclose(D[:, :3, 3] / eps, J[:, 3:, c], atol=1e-3), nm


# --- the definition a session or a calibration keeps ---------------------------------------

def _session(tmp_path: Path, rec: dict | None, arm_name: str | None = None) -> Session:
    robot: dict = {"driver": "sim"}
    if arm_name:
        robot["arm"] = arm_name
    if rec is not None:
        robot["arm_definition"] = rec
    return Session(header={"devices": {"robot": robot}}, poses=[],
                   path=tmp_path / "s.jsonl")


def test_the_definition_rebuilds_the_arm_without_the_file(tmp_path: Path) -> None:
    from tmscal.solving.kinematics import choose_definition

    p = tmp_path / "mimic.urdf"
    p.write_text(urdf_text(MIMIC))
    d = resolve_arm(str(p))
    rec = d.record()
    p.unlink()                                   # the file is gone
    back = arm_from_record(rec, "s.jsonl: header key 'devices.robot.arm_definition'")
    q = _q(d.arm, 20)
    assert np.array_equal(base_from_flange(back.arm, q), base_from_flange(d.arm, q))
    got, source = choose_definition(_session(tmp_path, rec), None)
    assert got.same_as(d) and "arm_definition" in source
    tampered = dict(rec, content=rec["content"].replace("0.6 0 0", "0.7 0 0"))
    with pytest.raises(CalibrationError, match=r"s\.jsonl: header key 'devices\.robot\."
                       r"arm_definition'\.sha256: does not match"):
        arm_from_record(tampered, "s.jsonl: header key 'devices.robot.arm_definition'")


def test_a_session_recorded_with_another_arm_is_an_error(tmp_path: Path) -> None:
    from tmscal.solving.kinematics import choose_definition

    a = tmp_path / "a.urdf"
    a.write_text(urdf_text(MIMIC))
    b = tmp_path / "b.urdf"
    b.write_text(urdf_text(MIMIC).replace("0.6 0 0", "0.61 0 0"))
    s = _session(tmp_path, resolve_arm(str(a)).record())
    with pytest.raises(CalibrationError) as e:
        choose_definition(s, str(b))
    msg = str(e.value)
    assert "s.jsonl" in msg and "devices.robot.arm_definition" in msg
    assert str(a) in msg and str(b) in msg
    assert choose_definition(s, str(a))[0].same_as(resolve_arm(str(a)))
    # a registry arm the driver reported: another registry arm is an error, a file of as many
    # joints refines it
    r = _session(tmp_path, None, "ur5e")
    with pytest.raises(CalibrationError, match=r"recorded with the registry's ur5e arm.*"
                       r"devices\.robot\.arm'.*ur10e"):
        choose_definition(r, "ur10e")
    u = tmp_path / "ur5e.urdf"
    u.write_text(urdf_text(UR5E))
    got, source = choose_definition(r, str(u))
    assert got.kind == "urdf" and "reported ur5e" in source


def test_solve_with_a_urdf_arm_and_check_without_it(tmp_path: Path) -> None:
    """tmscal solve --kinematics estimate --arm FILE.urdf; the calibration keeps the arm whole
    (arm.nominal_arm), so that --calib checks it with the URDF gone."""
    from tests.unit.test_kinematics_use import _session as sim_session
    from tmscal.cli import main

    s = tmp_path / "s.jsonl"
    sim_session(s, arm="ur5e", n=14, recorded_arm=True)
    u = tmp_path / "robot.urdf"
    u.write_text(urdf_text(UR5E, base="world_base", flange="tcp"))
    out = tmp_path / "cal.yaml"
    r = CliRunner().invoke(main, ["solve", str(s), "--kinematics", "estimate", "--arm", str(u),
                                  "--urdf-base", "world_base", "--urdf-flange", "tcp",
                                  "--level", "offsets", "-o", str(out)])
    assert r.exit_code == 0, r.output
    doc = yaml.safe_load(out.read_text())
    assert doc["arm"]["nominal"] == "test_arm" and "nominal_arm" in doc["arm"]
    u.unlink()
    r = CliRunner().invoke(main, ["solve", str(s), "--calib", str(out)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["solve", str(s), "--kinematics", "estimate", "--arm",
                                  "ur10e"])
    assert r.exit_code == 1 and "recorded with the registry's ur5e arm" in r.output


# --- bad input ----------------------------------------------------------------------------

def _urdf_error(text: str, tmp_path: Path, **kw: str) -> str:
    p = tmp_path / "bad.urdf"
    p.write_text(text)
    with pytest.raises(CalibrationError) as e:
        read_urdf(p, **kw)
    msg = str(e.value)
    assert msg.startswith(str(p)), msg
    return msg


def test_urdf_bad_input_names_the_file_and_the_element(tmp_path: Path) -> None:
    # the chain does not connect the named links
    msg = _urdf_error(urdf_text(UR5E, extra='<link name="other"/>'), tmp_path,
                      base_link="other")
    assert "<link name='tool0'>" in msg and "does not connect" in msg and "'other'" in msg
    # a closed loop: a link with two parents
    loop = urdf_text(UR5E, extra='<joint name="strut" type="fixed"><parent link="base_link"/>'
                     '<child link="l2"/></joint>')
    msg = _urdf_error(loop, tmp_path)
    assert "<joint name='strut'>" in msg and "closed loop" in msg and "'l2'" in msg
    # an unsupported joint type on the chain
    bad = [dict(j) for j in UR5E]
    bad[3] = dict(bad[3], type="planar")
    msg = _urdf_error(urdf_text(bad), tmp_path)
    assert "<joint name='wrist_1'>" in msg and "planar" in msg
    bad[3] = dict(bad[3], type="screw")
    msg = _urdf_error(urdf_text(bad), tmp_path)
    assert "<joint name='wrist_1'>" in msg and "unknown joint type 'screw'" in msg
    # a missing link, a non-finite origin, a missing limit, a mimic off the chain
    msg = _urdf_error(urdf_text(UR5E), tmp_path, flange_link="tool9")
    assert "<link name='tool9'>" in msg and "--urdf-flange" in msg
    nan = urdf_text(UR5E).replace('xyz="0 0 0.1625"', 'xyz="0 0 nan"')
    assert "<joint name='shoulder_pan'>" in _urdf_error(nan, tmp_path)
    nolim = urdf_text(UR5E).replace(f'<limit lower="{-2 * math.pi}" upper="{2 * math.pi}"/>',
                                    "", 1)
    assert "needs <limit" in _urdf_error(nolim, tmp_path)
    off = [dict(j) for j in MIMIC]
    off[3] = dict(off[3], mimic=("gripper", 1.0, 0.0))
    assert "not on the chain" in _urdf_error(urdf_text(off), tmp_path)
    assert "not a readable URDF" in _urdf_error("<robot><link", tmp_path)


def _kin_error(doc: dict, tmp_path: Path) -> str:
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(CalibrationError) as e:
        read_kinematics(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: key '"), msg
    return msg


def test_arm_file_bad_input_names_the_file_and_the_key(tmp_path: Path) -> None:
    doc = yaml.safe_load(UR5E_ARM_FILE)
    missing = yaml.safe_load(UR5E_ARM_FILE)
    del missing["joints"][2]["d_mm"]
    assert "key 'joints[2].d_mm': missing" in _kin_error(missing, tmp_path)
    for bad in (float("nan"), float("inf")):
        d = yaml.safe_load(UR5E_ARM_FILE)
        d["joints"][4]["alpha_deg"] = bad
        assert "key 'joints[4].alpha_deg'" in _kin_error(d, tmp_path)
    d = yaml.safe_load(UR5E_ARM_FILE)
    d["joints"][1]["type"] = "helical"
    assert "key 'joints[1].type': expected revolute or prismatic" in _kin_error(d, tmp_path)
    d = yaml.safe_load(UR5E_ARM_FILE)
    d["joints"][1]["type"] = "prismatic"
    assert "a prismatic joint's limits are min_mm and max_mm" in _kin_error(d, tmp_path)
    d = yaml.safe_load(UR5E_ARM_FILE)
    d["joints"][2]["coupling"] = [{"joint": 9, "factor": 1.0}]
    assert "key 'joints[2].coupling[0].joint'" in _kin_error(d, tmp_path)
    d = yaml.safe_load(UR5E_ARM_FILE)
    d["joints"][0]["sign"] = 2
    assert "key 'joints[0].sign'" in _kin_error(d, tmp_path)
    d = dict(doc, root={"xyz_mm": [0, 0, "x"]})
    assert "key 'root.xyz_mm[2]'" in _kin_error(d, tmp_path)


def test_an_unknown_arm_names_what_is_known() -> None:
    with pytest.raises(ConfigError, match=r"--arm: unknown arm 'ur7'.*ur5e.*xarm6.*URDF"):
        resolve_arm("ur7")
    with pytest.raises(ConfigError, match="--urdf-base and --urdf-flange go with a URDF"):
        resolve_arm("ur5e", urdf_base="base")


def test_pose_from_rpy_is_the_urdf_origin() -> None:
    for _ in range(20):
        rpy = RNG.uniform(-3, 3, 3)
        assert np.allclose(pose_from_rpy(rpy, [0, 0, 0])[:3, :3], _rpy(*rpy), atol=1e-15)


def test_selfcal_identify_takes_an_arm_file(tmp_path: Path) -> None:
    """`selfcal identify --arm FILE` starts from the file's arm: on a UR5e session, the UR5e
    arm file of the docs (the registry's forward kinematics exactly) gives the registry
    name's estimate; a URDF with a passive row is refused naming --arm."""
    from tests.unit.test_kinfile import selfcal_session
    from tmscal.session import read_session
    from tmscal.sim import make_arm
    from tmscal.solving.selfcal import identify_session

    pair = make_arm("ur5e", "all", 3)
    s = tmp_path / "sc.jsonl"
    selfcal_session(s, pair, n=40)
    f = tmp_path / "ur5e.yaml"
    f.write_text(UR5E_ARM_FILE)
    by_name = identify_session(read_session(s), "ur5e")
    by_file = identify_session(read_session(s), str(f))
    assert by_file.name == "my_ur5e"
    names = by_name.model.geometry_names()
    np.testing.assert_allclose(by_file.model.geometry_vector(), by_name.model.geometry_vector(),
                               rtol=0, atol=1e-9, err_msg=str(names))
    p = tmp_path / "mimic.urdf"
    p.write_text(urdf_text(MIMIC))
    with pytest.raises(ConfigError, match=r"--arm: .*mimicking row"):
        identify_session(read_session(s), str(p))
