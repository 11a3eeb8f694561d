"""The self-calibration arm model (tmscal.calib.selfcal.model): forward kinematics against
hand-derived poses and an independent DH product, the gravity wrench against hand-worked
cases, the analytic Jacobian against central differences, the parameter vector."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tmscal.calib.selfcal.model import (
    G_STANDARD,
    NOMINAL,
    UR5E,
    VS060,
    ArmModel,
    forward,
    jacobian,
    joint_frames,
    perturb,
    pose_from_rpy,
    rpy_from_matrix,
    wrench,
)
from tmscal.geometry import rot_x, rot_y, rot_z


def dh_by_hand(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Rz(θ) Tz(d) Tx(a) Rx(α) as four separate 4×4 matrices multiplied."""
    Rz, Tz, Tx, Rx = np.eye(4), np.eye(4), np.eye(4), np.eye(4)
    Rz[:3, :3] = rot_z(theta)
    Tz[2, 3] = d
    Tx[0, 3] = a
    Rx[:3, :3] = rot_x(alpha)
    return Rz @ Tz @ Tx @ Rx


def mdh_by_hand(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Modified DH (Craig 1989): Rx(α) Tx(a) Rz(θ) Tz(d) as four matrices multiplied."""
    Rz, Tz, Tx, Rx = np.eye(4), np.eye(4), np.eye(4), np.eye(4)
    Rz[:3, :3] = rot_z(theta)
    Tz[2, 3] = d
    Tx[0, 3] = a
    Rx[:3, :3] = rot_x(alpha)
    return Rx @ Tx @ Rz @ Tz


def random_q(model: ArmModel, m: int, rng: np.random.Generator) -> np.ndarray:
    lim = model.joint_limits_rad
    return rng.uniform(lim[:, 0], lim[:, 1], (m, model.n_joints))


def odd_model(base: ArmModel) -> ArmModel:
    """A model with a tilted base, a rotated sensor, an off-axis tool and a bias."""
    return replace(base, base=pose_from_rpy([0.1, -0.05, 0.3], [10.0, 20.0, 30.0]),
                   flange_from_sensor=pose_from_rpy([0.02, 0.03, 0.5], [1.0, 2.0, 40.0]),
                   tool_cog_mm=np.array([5.0, -3.0, 70.0]), tool_mass_kg=2.1,
                   bias=np.array([0.5, -0.3, 1.2, 0.02, -0.01, 0.03]))


def test_ur5e_home_pose_is_the_published_one():
    # all joints 0: x = a2 + a3, y = −(d4 + d6), z = d1 − d5; flange z along −y of the base
    T = forward(UR5E, np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [-425.0 - 392.2, -(133.3 + 99.6), 162.5 - 99.7],
                               atol=1e-9)
    np.testing.assert_allclose(T[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)


def test_vs060_matches_its_joint_origins():
    # q = 0: straight up, J2 at 345, +305, forearm 300 with −10 mm in x, flange 70 above J5
    np.testing.assert_allclose(forward(VS060, np.zeros(6)),
                               [[1, 0, 0, -10.0], [0, 1, 0, 0], [0, 0, 1, 1020.0], [0, 0, 0, 1]],
                               atol=1e-9)
    # J2 +90° about the base y axis: the arm above J2, (−10, 0, 675), turns to (675, 0, 10)
    T = forward(VS060, [0.0, math.pi / 2, 0, 0, 0, 0])
    np.testing.assert_allclose(T[:3, 3], [675.0, 0.0, 345.0 + 10.0], atol=1e-9)
    # J1 +90°: (−10, 0, 1020) turns to (0, −10, 1020)
    np.testing.assert_allclose(forward(VS060, [math.pi / 2, 0, 0, 0, 0, 0])[:3, 3],
                               [0.0, -10.0, 1020.0], atol=1e-9)


@pytest.mark.parametrize("name", sorted(NOMINAL))
def test_forward_is_the_product_of_dh_matrices(name):
    rng = np.random.default_rng(11)
    model = odd_model(NOMINAL[name])
    q = random_q(model, 5, rng)
    got = forward(model, q)
    frames = joint_frames(model, q)
    by_hand = dh_by_hand if model.convention == "standard" else mdh_by_hand
    for k in range(len(q)):
        T = model.base.copy()
        for i, (th0, d, a, al) in enumerate(model.dh):
            T = T @ by_hand(q[k, i] + th0, d, a, al)
            np.testing.assert_allclose(frames[k, i + 1], T, atol=1e-9)
        np.testing.assert_allclose(got[k], T @ model.flange, atol=1e-9)
    assert forward(model, q[0]).shape == (4, 4)


def test_wrench_hand_worked_case():
    # VS060 at q = 0: sensor frame = world orientation; tool 10 mm out along x
    model = replace(VS060, tool_mass_kg=2.0, tool_cog_mm=np.array([10.0, 0.0, 0.0]),
                    bias=np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
    mg = 2.0 * G_STANDARD
    # f = (0, 0, −mg); τ = (0.01 m, 0, 0) × (0, 0, −mg) = (0, 0.01 mg, 0)
    np.testing.assert_allclose(wrench(model, np.zeros(6)),
                               [1.0, 2.0, 3.0 - mg, 0.1, 0.2 + 0.01 * mg, 0.3], atol=1e-12)
    # J5 +90° (about the base y axis): the sensor z axis points along world +x, its x axis
    # along world −z; gravity (0, 0, −mg) reads f_s = (+mg, 0, 0), τ = (0.01, 0, 0) × f_s = 0
    np.testing.assert_allclose(wrench(model, [0, 0, 0, 0, math.pi / 2, 0]),
                               [1.0 + mg, 2.0, 3.0, 0.1, 0.2, 0.3], atol=1e-12)


@pytest.mark.parametrize("name", sorted(NOMINAL))
def test_jacobian_matches_central_differences(name):
    rng = np.random.default_rng(5)
    model = odd_model(NOMINAL[name])
    q = random_q(model, 12, rng)
    J = jacobian(model, q)
    p = model.vector()
    assert J.shape == (6 * len(q), len(p))
    for j in range(len(p)):
        h = 1e-6 * max(1.0, abs(p[j]))
        up, dn = p.copy(), p.copy()
        up[j] += h
        dn[j] -= h
        fd = (wrench(model.with_vector(up), q) - wrench(model.with_vector(dn), q)) / (2 * h)
        np.testing.assert_allclose(J[:, j], fd.ravel(), atol=1e-6 * max(1.0, abs(J).max()),
                                   err_msg=model.parameter_names()[j])


def test_parameter_vector_round_trip_and_names():
    model = odd_model(UR5E)
    p = model.vector()
    names = model.parameter_names()
    assert len(names) == len(set(names)) == len(p) == 4 * 6 + 22 == len(model.parameter_units())
    assert names[:4] == ["theta0_1", "d_1", "a_1", "alpha_1"]
    np.testing.assert_allclose(model.with_vector(p).vector(), p, atol=1e-12)
    np.testing.assert_allclose(p[names.index("mg")], 2.1 * G_STANDARD)
    np.testing.assert_allclose(p[names.index("base_yaw")], 0.3)
    np.testing.assert_allclose(p[names.index("sensor_z")], 40.0)
    np.testing.assert_allclose(p[names.index("t0_z")], 0.03)
    q2 = p.copy()
    q2[names.index("d_2")] += 1.5
    assert model.with_vector(q2).dh[1, 1] == pytest.approx(1.5)
    with pytest.raises(ValueError, match="entries"):
        model.with_vector(p[:-1])


def test_rpy_round_trip_and_gimbal_lock():
    rng = np.random.default_rng(2)
    for _ in range(50):
        rpy = rng.uniform([-math.pi, -1.5, -math.pi], [math.pi, 1.5, math.pi])
        np.testing.assert_allclose(rpy_from_matrix(pose_from_rpy(rpy, [0, 0, 0])), rpy,
                                   atol=1e-10)
    R = rot_z(0.4) @ rot_y(math.pi / 2) @ rot_x(0.1)
    back = pose_from_rpy(rpy_from_matrix(R), [0, 0, 0])[:3, :3]
    np.testing.assert_allclose(back, R, atol=1e-9)


def test_perturb_moves_only_the_named_lengths_and_angles_within_bounds():
    rng = np.random.default_rng(3)
    names = ["d_2", "alpha_3", "base_roll", "mg", "f0_x"]
    p0 = UR5E.vector()
    p1 = perturb(UR5E, rng, names, length_mm=2.0, angle_deg=1.0).vector()
    moved = {UR5E.parameter_names()[i] for i in np.flatnonzero(p1 != p0)}
    assert moved == {"d_2", "alpha_3", "base_roll"}
    diff = np.abs(p1 - p0)
    assert diff.max() <= 2.0
    assert diff[UR5E.parameter_names().index("alpha_3")] <= math.radians(1.0)
    with pytest.raises(ValueError, match="unknown"):
        perturb(UR5E, rng, ["nope"])


def test_dict_round_trip_and_bad_input():
    model = odd_model(VS060)
    back = ArmModel.from_dict(model.to_dict())
    np.testing.assert_allclose(back.vector(), model.vector(), atol=1e-12)
    np.testing.assert_array_equal(back.joint_limits_rad, model.joint_limits_rad)
    d = model.to_dict()
    del d["bias"]
    with pytest.raises(ValueError, match="bias"):
        ArmModel.from_dict(d)
    with pytest.raises(ValueError, match="dh"):
        ArmModel("x", dh=np.zeros((6, 3)))
    with pytest.raises(ValueError, match="tool_cog_mm"):
        replace(UR5E, tool_cog_mm=[1.0, 2.0])
    with pytest.raises(ValueError, match="6 joint values"):
        forward(UR5E, np.zeros(5))
