"""The wrench rows of the kinematic estimator (tmscal.calib.kinematics.wrench): the analytic
Jacobian against central differences, noise-free recovery of the arm, the base tilt, the sensor
rotation, the tool's weight and centre of gravity and the bias, and the posterior SD of the
wrist's orientation with and without the wrench. The wrenches are simulated by the
self-calibration model (tmscal.calib.selfcal.model), an implementation of its own.

Poses 4×4 mm, joints rad, wrenches [N, N·m] in the sensor frame.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tmscal.calib.kinematics import base_from_flange, pose_from_rpy
from tmscal.calib.kinematics import estimate as est
from tmscal.calib.kinematics import solve as ksolve
from tmscal.calib.kinematics.jacobian import deviation_twists
from tmscal.calib.kinematics.wrench import (
    WRENCH_NAMES,
    WrenchData,
    WrenchParams,
    predict_wrench,
    wrench_rows,
)
from tmscal.calib.selfcal.model import G_STANDARD, ArmModel
from tmscal.calib.selfcal.model import wrench as selfcal_wrench
from tmscal.errors import CalibrationError
from tmscal.geometry import make_pose, random_rotation

from .test_kinematics_estimate import HOME, LOOSE, NOISE, _noisy, _rig, _start

TILT = np.array([0.01, -0.02])
MASS, COG = 1.2, np.array([5.0, -3.0, 70.0])
BIAS = np.array([1.0, -2.0, 0.5, 0.05, -0.02, 0.01])


def _sensor(rng: np.random.Generator) -> np.ndarray:
    return make_pose(random_rotation(rng), [0.0, 0.0, 10.0])


def _wrenches(true, q: np.ndarray, F_s: np.ndarray) -> np.ndarray:
    """The gravity wrench at q of the TRUE arm on a tilted base (yaw and position arbitrary:
    gravity cannot see them)."""
    model = ArmModel.from_arm(replace(true, base=pose_from_rpy([*TILT, 0.3], [1.0, 2.0, 3.0])),
                              flange_from_sensor=F_s, tool_mass_kg=MASS, tool_cog_mm=COG,
                              bias=BIAS)
    return selfcal_wrench(model, q)


def test_wrench_rows_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(4)
    chain0, true, names, _, _, q, _, _ = _rig(3, 6)
    data = WrenchData.make(_wrenches(true, q, _sensor(rng)) + rng.normal(0, 0.3, (6, 6)),
                           rng.uniform(0.05, 0.2, (6, 6)), 6)
    p = WrenchParams(TILT, random_rotation(rng), 10.0, COG, BIAS)
    A, Jk = deviation_twists(true, q, names)
    r, Jw, Jd = wrench_rows(p, data, A[:, :3, :3], Jk[:, :3, :])
    h = 1e-6
    for j, nm in enumerate(WRENCH_NAMES):
        e = np.zeros(len(WRENCH_NAMES))
        e[j] = h
        rp, _, _ = wrench_rows(p.step(e), data, A[:, :3, :3], None)
        rm, _, _ = wrench_rows(p.step(-e), data, A[:, :3, :3], None)
        np.testing.assert_allclose((rp - rm) / (2 * h), Jw[:, :, j], atol=1e-5, rtol=1e-6,
                                   err_msg=nm)
    for j, nm in enumerate(names):
        Rp = base_from_flange(true.with_deviations([nm], [h]), q)[:, :3, :3]
        Rm = base_from_flange(true.with_deviations([nm], [-h]), q)[:, :3, :3]
        num = (wrench_rows(p, data, Rp, None)[0] - wrench_rows(p, data, Rm, None)[0]) / (2 * h)
        np.testing.assert_allclose(num, Jd[:, :, j], atol=1e-5, rtol=1e-6, err_msg=nm)


def test_the_model_is_the_self_calibration_model() -> None:
    rng = np.random.default_rng(5)
    _, true, _, _, _, q, _, _ = _rig(4, 8)
    F_s = _sensor(rng)
    p = WrenchParams(TILT, F_s[:3, :3], MASS * G_STANDARD, COG, BIAS)
    np.testing.assert_allclose(predict_wrench(p, base_from_flange(true, q)[:, :3, :3]),
                               _wrenches(true, q, F_s), atol=1e-9)


def test_noise_free_recovery_with_wrench_rows() -> None:
    rng = np.random.default_rng(6)
    chain0, true, names, delta, (X, Y, Z), q, B, C = _rig(0, 40)
    F_s = _sensor(rng)
    data = WrenchData.make(_wrenches(true, q, F_s), None, len(q))
    fit = est.fit_kinematics(q, [B, C], chain0, "full", _start(chain0, q, B, C), NOISE, LOOSE,
                             wrench=data, noise_mode="given")   # noise-free: nothing to estimate
    # tracker poses and wrenches reproduced exactly …
    A = base_from_flange(fit.chain, q)
    np.testing.assert_allclose(np.linalg.inv(fit.Z) @ A @ fit.Y, C, atol=1e-6)
    w = fit.wrench
    np.testing.assert_allclose(predict_wrench(w["params"], A[:, :3, :3]), data.wrench,
                               atol=1e-6)
    # … every identified combination of the arm has its true value …
    assert len(fit.identified) == 18
    tau = est.prior_sigmas(names, LOOSE)
    for c in fit.identified:
        assert c.vector @ (delta / tau) == pytest.approx(c.estimate, rel=1e-6, abs=1e-9)
    # … and the tool, the bias, the tilt and the sensor (up to the last joint's rotation,
    # which the sensor mounting absorbs as X does)
    est_ = w["estimate"]
    assert est_["mg"] == pytest.approx(MASS * G_STANDARD, rel=1e-8)
    np.testing.assert_allclose([est_[f"cog_{k}"] for k in "xyz"], COG, atol=1e-6)
    np.testing.assert_allclose([est_[k] for k in WRENCH_NAMES[9:]], BIAS, atol=1e-8)
    np.testing.assert_allclose([est_["base_roll"], est_["base_pitch"]], TILT, atol=1e-4)
    R_err = w["params"].R_fs.T @ F_s[:3, :3]
    assert np.degrees(np.arccos((np.trace(R_err) - 1) / 2)) < 0.2
    # the sensor's orientation in the robot's base frame is exact up to one turn of the whole
    # arm about the base's z (θ0_1, which Z absorbs and gravity cannot see)
    D = A[:, :3, :3] @ w["params"].R_fs @ np.swapaxes(
        base_from_flange(true, q)[:, :3, :3] @ F_s[:3, :3], 1, 2)
    np.testing.assert_allclose(D, np.broadcast_to(D[0], D.shape), atol=1e-7)
    assert D[0][2, 2] == pytest.approx(1.0, abs=1e-9)


def test_the_wrench_sharpens_the_wrist_and_never_blurs_anything() -> None:
    """Information adds: with the wrench rows no deviation's posterior variance (in units of
    the variance factor) grows, and the wrist's orientation (θ0, α of joints 4–5) shrinks."""
    rng = np.random.default_rng(7)
    chain0, true, names, _, _, q, B, C = _rig(8, 30, span=0.6)
    B, C = _noisy(B, rng), _noisy(C, rng)
    # an averaged wrench (e.g. 0.1 N / 0.005 N·m per sample, 100 samples); at 0.05 N the
    # tracker's lever arms know the wrist's orientation better and the gain is ~1 %
    sigma = np.array([0.01] * 3 + [0.0005] * 3)
    W = _wrenches(true, q, _sensor(rng)) + rng.normal(0, 1, (len(q), 6)) * sigma
    start = _start(chain0, q, B, C)
    # the same noise for both (as given): the information the wrench adds, nothing else
    a = est.fit_kinematics(q, [B, C], chain0, "full", start, NOISE, noise_mode="given")
    b = est.fit_kinematics(q, [B, C], chain0, "full", start, NOISE, noise_mode="given",
                           wrench=WrenchData.make(W, sigma, len(q)))
    k = len(names)
    va = np.diag(a.covariance)[-k:] / a.variance_factor
    vb = np.diag(b.covariance)[-k:] / b.variance_factor
    assert np.all(vb <= va * (1 + 1e-6))
    wrist = [names.index(n) for n in ("alpha_4", "theta0_5", "alpha_5")]
    assert np.all(vb[wrist] < 0.8 * va[wrist]), (va[wrist], vb[wrist])


