"""The tracker-based kinematic calibration (tmscal.calib.kinematics): the chain's analytic
parameter twists and joint Jacobian against finite differences, noise-free recovery of every
identifiable combination, the answer's independence of the parameters' order, unidentifiable
directions reported with their reason and left at zero, and level selection by held-out error.

Poses 4×4 mm (A = base_from_flange, B/C = tracker_from_marker/probe), joints rad.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tmscal.calib import solve
from tmscal.calib.kinematics import arm_by_name, base_from_flange
from tmscal.calib.kinematics import estimate as est
from tmscal.calib.kinematics.ik import inverse
from tmscal.calib.kinematics.jacobian import deviation_twists, parallel_joints
from tmscal.geometry import make_pose, matrix_from_rotvec, random_rotation

HOME = np.array([np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
NOISE = {"robot_sigma_mm": 0.05, "robot_sigma_deg": 0.03, "tracker_sigma_mm": 0.025,
         "tracker_sigma_deg": 0.05}
#: a prior so weak that noise-free data decide alone
LOOSE = est.Tolerances(length_mm=1e4, angle_deg=1e3)


def _twist_of(D: np.ndarray) -> np.ndarray:
    """[ω; v] of a (m, 4, 4) element of se(3) (the derivative A⁻¹ dA)."""
    return np.stack([D[:, 2, 1], D[:, 0, 2], D[:, 1, 0], D[:, 0, 3], D[:, 1, 3], D[:, 2, 3]], 1)


@pytest.mark.parametrize("name", ["ur5e", "vs060", "fr3"])
def test_deviation_twists_match_finite_differences(name: str) -> None:
    """Standard (UR, DENSO) and modified (Franka) DH, with Hayati angles and a flange."""
    rng = np.random.default_rng(3)
    nominal = arm_by_name(name)
    n = nominal.n_joints
    arm = replace(nominal, beta=rng.normal(0, 0.01, n),
                  flange=nominal.flange @ make_pose(random_rotation(rng), [1.0, 2.0, 30.0]))
    names = [f"{k}_{i}" for i in range(1, n + 1) for k in ("theta0", "d", "a", "alpha", "beta")]
    q = rng.uniform(-1.0, 1.0, (6, n))
    A, J = deviation_twists(arm, q, names)
    np.testing.assert_allclose(A, base_from_flange(arm, q), atol=1e-9)
    h = 1e-6
    for j, nm in enumerate(names):
        dA = (base_from_flange(arm.with_deviations([nm], [h]), q)
              - base_from_flange(arm.with_deviations([nm], [-h]), q))
        np.testing.assert_allclose(_twist_of(np.linalg.inv(A) @ dA / (2 * h)), J[:, :, j],
                                   atol=2e-6, err_msg=nm)


def test_parallel_joints_of_the_ur5e_are_2_and_3() -> None:
    assert parallel_joints(arm_by_name("ur5e")) == [2, 3]
    assert parallel_joints(arm_by_name("vs060")) == [2]


def _rig(seed: int, n: int, level: str = "full", span: float = 0.6, scale: float = 1.0):
    """A noise-free rig: the UR5e with deviations at ``scale`` × the default tolerance on the
    level's parameters, random X, Y, Z, ``n`` configurations around the home."""
    rng = np.random.default_rng(seed)
    chain0 = arm_by_name("ur5e")
    names = est.level_parameters(chain0, level)
    delta = rng.normal(0, scale, len(names)) * est.prior_sigmas(names, est.Tolerances())
    true = chain0.with_deviations(names, delta)
    X = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Y = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Z = make_pose(random_rotation(rng), rng.uniform(500, 1500, 3))
    q = HOME + rng.uniform(-span, span, (n, 6))
    A = base_from_flange(true, q)
    B = np.linalg.inv(Z) @ A @ X
    C = np.linalg.inv(Z) @ A @ Y
    return chain0, true, names, delta, (X, Y, Z), q, B, C


def _start(chain0, q: np.ndarray, B: np.ndarray, C: np.ndarray):
    s = solve(base_from_flange(chain0, q), B, C, method="qr36")
    return [s.X, s.Y], s.Z


