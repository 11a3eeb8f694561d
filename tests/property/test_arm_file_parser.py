"""The arm-file and URDF readers (docs/kinematics.md, "Arm files"): properties.

- any arm (either DH convention, 1–8 rows, revolute and prismatic rows, signs, couplings and
  passive mimic rows, any base, root and flange) written as an arm file reads back with the
  same forward kinematics (1e-9 mm) and the same joint map, types and limits;
- any URDF chain (random origins and axes; revolute, continuous, prismatic, fixed and mimic
  joints) reads as an arm whose forward kinematics is that of the URDF, evaluated
  independently (tests/unit/test_arm_files.py), to 1e-9 mm;
- any JSON value substituted anywhere in an arm file, or any text cut or spliced into a URDF:
  the reader raises CalibrationError naming the source, or reads an arm; never another
  exception.
"""

from __future__ import annotations

import math

import numpy as np
import yaml
from hypothesis import assume, given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tests.unit.test_arm_files import UR5E, UR5E_ARM_FILE, urdf_fk, urdf_text
from tmscal.calib.kinematics import Arm, base_from_flange
from tmscal.errors import CalibrationError
from tmscal.formats.kinfile import kinematics_yaml, parse_kinematics
from tmscal.formats.urdf import parse_urdf
from tmscal.geometry import make_pose, matrix_from_rotvec

_angle = st.floats(-math.pi, math.pi)
_length = st.floats(-1000.0, 1000.0)
_pose = st.tuples(st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
                  st.lists(_length, min_size=3, max_size=3)).map(
    lambda rv: make_pose(matrix_from_rotvec(np.array(rv[0])), rv[1]))


@st.composite
def arms(draw: st.DrawFn) -> Arm:
    m = draw(st.integers(1, 8))
    dh = np.array([[draw(_angle), draw(_length), draw(_length), draw(_angle)]
                   for _ in range(m)])
    types = tuple(draw(st.sampled_from(["revolute", "prismatic"])) for _ in range(m))
    passive = [i > 0 and draw(st.booleans()) and draw(st.booleans()) for i in range(m)]
    own = [i for i in range(m) if not passive[i]]
    M = np.zeros((m, len(own)))
    for j, i in enumerate(own):
        M[i, j] = draw(st.sampled_from([1.0, -1.0]))
    for i in range(m):                      # couplings to joints of the same type
        for j, k in enumerate(own):
            if k != i and types[k] == types[i] and (passive[i] or draw(st.booleans())):
                M[i, j] += draw(st.floats(-3.0, 3.0).filter(lambda c: abs(c) > 1e-3))
    for i in range(m):
        if passive[i] and not M[i].any():   # a passive row must follow something
            passive[i] = False
    for j in range(M.shape[1]):
        if not M[:, j].any():
            M[own[j], j] = 1.0
    lim = []
    for i in own:
        lo = draw(st.floats(-300.0, 300.0)) if types[i] == "prismatic" else draw(_angle)
        lim.append([lo, lo + draw(st.floats(0.1, 1.0))])
    try:
        return Arm(name="prop", dh=dh, joint_types=types, joint_map=M,
                   joint_limits_rad=np.array(lim), convention=draw(st.sampled_from(
                       ["standard", "modified"])), base=draw(_pose), root=draw(_pose),
                   flange=draw(_pose))
    except ValueError:                      # a map the model refuses (a mixed-type column)
        return Arm(name="prop", dh=dh)


@fuzz_settings(80)
@given(arms())
def test_any_arm_reads_back_from_its_arm_file(arm: Arm) -> None:
    back = parse_kinematics(yaml.safe_load(kinematics_yaml(arm)), "prop.yaml").model
    q = np.random.default_rng(0).uniform(arm.joint_limits_rad[:, 0], arm.joint_limits_rad[:, 1],
                                         (10, arm.n_joints))
    assert np.abs(base_from_flange(back, q) - base_from_flange(arm, q)).max() < 1e-9
    assert back.types == arm.types and back.n_joints == arm.n_joints
    assert np.allclose(back.joint_limits_rad, arm.joint_limits_rad, rtol=0, atol=1e-12)
    M = np.eye(arm.n_rows) if arm.joint_map is None else arm.joint_map
    B = np.eye(back.n_rows) if back.joint_map is None else back.joint_map
    assert np.array_equal(M, B)


_axis = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(
    lambda v: float(np.linalg.norm(v)) > 0.1)


