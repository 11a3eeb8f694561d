"""Realistic arm errors on the sim rig (``mock.kinematics.errors: realistic``; docs/
kinematics.md, "Realistic arm errors"): every geometric parameter drawn, at the stated sizes;
the controller reports the nominal forward kinematics while the tracker sees the true arm, both
recovered from the session header's ``truth.arm``; the header's arm round-trips and a malformed
one is a SessionError naming the key; ``tmscal simulate --arm``. Poses 4×4 mm, joints rad."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from tests.rigs import write_config
from tmscal.calib.kinematics import ARM_NAMES, forward
from tmscal.cli import main
from tmscal.config import load_config
from tmscal.config.mock import KINEMATIC_ERRORS
from tmscal.errors import SessionError
from tmscal.geometry import invert
from tmscal.mocks.launch import build_sim_rig
from tmscal.poses import eq14_poses
from tmscal.session import make_header, read_session, write_session
from tmscal.sim import TMS_RIG_P0, Noise, SimRig, make_arm, tms_rig_truth
from tmscal.sim.arm import ERROR_PROTOCOLS

#: the stated assumption (docs/kinematics.md): σ_L = 0.0004 × the stated reach (mm), 0.03°
REACH_MM = {"ur5e": 850.0, "ur20": 1750.0, "vs060": 605.0, "fr3": 855.0}
ANGLE_RAD = math.radians(0.03)
#: the parameters of the wrist force-torque model that are not the arm's geometry
NOT_GEOMETRY = ("sensor_roll", "sensor_x", "mg", "cog_x", "cog_z", "f0_x", "t0_z")


def _deviations(pair) -> dict[str, float]:
    """true − nominal per geometric parameter (geometry vector names) and per β_i."""
    names = pair.nominal.geometry_names()
    d = dict(zip(names, pair.true.geometry_vector() - pair.nominal.geometry_vector(),
                 strict=True))
    d.update({f"beta_{i + 1}": b for i, b in enumerate(pair.true.beta - pair.nominal.beta)})
    return d


@pytest.mark.parametrize("arm, parallel", [("ur5e", [2, 3]), ("vs060", [2]), ("fr3", [])])
def test_every_geometric_parameter_is_drawn(arm: str, parallel: list[int]) -> None:
    """Every joint's θ0, d, a, α, the base's and the flange's six, and β of each parallel
    joint carry an error — also those a wrench identification cannot see (lengths, the base
    position and yaw); β of the other joints and the sensor and tool stay nominal."""
    pair = make_arm(arm, "realistic", 11)
    n = pair.nominal.n_joints
    dev = _deviations(pair)
    drawn = [f"{k}_{i}" for i in range(1, n + 1) for k in ("theta0", "d", "a", "alpha")]
    drawn += [f"{p}_{k}" for p in ("base", "flange")
              for k in ("roll", "pitch", "yaw", "x", "y", "z")]
    drawn += [f"beta_{i}" for i in parallel]
    assert set(pair.perturbed) == set(drawn)
    for name in drawn:
        assert dev[name] != 0.0, name
    for i in range(1, n + 1):
        if i not in parallel:
            assert dev[f"beta_{i}"] == 0.0
    assert {"a_2", "d_1", "base_yaw", "base_x", "flange_z"} <= set(pair.perturbed)
    sensor = dict(zip(pair.nominal.parameter_names(),
                      pair.true.vector() - pair.nominal.vector(), strict=True))
    for name in NOT_GEOMETRY:
        assert sensor[name] == pytest.approx(0.0, abs=1e-12), name
    assert pair.errors == "realistic" and pair.base_in_rig


@pytest.mark.parametrize("arm", sorted(REACH_MM))
def test_sizes_are_the_stated_ones(arm: str) -> None:
    """Over 400 draws each parameter's deviation has mean ≈ 0 and standard deviation
    0.0004 × reach (lengths) or 0.03° (angles), within 20 % (the standard error of a standard
    deviation over 400 draws is 3.5 %)."""
    draws = [_deviations(make_arm(arm, "realistic", seed)) for seed in range(400)]
    units = dict(zip(make_arm(arm, "none", 0).nominal.geometry_names(),
                     make_arm(arm, "none", 0).nominal.geometry_units(), strict=True))
    sigma_l = 0.0004 * REACH_MM[arm]
    for name in draws[0]:
        x = np.array([d[name] for d in draws])
        if name.startswith("beta") and not np.any(x):
            continue   # not a parallel joint
        want = sigma_l if units.get(name) == "mm" else ANGLE_RAD
        assert 0.8 * want < x.std() < 1.2 * want, (name, x.std(), want)
        assert abs(x.mean()) < 0.2 * want, (name, x.mean())


def test_larger_arms_larger_errors_and_the_seed_decides() -> None:
    def rms_length(arm: str) -> float:
        return float(np.sqrt(np.mean([v ** 2 for s in range(50)
                                      for k, v in _deviations(make_arm(arm, "realistic", s))
                                      .items() if k.split("_")[0] in ("d", "a")])))
    assert rms_length("ur3e") < rms_length("ur5e") < rms_length("ur10e") < rms_length("ur20")
    a, b = make_arm("ur5e", "realistic", 3), make_arm("ur5e", "realistic", 3)
    np.testing.assert_array_equal(a.true.geometry_vector(), b.true.geometry_vector())
    np.testing.assert_array_equal(a.true.beta, b.true.beta)
    assert not np.array_equal(make_arm("ur5e", "realistic", 4).true.geometry_vector(),
                              a.true.geometry_vector())


def test_config_accepts_realistic_and_lists_the_sim_protocols(tmp_path) -> None:
    assert set(KINEMATIC_ERRORS) == set(ERROR_PROTOCOLS)
    cfg = load_config(write_config(tmp_path, "mock-ur-polaris.yaml", mock={
        "kinematics": {"arm": "ur5e", "errors": "realistic", "seed": 4}}))
    rig = build_sim_rig(cfg)
    assert rig.arm is not None and rig.arm.errors == "realistic"
    np.testing.assert_array_equal(rig.arm.true.geometry_vector(),
                                  make_arm("ur5e", "realistic", 4).true.geometry_vector())
    assert rig.truth.arm is rig.arm   # the truth carries the rig's arm


def _session_of(rig: SimRig, tmp_path, records=()):
    p = tmp_path / "truth.jsonl"
    write_session(p, make_header(["marker", "probe"], truth=rig.truth.as_dict()), records)
    return read_session(p)


@pytest.mark.parametrize("arm", ["ur5e", "vs060"])
def test_controller_reports_nominal_tracker_sees_the_true_arm_of_the_header(tmp_path,
                                                                             arm) -> None:
    """Noise-free: after each move the reported flange is the nominal forward kinematics of
    the joints and the tracker's poses are Z⁻¹ · (the true arm's flange) · X or Y, both from
    the header's truth alone (mount · forward(arm, q)); the two differ by about a millimetre
    (the arm's absolute error)."""
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0,
                 arm=make_arm(arm, "realistic", 2))
    s = _session_of(rig, tmp_path)
    ta, truth = s.truth_arm, s.truth
    assert ta is not None and ta["name"] == arm and ta["errors"] == "realistic"
    assert set(truth) == {"X", "Y", "Z"}
    gaps = []
    for cmd in eq14_poses(TMS_RIG_P0, 12, np.random.default_rng(5)):
        rig.move_flange(cmd)
        q = rig.joints()
        A = rig.reported_flange()
        np.testing.assert_allclose(A, ta["mount"] @ forward(ta["nominal"], q), atol=1e-9)
        assert np.linalg.norm(A[:3, 3] - cmd[:3, 3]) < 1e-6
        true_flange = ta["mount"] @ forward(ta["true"], q)
        for body, W in (("marker", truth["X"]), ("probe", truth["Y"])):
            np.testing.assert_allclose(rig.observe(body),
                                       invert(truth["Z"]) @ true_flange @ W, atol=1e-9)
        gaps.append(np.linalg.norm(true_flange[:3, 3] - A[:3, 3]))
    assert 0.2 < np.median(gaps) < 5.0, gaps