def test_noise_free_recovery_of_every_identifiable_combination() -> None:
    chain0, true, names, delta, (X, Y, Z), q, B, C = _rig(0, 40)
    fit = est.fit_kinematics(q, [B, C], chain0, "full", _start(chain0, q, B, C), NOISE, LOOSE,
                             noise_mode="given")  # noise-free: no noise to estimate
    # the tracker poses are reproduced exactly …
    A = base_from_flange(fit.chain, q)
    np.testing.assert_allclose(np.linalg.inv(fit.Z) @ A @ fit.X, B, atol=1e-6)
    np.testing.assert_allclose(np.linalg.inv(fit.Z) @ A @ fit.Y, C, atol=1e-6)
    # … 18 combinations are identified (26 parameters: θ0, d, a, α per joint and β on the two
    # parallel axes; 2 redundant on those axes, 2 Z absorbs, 4 X and Y absorb) …
    assert len(fit.identified) == 18 and len(fit.unidentified) == 8 and not fit.weak
    # … and each identified combination has the true value (tolerance units)
    tau = est.prior_sigmas(names, LOOSE)
    for c in fit.identified:
        assert c.vector @ (delta / tau) == pytest.approx(c.estimate, rel=1e-6, abs=1e-9)
        shown = np.array([c.terms.get(n, 0.0) for n in names])
        assert np.linalg.norm(shown - c.vector) < 0.25  # the printed terms are its main part


def test_unidentifiable_directions_are_reported_with_their_reason_and_not_estimated() -> None:
    chain0, true, names, delta, _, q, B, C = _rig(1, 30)
    fit = est.fit_kinematics(q, [B, C], chain0, "full", _start(chain0, q, B, C), NOISE)
    reasons = [c.reason for c in fit.unidentified]
    assert sum("moves no flange" in r for r in reasons) == 2        # d_2, d_3, d_4 on parallel axes
    assert sum("absorbed by Z" in r for r in reasons) == 2          # θ0_1, d_1
    assert sum("absorbed by X and Y" in r for r in reasons) == 4    # the last link
    z_terms = {k for c in fit.unidentified if "absorbed by Z" in c.reason for k in c.terms}
    assert z_terms == {"theta0_1", "d_1"}
    for c in fit.unidentified:  # minimum norm: nothing of the estimate lies along them
        assert abs(c.estimate) < 1e-6


def test_two_parameter_orders_give_the_same_predicted_poses() -> None:
    chain0, _, names, _, _, q, B, C = _rig(2, 30)
    start = _start(chain0, q, B, C)
    a = est.fit_kinematics(q, [B, C], chain0, "full", start, NOISE)
    order = list(reversed(names))
    orig = est.level_parameters
    try:
        est.level_parameters = lambda ch, lv: order if lv == "full" else orig(ch, lv)
        b = est.fit_kinematics(q, [B, C], chain0, "full", start, NOISE)
    finally:
        est.level_parameters = orig
    q_new = HOME + np.random.default_rng(9).uniform(-0.6, 0.6, (50, 6))
    np.testing.assert_allclose(base_from_flange(a.chain, q_new) @ a.Y,
                               base_from_flange(b.chain, q_new) @ b.Y, atol=1e-6)
    np.testing.assert_allclose(a.Z, b.Z, atol=1e-6)


def test_auto_level_prefers_full_when_the_arm_is_in_error_and_none_when_it_is_not() -> None:
    rng = np.random.default_rng(5)
    for scale, want in ((1.0, "full"), (0.0, "none")):
        chain0, true, names, delta, (X, Y, Z), q, B, C = _rig(5, 40, scale=scale)
        B = _noisy(B, rng)
        C = _noisy(C, rng)
        res = est.estimate_kinematics(q, [B, C], chain0, _start(chain0, q, B, C), NOISE)
        assert res.fit.level == want, res.reason
        assert set(res.cv) == set(est.LEVELS)


def _noisy(P: np.ndarray, rng: np.random.Generator, mm: float = 0.03) -> np.ndarray:
    out = P.copy()
    out[:, :3, 3] += rng.normal(0, mm, (len(P), 3))
    return out


def test_inverse_kinematics_reaches_the_pose_from_a_nearby_seed() -> None:
    chain = arm_by_name("ur5e")
    rng = np.random.default_rng(4)
    for _ in range(10):
        q = HOME + rng.uniform(-0.5, 0.5, 6)
        T = base_from_flange(chain, q)
        qs = inverse(chain, T, [q + rng.uniform(-0.1, 0.1, 6)])
        assert qs is not None
        np.testing.assert_allclose(base_from_flange(chain, qs), T, atol=1e-6)


