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
from tmscal.geometry import make_pose, random_rotation

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
    fit = est.fit_kinematics(q, [B, C], chain0, "full", _start(chain0, q, B, C), NOISE, LOOSE)
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