@pytest.mark.parametrize("errors", ["paper", "all", "none"])
def test_the_header_arm_explains_the_older_protocols_too(tmp_path, errors) -> None:
    """For paper / all / none the header's true arm is the one whose flange the tracker sees
    (their base errors tilt the arm against gravity only and do not move it in the rig)."""
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0,
                 arm=make_arm("ur5e", errors, 6))
    ta = _session_of(rig, tmp_path).truth_arm
    assert ta is not None and ta["errors"] == errors
    for cmd in eq14_poses(TMS_RIG_P0, 5, np.random.default_rng(1)):
        rig.move_flange(cmd)
        q = rig.joints()
        np.testing.assert_allclose(rig.true_flange(), ta["mount"] @ forward(ta["true"], q),
                                   atol=1e-9)
        np.testing.assert_allclose(rig.reported_flange(),
                                   ta["mount"] @ forward(ta["nominal"], q), atol=1e-9)


@pytest.mark.parametrize("arm", ARM_NAMES)
def test_header_arm_round_trips_exactly(tmp_path, arm) -> None:
    pair = make_arm(arm, "realistic", 9)
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0, arm=pair)
    ta = _session_of(rig, tmp_path).truth_arm
    assert ta is not None
    nominal, true = pair.geometry()
    for got, want in ((ta["nominal"], nominal), (ta["true"], true)):
        for k in ("dh", "beta", "base", "flange", "joint_limits_rad"):
            np.testing.assert_array_equal(getattr(got, k), getattr(want, k), err_msg=k)
        assert (got.name, got.convention) == (arm, want.convention)
    np.testing.assert_array_equal(ta["mount"], pair.mount)
    assert np.any(ta["true"].beta != 0) == (arm in ("ur3", "ur5", "ur10", "ur3e", "ur5e",
                                                    "ur10e", "ur16e", "ur20", "vs060",
                                                    "cobotta"))