def test_library_form_reports_the_wrench_rows() -> None:
    rng = np.random.default_rng(8)
    chain0, true, _, _, _, q, B, C = _rig(9, 30)
    F_s = _sensor(rng)
    A = base_from_flange(chain0, q)
    cal = ksolve.solve_with_kinematics(A, B, C, joints=q, arm=chain0, level="full",
                                       wrench=_wrenches(true, q, F_s), wrench_sigma=0.1)
    rep = cal.arm.report["wrench"]
    assert rep["rows"] == 6 * len(q)
    # (the default prior holds the arm's deviations back a little)
    assert rep["estimate"]["mg"] == pytest.approx(MASS * G_STANDARD, rel=1e-4)
    assert rep["tool_mass_kg"] == pytest.approx(MASS, rel=1e-4)
    assert cal.extra["parameters"][-len(est.level_parameters(chain0, "full")) - 1] \
        .startswith("t0_z")


@pytest.mark.parametrize("wrench, sigma, what", [
    (np.zeros((5, 6)), None, "wrench must be"),
    (np.zeros((30, 6)), -1.0, "wrench_sigma must be finite"),
    (np.zeros((30, 6)), np.ones(4), "wrench_sigma must be"),
])
def test_bad_wrench_input_is_a_calibration_error(wrench, sigma, what) -> None:
    chain0, _, _, _, _, q, B, C = _rig(10, 30)
    with pytest.raises(CalibrationError, match=what):
        ksolve.solve_with_kinematics(base_from_flange(chain0, q), B, C, joints=q, arm=chain0,
                                     level="none", wrench=wrench, wrench_sigma=sigma)


def test_poses_that_never_turn_the_wrist_are_refused() -> None:
    chain0, _, _, _, _, _, _, _ = _rig(11, 4)
    q = np.tile(HOME, (12, 1))
    q[:, 0] += np.linspace(0, 1, 12)      # only the base turns: gravity stays put in the flange
    A = base_from_flange(chain0, q)
    with pytest.raises(CalibrationError, match="gravity directions"):
        est.fit_kinematics(q, [A], chain0, "none",
                           ([np.eye(4)], np.eye(4)), NOISE,
                           wrench=WrenchData.make(np.zeros((12, 6)), None, 12))


def test_ml_without_the_kinematics_refuses_a_wrench() -> None:
    from tmscal.calib import solve

    chain0, _, _, _, _, q, B, C = _rig(12, 20)
    with pytest.raises(CalibrationError, match="go with kinematics='estimate'"):
        solve(base_from_flange(chain0, q), B, C, method="ml", wrench=np.zeros((20, 6)))
