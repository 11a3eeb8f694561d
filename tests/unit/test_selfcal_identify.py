"""Identifiability and identification (tmscal.calib.selfcal.identify): what the gravity wrench
cannot see is found (and asserted by name), every identifiable parameter is recovered from
noise-free wrenches, noisy fits agree with their covariance, position errors by hand."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tmscal.calib.selfcal.identify import (
    ZERO_REASON,
    error_stats,
    identifiable,
    identify,
    position_errors,
)
from tmscal.calib.selfcal.model import (
    G_STANDARD,
    NOMINAL,
    UR5E,
    VS060,
    ArmModel,
    jacobian,
    perturb,
    pose_from_rpy,
    wrench,
)

#: the paper's wrench noise, ±1 N and ±0.2 N·m uniform: σ = half-width / √3
SIGMA = np.array([1.0, 1.0, 1.0, 0.2, 0.2, 0.2]) / math.sqrt(3.0)


def random_q(model: ArmModel, m: int, rng: np.random.Generator) -> np.ndarray:
    lim = model.joint_limits_rad
    return rng.uniform(lim[:, 0], lim[:, 1], (m, model.n_joints))


def analyse(model: ArmModel, seed: int = 0, m: int = 100):
    q = random_q(model, m, np.random.default_rng(seed))
    return q, identifiable(jacobian(model, q), model.parameter_names())


def test_ur5e_unidentifiable_parameters_are_found_with_their_reasons():
    _, idf = analyse(UR5E)
    reasons = dict(idf.removed)
    # lengths and positions do not enter a gravity wrench
    lengths = [f"{k}_{i}" for i in range(1, 7) for k in ("d", "a")]
    for name in lengths + ["base_x", "base_y", "base_z", "sensor_x", "sensor_y", "sensor_z"]:
        assert reasons[name] == ZERO_REASON, name
    # a rotation about gravity changes nothing: the base yaw, and joint 1's offset on a level
    # base (its axis is vertical)
    assert reasons["base_yaw"] == ZERO_REASON
    assert reasons["theta0_1"] == ZERO_REASON
    # the sensor's rotation about the last joint axis is joint 6's offset: one of them goes
    pair = {"theta0_6", "sensor_yaw"}
    gone = pair & set(reasons)
    assert len(gone) == 1
    (name,) = gone
    assert reasons[name].startswith("dependent") and (pair - gone).pop() in reasons[name]
    # joints 2, 3, 4 are parallel: only the sum of their offsets is seen
    assert len({"theta0_2", "theta0_3", "theta0_4"} & set(idf.kept)) == 1
    for name in ("mg", "cog_x", "cog_y", "cog_z", "f0_x", "t0_z", "base_roll", "base_pitch",
                 "alpha_1", "alpha_5"):
        assert name in idf.kept, name
    assert idf.rank == len(idf.kept) == idf.qr_rank
    assert len(idf.kept) + len(idf.removed) == len(UR5E.parameter_names())
    assert set(idf.kept) | set(reasons) == set(UR5E.parameter_names())
    assert math.isfinite(idf.cond) and idf.cond >= 1.0
    assert "identifiable" in idf.summary() and "base_yaw" in idf.summary()


@pytest.mark.parametrize("name", sorted(NOMINAL))
def test_same_verdict_from_a_central_difference_jacobian(name):
    # the wrench itself decides, not the analytic Jacobian's structure: differentiate
    # wrench() numerically and the step finds the same parameters with the same reasons
    model = NOMINAL[name]
    q, idf = analyse(model, seed=6)
    p = model.vector()
    cols = []
    for j in range(len(p)):
        h = 1e-5 * max(1.0, abs(p[j]))
        up, dn = p.copy(), p.copy()
        up[j] += h
        dn[j] -= h
        cols.append(((wrench(model.with_vector(up), q)
                      - wrench(model.with_vector(dn), q)) / (2 * h)).ravel())
    numeric = identifiable(np.array(cols).T, model.parameter_names())
    assert numeric.kept == idf.kept
    assert numeric.removed == idf.removed


def test_tilted_base_joint1_offset_is_confounded_with_the_tilt():
    # on a tilted base, joint 1's offset is no longer a rotation about gravity but its effect
    # (turning the gravity direction about the base z) is reached by base roll and pitch
    model = replace(UR5E, base=pose_from_rpy([0.1, -0.05, 0.3], [10.0, 20.0, 30.0]))
    _, idf = analyse(model, seed=4)
    assert idf.reason("base_yaw") == ZERO_REASON
    group = {"theta0_1", "base_roll", "base_pitch"}
    gone = group - set(idf.kept)
    assert len(gone) == 1
    assert idf.reason(gone.pop()).startswith("dependent")
    assert idf.rank == idf.qr_rank == len(idf.kept)


def test_vs060_keeps_joint4_offset_and_drops_one_of_the_parallel_pair():
    _, idf = analyse(VS060, seed=1)
    assert "theta0_4" in idf.kept
    assert len({"theta0_2", "theta0_3"} & set(idf.kept)) == 1
    assert idf.rank == idf.qr_rank == len(idf.kept)


def test_mass_and_gravity_separately_are_dependent():
    # split the weight column by the chain rule into m (kg) and g (m/s²): the step must find
    # that only their product is seen
    q, _ = analyse(UR5E)
    J = jacobian(UR5E, q)
    names = UR5E.parameter_names()
    k = names.index("mg")
    m = UR5E.tool_mass_kg
    J2 = np.column_stack([J, J[:, k] * m])            # d/dg = d/d(mg) · m
    J2[:, k] = J[:, k] * G_STANDARD                   # d/dm = d/d(mg) · g
    names2 = names[:k] + ["m"] + names[k + 1:] + ["g"]
    idf = identifiable(J2, names2)
    gone = {"m", "g"} - set(idf.kept)
    assert len(gone) == 1
    assert (({"m", "g"} - gone).pop()) in idf.reason(gone.pop())


def test_identifiable_names_a_constructed_dependence():
    rng = np.random.default_rng(8)
    J = rng.normal(size=(40, 5))
    J[:, 3] = J[:, 0] + 2.0 * J[:, 2]
    J[:, 4] = 0.0
    idf = identifiable(J, ["a", "b", "c", "d", "e"])
    assert idf.reason("e") == ZERO_REASON
    assert idf.rank == idf.qr_rank == 3
    (dep,) = [n for n, r in idf.removed if r.startswith("dependent")]
    assert dep in {"a", "c", "d"}
    for other in {"a", "c", "d"} - {dep}:
        assert other in idf.reason(dep)
    assert "b" not in idf.reason(dep)
    with pytest.raises(ValueError):
        identifiable(J, ["a", "b"])


@pytest.mark.parametrize("name", sorted(NOMINAL))
def test_noise_free_recovery_of_every_identifiable_parameter(name):
    nominal = NOMINAL[name]
    q, idf = analyse(nominal, seed=20)
    rng = np.random.default_rng(21)
    truth = perturb(nominal, rng, idf.kept, length_mm=2.0, angle_deg=1.0)
    # the weight and the bias are off too (perturb moves the lengths and angles)
    p = truth.vector()
    names = nominal.parameter_names()
    for i in idf.kept_index:
        size = {"N": 1.0, "N·m": 0.05}.get(nominal.parameter_units()[i], 0.0)
        p[i] += rng.uniform(-size, size)
    truth = truth.with_vector(p)
    fit = identify(nominal, q, wrench(truth, q), SIGMA, idf)
    assert fit.converged
    k = idf.kept_index
    p_true, p_est, p0 = truth.vector(), fit.model.vector(), nominal.vector()
    assert np.abs(p_true - p0)[k].min() > 0           # every kept parameter was in error
    rel = np.abs(p_est - p_true)[k] / np.abs(p_true - p0)[k]
    assert rel.max() < 1e-8, names[k[np.argmax(rel)]]
    # the parameters not estimated keep the start's values
    rest = np.setdiff1d(np.arange(len(p0)), k)
    np.testing.assert_array_equal(p_est[rest], p0[rest])
    assert fit.parameters == idf.kept
    held_out = random_q(nominal, 200, np.random.default_rng(22))
    assert position_errors(truth, fit.model, held_out, (0, 0, 100)).max() < 1e-6


def test_noisy_fit_agrees_with_its_covariance():
    # seeded: 300 configurations, Gaussian noise at SIGMA; each parameter's error within 4.5
    # of its standard deviations, their RMS near 1, and the reduced χ² within 0.25 of 1 (its SD
    # is √(2/dof) ≈ 0.03)
    rng = np.random.default_rng(30)
    q, idf = analyse(UR5E, seed=31, m=300)
    truth = perturb(UR5E, rng, idf.kept)
    meas = wrench(truth, q) + rng.normal(size=(len(q), 6)) * SIGMA
    fit = identify(UR5E, q, meas, SIGMA, idf)
    assert fit.converged
    z = (fit.model.vector() - truth.vector())[idf.kept_index] / fit.std
    assert np.abs(z).max() < 4.5
    assert 0.5 < np.sqrt(np.mean(z ** 2)) < 1.6       # 22 z-scores: their RMS is ≈ 1 ± 0.15
    assert abs(fit.reduced_chi2 - 1.0) < 0.25
    assert fit.covariance.shape == (len(idf.kept),) * 2
    np.testing.assert_allclose(fit.covariance, fit.covariance.T, atol=1e-15)
    np.testing.assert_allclose(fit.rms, SIGMA, rtol=0.25)


def test_iteration_cap_reports_not_converged():
    q, idf = analyse(UR5E, seed=40)
    truth = perturb(UR5E, np.random.default_rng(41), idf.kept, angle_deg=5.0)
    fit = identify(UR5E, q, wrench(truth, q), SIGMA, idf, max_iter=1)
    assert fit.iterations == 1 and not fit.converged


def test_identify_rejects_bad_input():
    q = np.zeros((3, 6))
    w = np.zeros((3, 6))
    with pytest.raises(ValueError, match="unknown parameter"):
        identify(UR5E, q, w, SIGMA, ["mg", "nope"])
    with pytest.raises(ValueError, match="wrench_meas"):
        identify(UR5E, q, w[:2], SIGMA, ["mg"])
    with pytest.raises(ValueError, match="sigma"):
        identify(UR5E, q, w, [1, 1, 1, 0, 1, 1], ["mg"])
    with pytest.raises(ValueError, match="q must be"):
        identify(UR5E, q[:, :5], w, SIGMA, ["mg"])
    w[1, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        identify(UR5E, q, w, SIGMA, ["mg"])


def test_position_errors_by_hand():
    rng = np.random.default_rng(50)
    q = random_q(UR5E, 20, rng)
    shifted = replace(UR5E, base=pose_from_rpy([0, 0, 0], [1.0, 2.0, 2.0]))
    np.testing.assert_allclose(position_errors(UR5E, shifted, q), 3.0, atol=1e-9)
    # a 1° error of joint 6's offset moves a TCP 100 mm off the flange axis by 2·100·sin(0.5°)
    p = UR5E.vector()
    p[UR5E.parameter_names().index("theta0_6")] += math.radians(1.0)
    e = position_errors(UR5E, UR5E.with_vector(p), q, (100.0, 0.0, 0.0))
    np.testing.assert_allclose(e, 200.0 * math.sin(math.radians(0.5)), atol=1e-9)
    np.testing.assert_allclose(position_errors(UR5E, UR5E.with_vector(p), q, (0, 0, 50.0)),
                               0.0, atol=1e-9)


def test_error_stats():
    s = error_stats([1.0, 2.0, 3.0])
    assert s == {"mean_mm": 2.0, "max_mm": 3.0, "sd_mm": 1.0}
    assert error_stats([4.0])["sd_mm"] == 0.0
    with pytest.raises(ValueError):
        error_stats([])