def test_unknown_level_and_bad_tolerance_are_calibration_errors() -> None:
    from tmscal.errors import CalibrationError
    with pytest.raises(CalibrationError, match="unknown level 'most'"):
        est.level_parameters(arm_by_name("ur5e"), "most")
    with pytest.raises(CalibrationError, match="length_mm"):
        est.Tolerances(length_mm=0.0)


def _controller_rig(seed: int = 7, n: int = 40):
    """A rig whose controller reports in a frame 150 mm from the arm's base (a work
    coordinate system), with an arm in error and noisy tracker positions."""
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
    B = _noisy(np.linalg.inv(Z) @ At @ X, rng, 0.02)
    C = _noisy(np.linalg.inv(Z) @ At @ Y, rng, 0.02)
    return arm0, true, M, (X, Y, Z), q, M @ base_from_flange(arm0, q), B, C, rng


def test_library_form_commands_the_coil_closer_than_the_nominal_arm() -> None:
    """calib.solve(..., method="ml", joints=q, arm="ur5e", kinematics="estimate"): the
    controller's frame is found, and the flange commands (IK on the identified arm, FK on the
    nominal) put the coil where it is wanted, on joints the calibration never saw."""
    from tmscal.calib.metrics import placement_errors

    arm0, true, M, (X, Y, Z), q, A_rep, B, C, rng = _controller_rig()
    cal = solve(A_rep, B, C, method="ml", joints=q, arm="ur5e", kinematics="estimate")
    np.testing.assert_allclose(cal.arm.controller_frame, M, atol=1e-9)
    assert cal.arm.report["level"] == "full"
    qt = HOME + rng.uniform(-0.5, 0.5, (30, 6))
    Ct = np.linalg.inv(Z) @ (M @ base_from_flange(true, qt)) @ Y  # targets as the tracker sees

    def reached(A_cmd):  # the controller: IK on its nominal model, the true arm moves
        qs = [inverse(arm0, np.linalg.inv(M) @ T, [s]) for T, s in zip(A_cmd, qt, strict=True)]
        return M @ base_from_flange(true, np.array(qs))

    with_arm = placement_errors(cal.flange_command(Ct, seeds=qt), Ct, Y, Z, reached)
    nominal = solve(A_rep, B, C, method="qr36", orthonormal=True)
    without = placement_errors(nominal.flange_command(Ct), Ct, Y, Z, reached)
    assert with_arm.mean() < 0.3 * without.mean()
    # the daily check's robot poses (the identified arm at the joints, controller frame)
    # predict where the tracker sees the marker, to within the tracker's noise
    seen = np.linalg.inv(cal.Z) @ cal.robot_poses(A_rep, q) @ cal.X
    assert np.linalg.norm(seen[:, :3, 3] - B[:, :3, 3], axis=1).max() < 0.15


def test_flange_command_without_an_arm_is_the_placement_rule() -> None:
    _, _, _, _, q, A_rep, B, C, _ = _controller_rig(n=20)
    cal = solve(A_rep, B, C, method="qr36", orthonormal=True)
    np.testing.assert_allclose(cal.flange_command(C[:3]),
                               cal.Z @ C[:3] @ np.linalg.inv(cal.Y), atol=1e-9)
    np.testing.assert_array_equal(cal.robot_poses(A_rep), A_rep)


def test_kinematics_needs_joints_and_the_right_arm() -> None:
    from tmscal.errors import CalibrationError

    _, _, _, _, q, A_rep, B, C, _ = _controller_rig(n=20)
    with pytest.raises(CalibrationError, match="joint angles of every pose"):
        solve(A_rep, B, C, method="ml", arm="ur5e", kinematics="estimate")
    with pytest.raises(CalibrationError, match="not the ur10e nominal forward kinematics"):
        solve(A_rep, B, C, method="ml", joints=q, arm="ur10e", kinematics="estimate")
    with pytest.raises(CalibrationError, match="unknown arm 'ur7'"):
        solve(A_rep, B, C, method="ml", joints=q, arm="ur7", kinematics="estimate")
    with pytest.raises(CalibrationError, match="fixed model"):
        solve(A_rep, B, C, method="ml", joints=q, arm="ur5e", kinematics="estimate",
              distortion="bent")


