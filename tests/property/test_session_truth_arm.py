"""The simulated rig's arm in a session header (``truth.arm``; docs/session-format.md):
properties of the writer and the reader.

- any arm (either DH convention, 1–7 joints, Hayati β or none, any base and flange) written
  by ``make_header``/``write_session`` reads back exactly as ``Session.truth_arm``;
- an entry of it made non-finite or out of range is refused by the writer, naming the key,
  and nothing is written;
- any JSON value substituted anywhere inside a header's ``truth.arm``: the reader raises
  SessionError (naming ``truth.arm`` and the part changed, when the value is plain JSON) or
  reads a session whose ``truth_arm`` is well formed and holds the value; never another
  exception.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given
from hypothesis import strategies as st

from tests.fuzz import fuzz_settings
from tmscal.calib.kinematics import Arm
from tmscal.errors import SessionError
from tmscal.geometry import make_pose, matrix_from_rotvec
from tmscal.session import make_header, read_session, write_session
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth

_SETTINGS = dict(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                        HealthCheck.filter_too_much,
                                        HealthCheck.function_scoped_fixture])
_DIR = Path(tempfile.mkdtemp(prefix="tmscal-truth-arm-"))
_TRUTH = tms_rig_truth()

_angle = st.floats(-math.pi, math.pi)
_length = st.floats(-2000.0, 2000.0)


@st.composite
def _pose(draw) -> np.ndarray:
    w = np.array(draw(st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)))
    t = draw(st.lists(st.floats(-1000.0, 1000.0), min_size=3, max_size=3))
    return make_pose(matrix_from_rotvec(w), t)


@st.composite
def _arms(draw) -> Arm:
    n = draw(st.integers(1, 7))
    dh = [[draw(_angle), draw(_length), draw(_length), draw(_angle)] for _ in range(n)]
    lim = []
    for _ in range(n):
        a, b = draw(st.floats(-7.0, 7.0)), draw(st.floats(-7.0, 7.0))
        lim.append([min(a, b), max(a, b)])
    beta = draw(st.one_of(st.none(), st.lists(st.floats(-0.1, 0.1), min_size=n, max_size=n)))
    return Arm(name=draw(st.text(max_size=12)), dh=dh, joint_limits_rad=lim,
               convention=draw(st.sampled_from(["standard", "modified"])),
               base=draw(_pose()), flange=draw(_pose()), beta=beta)


def _truth_with(nominal: Arm, true: Arm, mount: np.ndarray) -> dict:
    return {**_TRUTH_XYZ, "arm": {"name": "some arm", "errors": "realistic",
                                  "nominal": nominal.to_dict(), "true": true.to_dict(),
                                  "mount": mount.tolist()}}


_TRUTH_XYZ = {"X": _TRUTH.X.tolist(), "Z": _TRUTH.Z.tolist(), "Y": _TRUTH.Y.tolist()}


def _fresh(name: str) -> Path:
    p = Path(tempfile.mkdtemp(dir=_DIR)) / name
    return p


@fuzz_settings(100, **_SETTINGS)
@given(arm=_arms(), mount=_pose(), data=st.data())
def test_any_arm_round_trips_exactly(arm, mount, data):
    true = arm.with_deviations([f"d_{arm.n_joints}"], [data.draw(st.floats(-1.0, 1.0))])
    p = write_session(_fresh("s.jsonl"), make_header(["marker"],
                                                     truth=_truth_with(arm, true, mount)), [])
    ta = read_session(p).truth_arm
    assert ta is not None and ta["errors"] == "realistic"
    np.testing.assert_array_equal(ta["mount"], mount)
    for got, want in ((ta["nominal"], arm), (ta["true"], true)):
        assert (got.name, got.convention, got.n_joints) == (want.name, want.convention,
                                                             want.n_joints)
        for k in ("dh", "beta", "base", "flange", "joint_limits_rad"):
            np.testing.assert_array_equal(getattr(got, k), getattr(want, k), err_msg=k)


_bad_floats = st.sampled_from([math.nan, math.inf, -math.inf, 1e4, -2e4, 1e300])


@fuzz_settings(100, **_SETTINGS)
@given(arm=_arms(), which=st.sampled_from(["nominal", "true"]), data=st.data())
def test_the_writer_refuses_a_bad_entry_naming_the_key(arm, which, data):
    d = arm.to_dict()
    field = data.draw(st.sampled_from(["dh", "joint_limits_rad", "beta"]))
    n = arm.n_joints
    i = data.draw(st.integers(0, n - 1))
    bad = data.draw(_bad_floats)
    if field == "beta":
        if field not in d or not math.isfinite(bad):
            d["beta"] = [0.0] * n
        d["beta"][i] = bad if not math.isfinite(bad) else 2e3   # beyond ±1000 rad
    elif field == "dh":
        d["dh"][i][data.draw(st.integers(0, 3))] = bad
    else:
        d["joint_limits_rad"][i] = [-bad if math.isfinite(bad) else bad, 2e3]
    truth = _truth_with(arm, arm, np.eye(4))
    truth["arm"][which] = d
    p = _fresh("bad.jsonl")
    try:
        write_session(p, make_header(["marker"], truth=truth), [])
    except SessionError as e:
        assert f"truth.arm.{which}.{field}" in str(e), str(e)
        assert not p.exists()
        return
    raise AssertionError(f"the writer took {field} {bad!r}")


_PAIR = make_arm("ur5e", "realistic", 1)
_RIG = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0, arm=_PAIR)
_HEADER = make_header(["marker", "probe"], truth=_RIG.truth.as_dict())
_LINE = json.dumps(_HEADER, separators=(",", ":"))
_SENTINEL = "__FUZZ_RAW__"
_RAW_VALUES = ["NaN", "Infinity", "1e400", "1" + "0" * 400, "[" * 3000 + "]" * 3000, "1e308",
               "-0.0", "true", "null", "{}", "[]", '""', '"standard"', '"modified"',
               "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]", "[[1,0,0,0],[0,1,0,0],[0,0,1,0],"
               "[0,0,0,1],[0,0,0,1]]", "[0,0,0,0,0,0]", "[[0,0,0,0]]", "[[-1,1]]"]


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))


_ARM_PATHS = [("truth", "arm", *p) for p in _paths(_HEADER["truth"]["arm"])]


def _plain_json(text: str) -> bool:
    """True when ``text`` is JSON a strict reader parses into finite numbers only."""
    def bad(_: str) -> float:
        raise ValueError

    try:
        obj = json.loads(text, parse_constant=bad)
    except (ValueError, RecursionError):
        return False

    def finite(v) -> bool:
        if isinstance(v, float):
            return math.isfinite(v)
        if isinstance(v, list):
            return all(finite(x) for x in v)
        if isinstance(v, dict):
            return all(finite(x) for x in v.values())
        return True
    return finite(obj)


@fuzz_settings(300, **_SETTINGS)
@given(data=st.data())
def test_substituted_values_in_the_truth_arm(data):
    path = data.draw(st.sampled_from(_ARM_PATHS))
    value = data.draw(st.one_of(st.sampled_from(_RAW_VALUES), st.from_type(int).map(str),
                                st.floats(allow_nan=False, allow_infinity=False).map(repr),
                                st.text(max_size=8).map(json.dumps)))
    obj = json.loads(_LINE)
    parent = obj
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = _SENTINEL
    line = json.dumps(obj, separators=(",", ":")).replace(f'"{_SENTINEL}"', value)
    p = _fresh("sub.jsonl")
    p.write_text(line + "\n")
    try:
        s = read_session(p)
    except SessionError as e:
        msg = str(e)
        if _plain_json(value):
            assert "'truth.arm" in msg, msg
            if len(path) > 2:
                part = path[2]
                ok = {"nominal", "true"} if part in ("nominal", "true") else {part}
                assert any(f"truth.arm.{k}" in msg for k in ok), msg
        return
    ta = s.truth_arm
    assert ta is not None and isinstance(ta["nominal"], Arm) and isinstance(ta["true"], Arm)
    assert ta["nominal"].n_joints == ta["true"].n_joints
    assert all(isinstance(ta[k], str) and ta[k] for k in ("name", "errors"))
    assert ta["mount"].shape == (4, 4) and np.isfinite(ta["mount"]).all()
    assert set(s.truth) == {"X", "Y", "Z"}
    got = s.header
    for k in path:
        got = got[k]
    assert got == json.loads(value)