@st.composite
def chains(draw: st.DrawFn) -> list[dict]:
    n = draw(st.integers(1, 7))
    out: list[dict] = []
    for i in range(n):
        kind = draw(st.sampled_from(["revolute", "continuous", "prismatic", "fixed"]))
        j = {"name": f"j{i}", "type": kind,
             "axis": draw(_axis | st.sampled_from([[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, -1]])),
             "xyz": draw(st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3)),
             "rpy": draw(st.lists(_angle | st.integers(-4, 4).map(lambda k: k * math.pi / 4),
                                  min_size=3, max_size=3)),
             "lo": -1.0, "hi": 1.0}
        same = [k for k in out if k["type"] != "fixed" and k.get("mimic") is None
                and (k["type"] == "prismatic") == (kind == "prismatic")]
        if kind != "fixed" and same and draw(st.booleans()):
            j["mimic"] = (draw(st.sampled_from(same))["name"], draw(st.floats(-2.0, 2.0)),
                          draw(st.floats(-0.3, 0.3)))
        out.append(j)
    if not any(j["type"] != "fixed" and j.get("mimic") is None for j in out):
        out[0] = dict(out[0], type="revolute", mimic=None)
        for j in out[1:]:
            j.pop("mimic", None)
    return out


def _axes_at_zero(joints: list[dict]) -> list[np.ndarray]:
    from tests.unit.test_arm_files import _rpy

    R, out = np.eye(3), []
    for j in joints:
        R = R @ _rpy(*j["rpy"])
        if j["type"] != "fixed":
            out.append(R @ (np.asarray(j["axis"]) / np.linalg.norm(j["axis"])))
    return out


@fuzz_settings(80)
@given(chains(), st.integers(0, 2**31))
def test_any_urdf_chain_has_the_urdf_forward_kinematics(joints: list[dict], seed: int) -> None:
    # nearly parallel consecutive axes (not parallel, a sine below 1e-2) lose digits as DH does
    # (urdf.py): not this property's
    ax = _axes_at_zero(joints)
    assume(all(not 1e-10 < np.linalg.norm(np.cross(u, w)) < 1e-2 for u, w in zip(ax, ax[1:])))
    arm = parse_urdf(urdf_text(joints), "prop.urdf")
    moving = [j for j in joints if j["type"] != "fixed" and j.get("mimic") is None]
    rng = np.random.default_rng(seed)
    for _ in range(5):
        vals = {j["name"]: float(rng.uniform(-1.0, 1.0)) for j in moving}
        q = np.array([vals[j["name"]] * (1000.0 if j["type"] == "prismatic" else 1.0)
                      for j in moving])
        assert np.abs(urdf_fk(joints, vals) - base_from_flange(arm, q)).max() < 1e-9


_json = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) |
                     st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=8),
                     lambda kids: st.lists(kids, max_size=3) |
                     st.dictionaries(st.text(max_size=6), kids, max_size=3), max_leaves=6)


def _paths(v: object, at: tuple = ()) -> list[tuple]:
    out = [at]
    if isinstance(v, dict):
        for k, x in v.items():
            out += _paths(x, at + (k,))
    elif isinstance(v, list):
        for i, x in enumerate(v):
            out += _paths(x, at + (i,))
    return out


_FILE = yaml.safe_load(UR5E_ARM_FILE)
_FILE["joints"][2]["coupling"] = [{"joint": 2, "factor": -1.0}]
_FILE["joints"].append({"type": "prismatic", "theta_offset_deg": 0, "d_mm": 10, "a_mm": 0,
                        "alpha_deg": 0, "min_mm": 0, "max_mm": 100})
_FILE["root"] = {"xyz_mm": [1, 2, 3], "rpy_deg": [0, 0, 90]}
_PATHS = _paths(_FILE)[1:]


@fuzz_settings(300)
@given(st.sampled_from(_PATHS), _json)
def test_any_value_anywhere_is_refused_by_name_or_read(path: tuple, value: object) -> None:
    doc = yaml.safe_load(yaml.safe_dump(_FILE))
    at = doc
    for k in path[:-1]:
        at = at[k]
    at[path[-1]] = value
    try:
        parse_kinematics(doc, "fuzz.yaml")
    except CalibrationError as e:
        assert str(e).startswith("fuzz.yaml")


_URDF = urdf_text(UR5E)


@fuzz_settings(300)
@given(st.integers(0, len(_URDF)), st.integers(0, 40), st.text(max_size=20))
def test_any_spliced_urdf_is_refused_by_name_or_read(at: int, cut: int, text: str) -> None:
    bad = _URDF[:at] + text + _URDF[at + cut:]
    try:
        parse_urdf(bad, "fuzz.urdf")
    except CalibrationError as e:
        assert str(e).startswith("fuzz.urdf")