def test_a_tracker_scale_and_the_arms_size_are_one_direction() -> None:
    """A 0.1 % tracker scale and an arm in error, noise-free: the tracker poses are
    reproduced exactly with the scale estimated alongside, but a tracker scale and a uniform
    scaling of the arm's lengths (with X, Y, Z) are the same direction: one combination fewer
    is identified, and it is reported as absorbed together with the others."""
    rng = np.random.default_rng(11)
    arm0 = arm_by_name("ur5e")
    names = est.level_parameters(arm0, "full")
    true = arm0.with_deviations(names, rng.normal(0, 1, len(names))
                                * est.prior_sigmas(names, est.Tolerances(0.3, 0.03)))
    X = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Y = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Z = make_pose(random_rotation(rng), rng.uniform(500, 1500, 3))
    q = HOME + rng.uniform(-0.6, 0.6, (40, 6))
    At = base_from_flange(true, q)
    B, C = np.linalg.inv(Z) @ At @ X, np.linalg.inv(Z) @ At @ Y
    B[:, :3, 3] *= 1.001
    C[:, :3, 3] *= 1.001
    start = _start(arm0, q, B, C)
    fits = {d: est.fit_kinematics(q, [B, C], arm0, "full", start, NOISE, LOOSE, distortion=d,
                                  noise_mode="given")
            for d in ("none", "scale")}
    assert len(fits["scale"].identified) == len(fits["none"].identified) - 1 == 17
    f = fits["scale"]
    A = base_from_flange(f.chain, q)
    seen = np.linalg.inv(f.Z) @ A @ f.X
    undone = B[:, :3, 3] @ f.G.T
    assert np.abs(seen[:, :3, 3] - undone).max() < 1e-5
    assert any("together" in c.reason for c in f.unidentified)


# --- the noise estimated inside the fit (tmscal.calib.kinematics.noise) ---------------------

def _perturbed(P: np.ndarray, rng: np.random.Generator, rad: float, mm: float) -> np.ndarray:
    """P · exp(ε): a rigid error in P's own frame, rotation vector N(0, rad²), offset N(0, mm²)
    per component."""
    E = np.tile(np.eye(4), (len(P), 1, 1))
    E[:, :3, :3] = matrix_from_rotvec(rng.normal(0, rad, (len(P), 3)))
    E[:, :3, 3] = rng.normal(0, mm, (len(P), 3))
    return P @ E


def _noisy_rig(seed: int, scale: float = 1.0, robot_deg: float = 0.01, robot_mm: float = 0.15,
               n: int = 40):
    """The UR5e with deviations at ``scale`` × the tolerance, a coil 150 mm below the flange,
    the robot's flange error (rotation ``robot_deg`` per axis, offset ``robot_mm``) shared by
    marker and probe, the tracker's at NOISE's level on each (body frame)."""
    rng = np.random.default_rng(seed)
    chain0 = arm_by_name("ur5e")
    names = est.level_parameters(chain0, "full")
    true = chain0.with_deviations(names, rng.normal(0, scale, len(names))
                                  * est.prior_sigmas(names, est.Tolerances()))
    X = make_pose(random_rotation(rng), rng.uniform(-50, 50, 3))
    Y = make_pose(random_rotation(rng), [0.0, 0.0, 150.0] + rng.uniform(-20, 20, 3))
    Z = make_pose(random_rotation(rng), rng.uniform(500, 1500, 3))
    q = HOME + rng.uniform(-0.6, 0.6, (n, 6))
    At = _perturbed(base_from_flange(true, q), rng, np.radians(robot_deg), robot_mm)
    tr = (np.radians(NOISE["tracker_sigma_deg"]), NOISE["tracker_sigma_mm"])
    B = _perturbed(np.linalg.inv(Z) @ At @ X, rng, *tr)
    C = _perturbed(np.linalg.inv(Z) @ At @ Y, rng, *tr)
    return chain0, q, B, C


def test_the_robots_noise_is_estimated_inside_the_fit() -> None:
    """Robot noise at 3× the default translation (0.15 mm) and ⅓ the default rotation (0.01°),
    the defaults given as the start: the estimates land within 25 % (translation; about 100
    effective degrees of freedom) and a factor 2.5 (rotation: 1–25 degrees of freedom, the
    tracker's own 0.05° hides most of it) of the truth on every seed, the tracker's level
    within 25 %, and the report says what was estimated."""
    for seed in range(5):
        chain0, q, B, C = _noisy_rig(seed)
        fit = est.fit_kinematics(q, [B, C], chain0, "full", _start(chain0, q, B, C), NOISE)
        nz = fit.noise
        assert nz["mode"] == "estimate" and nz["estimated"] == ["robot_rot", "robot_trans",
                                                                "tracker"]
        assert 0.15 / 1.25 < nz["robot_sigma_mm"] < 0.15 * 1.25, nz
        assert 0.01 / 2.5 < nz["robot_sigma_deg"] < 0.01 * 2.5, nz
        assert 1 / 1.25 < nz["tracker_factor"] < 1.25, nz
        assert nz["dof"]["robot_trans"] > 50 and 1 <= nz["rounds"] <= est.NOISE_ROUNDS
        assert fit.noise_used["robot_sigma_mm"] == nz["robot_sigma_mm"]