def _header_with_arm() -> dict:
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0,
                 arm=make_arm("ur5e", "realistic", 1))
    return make_header(["marker", "probe"], truth=rig.truth.as_dict())


def _set(d: dict, path: tuple, value) -> None:
    for k in path[:-1]:
        d = d[k]
    if value is _DROP:
        del d[path[-1]]
    else:
        d[path[-1]] = value


_DROP = object()
_A = ("truth", "arm")


@pytest.mark.parametrize("path, value, key", [
    (_A, [1, 2], "truth.arm"),
    ((*_A, "true"), _DROP, "truth.arm.true"),
    ((*_A, "colour"), "red", "truth.arm"),
    ((*_A, "name"), 5, "truth.arm.name"),
    ((*_A, "errors"), "", "truth.arm.errors"),
    ((*_A, "mount"), [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
     "truth.arm.mount"),
    ((*_A, "mount"), None, "truth.arm.mount"),
    ((*_A, "nominal", "dh", 2), [0, 1, 2], "truth.arm.nominal.dh"),
    ((*_A, "nominal", "dh", 0, 1), "162.5", "truth.arm.nominal.dh"),
    ((*_A, "true", "dh", 0, 1), True, "truth.arm.true.dh"),
    ((*_A, "true", "dh", 1, 2), 1e5, "truth.arm.true.dh"),
    ((*_A, "true", "dh"), [], "truth.arm.true.dh"),
    ((*_A, "true", "beta"), [0.0, 0.001], "truth.arm.true.beta"),
    ((*_A, "true", "convention"), "craig", "truth.arm.true.convention"),
    ((*_A, "true", "base"), [[1, 0, 0]], "truth.arm.true.base"),
    ((*_A, "true", "flange", 0, 3), "x", "truth.arm.true.flange"),
    ((*_A, "nominal", "joint_limits_rad", 1), [1.0, -1.0], "truth.arm.nominal.joint_limits_rad"),
    ((*_A, "nominal", "joint_limits_rad"), [[0, 1]] * 5, "truth.arm.nominal.joint_limits_rad"),
    ((*_A, "nominal", "name"), _DROP, "truth.arm.nominal.name"),
    ((*_A, "nominal", "sensor"), 1, "truth.arm.nominal"),
    ((*_A, "true", "dh"), [[0, 1, 2, 3]] * 5, "truth.arm.true"),
])
def test_malformed_truth_arm_is_a_session_error_naming_the_key(tmp_path, path, value,
                                                               key) -> None:
    """Read from a file (the header line written as is) and from an in-memory header
    (``Session.truth_arm``), and refused by the writer: each names the key."""
    h = _header_with_arm()
    _set(h, path, value)
    p = tmp_path / "bad.jsonl"
    p.write_text(json.dumps(h) + "\n")
    with pytest.raises(SessionError, match=f"field '{key}[':. ]"):
        read_session(p)
    with pytest.raises(SessionError, match=f"field '{key}[':. ]"):
        write_session(tmp_path / "w.jsonl", h, [])
    assert not (tmp_path / "w.jsonl").exists()
    good = tmp_path / "good.jsonl"
    write_session(good, _header_with_arm(), [])
    s = read_session(good)
    s.header = h
    with pytest.raises(SessionError, match=f"field '{key}[':. ]"):
        _ = s.truth_arm


def test_sessions_without_an_arm_have_no_truth_arm(tmp_path) -> None:
    rig = SimRig(tms_rig_truth(), noise=Noise.none(), start=TMS_RIG_P0)
    s = _session_of(rig, tmp_path)
    assert s.truth_arm is None and set(s.truth) == {"X", "Y", "Z"}
    assert "arm" not in s.header["truth"]


# --- tmscal simulate --arm ----------------------------------------------------------------

def _simulate(tmp_path, *args: str):
    out = tmp_path / "sim.jsonl"
    r = CliRunner().invoke(main, ["simulate", "-o", str(out), "--poses", "25", "--seed", "2",
                                  "--fiducial-sigma", "0", "--robot-rot-sigma", "0",
                                  "--robot-trans-sigma", "0", *args])
    return r, out


@pytest.mark.parametrize("arm, errors", [("ur5e", None), ("vs060", "paper"), ("fr3", "none")])
def test_simulate_with_an_arm_writes_joints_and_the_true_arm(tmp_path, arm, errors) -> None:
    """Joints on every pose; A the nominal forward kinematics of them; B and C what the true
    arm of the header puts in front of the tracker (noise-free); --arm alone is realistic."""
    extra = [] if errors is None else ["--kinematic-errors", errors]
    r, out = _simulate(tmp_path, "--arm", arm, *extra)
    assert r.exit_code == 0, r.output
    s = read_session(out)
    ta, truth = s.truth_arm, s.truth
    assert ta is not None and ta["name"] == arm and ta["errors"] == (errors or "realistic")
    assert s.header["config"]["simulate"]["arm"] == arm
    assert s.header["config"]["simulate"]["kinematic_errors"] == (errors or "realistic")
    assert s.header["devices"]["robot"]["arm"] == arm
    assert len(s.poses) == 25
    n = ta["nominal"].n_joints
    lim = ta["nominal"].joint_limits_rad
    gaps = []
    for p in s.poses:
        q = np.array(p.joints_rad)
        assert q.shape == (n,) and np.all(q >= lim[:, 0]) and np.all(q <= lim[:, 1])
        np.testing.assert_allclose(p.A, ta["mount"] @ forward(ta["nominal"], q), atol=1e-9)
        np.testing.assert_allclose(p.A[:3, 3], p.commanded[:3, 3], atol=1e-6)
        seen = ta["mount"] @ forward(ta["true"], q)
        np.testing.assert_allclose(p.B, invert(truth["Z"]) @ seen @ truth["X"], atol=1e-6)
        np.testing.assert_allclose(p.C, invert(truth["Z"]) @ seen @ truth["Y"], atol=1e-6)
        gaps.append(np.linalg.norm(seen[:3, 3] - p.A[:3, 3]))
        # the plan is Eq. 14 around the mock's P0
        assert np.linalg.norm(p.commanded[:3, 3] - TMS_RIG_P0[:3, 3]) <= 100 * 3 ** 0.5 + 1e-6
    if errors == "none":
        assert max(gaps) < 1e-6
    else:
        assert np.median(gaps) > 0.2


def test_simulate_random_plan_with_an_arm_spreads_the_joints(tmp_path) -> None:
    r, out = _simulate(tmp_path, "--arm", "ur5e", "--plan", "random")
    assert r.exit_code == 0, r.output
    q = np.array([p.joints_rad for p in read_session(out).poses])
    assert np.ptp(q, axis=0).min() > 1.0   # every joint moves across its range


def test_simulate_without_an_arm_is_unchanged_and_kinematic_errors_need_one(tmp_path) -> None:
    r, out = _simulate(tmp_path)
    assert r.exit_code == 0, r.output
    s = read_session(out)
    assert s.truth_arm is None and all(p.joints_rad is None for p in s.poses)
    assert s.header["config"]["simulate"]["arm"] is None
    r = CliRunner().invoke(main, ["simulate", "-o", str(tmp_path / "x.jsonl"),
                                  "--kinematic-errors", "paper"])
    assert r.exit_code != 0 and "--kinematic-errors" in r.output and "--arm" in r.output
    assert not (tmp_path / "x.jsonl").exists()
    r = CliRunner().invoke(main, ["simulate", "-o", str(tmp_path / "y.jsonl"), "--arm", "ur6"])
    assert r.exit_code != 0 and "ur5e" in r.output


def test_simulate_redraws_what_the_cobotta_cannot_reach(tmp_path) -> None:
    """The COBOTTA reaches only part of the Eq. 14 plan around P0: the unreachable poses are
    re-drawn, so the session still has every pose, each reached."""
    r, out = _simulate(tmp_path, "--arm", "cobotta", "--poses", "60")
    assert r.exit_code == 0, r.output
    assert "re-drawn" in r.output
    s = read_session(out)
    assert len(s.poses) == 60 and all(p.joints_rad is not None for p in s.poses)