def test_noise_given_is_the_fit_before_the_noise_was_estimated() -> None:
    """noise_mode="given": the figures the estimator gave before issue 20's noise estimate
    (commit 1aab479, the same data), to the last digits; the default estimates instead."""
    chain0, q, B, C = _noisy_rig(0)
    start = _start(chain0, q, B, C)
    fit = est.fit_kinematics(q, [B, C], chain0, "full", start, NOISE, noise_mode="given")
    assert fit.chi2 == pytest.approx(1083.7656031712502, rel=1e-7)
    np.testing.assert_allclose(fit.X[:3, 3], [19.30670212996469, -11.0682891292926,
                                              -36.25224175352074], rtol=1e-7)
    assert fit.delta[2] == pytest.approx(0.2990812137576049, rel=1e-7)
    assert fit.noise["mode"] == "given" and fit.noise_used is NOISE
    res = est.estimate_kinematics(q, [B, C], chain0, start, NOISE, noise_mode="given")
    assert res.fit.level == "full"
    assert res.cv["full"]["e_t_mm"] == pytest.approx(0.5690584936605724, rel=1e-7)
    assert res.fit.aic == pytest.approx(462.28160012332467, rel=1e-7)
    estimated = est.fit_kinematics(q, [B, C], chain0, "full", start, NOISE)
    assert estimated.chi2 != pytest.approx(fit.chi2, rel=1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_prior_rows_do_not_bias_the_noise_estimate(seed: int) -> None:
    """A perfect arm: the noise of the full kinematic fit (26 deviations under their prior)
    matches plain ml's on the same data within 6 %, and the fit without deviations ("none",
    the same model as ml's) matches it to the iterations' tolerance — the prior's
    pseudo-observations are neither data nor ignored."""
    chain0, q, B, C = _noisy_rig(seed, scale=0.0)
    ml = solve(base_from_flange(chain0, q), B, C, method="ml", distortion="none").extra["noise"]
    start = _start(chain0, q, B, C)
    for level, rel in (("none", 1e-3), ("full", 0.06)):
        nz = est.fit_kinematics(q, [B, C], chain0, level, start, NOISE).noise
        for k in ("robot_sigma_mm", "robot_sigma_deg", "tracker_factor"):
            assert nz[k] == pytest.approx(ml[k], rel=rel), (level, k, nz[k], ml[k])


def test_the_level_is_chosen_by_held_out_chi2_with_a_paired_tie_break() -> None:
    """levels.choose_level: the lowest mean held-out χ² wins even against a lower held-out
    e_t; a simpler level within one standard error of the PAIRED per-pose difference wins
    only with the lower AIC; a level that could not be scored is left out."""
    from tmscal.calib.kinematics.levels import choose_level

    rng = np.random.default_rng(0)
    base = rng.normal(0.0, 5.0, 40)  # the pose-to-pose spread every level shares
    e_t = rng.uniform(0.1, 0.3, 40)
    wiggle = 0.01 * np.where(np.arange(40) % 2, 1.0, -1.0)  # paired SE 0.0016 per pose
    held = {"none": (e_t, base + 3.0), "offsets": (e_t - 0.05, base + wiggle + 0.001),
            "full": (e_t, base)}
    best, reason, cv = choose_level(held, {"none": 0.0, "offsets": 5.0, "full": 1.0}, 5)
    assert best == "full" and "lowest" in reason  # offsets is within its paired SE, AIC higher
    assert cv["offsets"]["e_t_mm"] < cv["full"]["e_t_mm"] and cv["full"]["folds"] == 5
    best, reason, _ = choose_level(held, {"none": 0.0, "offsets": 0.5, "full": 1.0}, 5)
    assert best == "offsets" and "the lower AIC decides" in reason
    # none is 3 per pose worse with a paired SE near 0: never within one SE, whatever its AIC
    best, _, cv = choose_level({"none": held["none"], "offsets": None, "full": held["full"]},
                               {"none": -100.0, "full": 1.0}, 5)
    assert best == "full" and cv["offsets"] is None
    assert choose_level({"none": None}, {}, 5)[0] is None
