import numpy as np
import pytest

from tmscal import geometry as g


def test_quaternion_hand_worked_90deg_about_z():
    q = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    R = g.matrix_from_quaternion(q)
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(g.quaternion_from_matrix(R), q, atol=1e-15)


def test_quaternion_round_trip_batched_and_scalar_first_positive():
    rng = np.random.default_rng(0)
    R = g.random_rotation(rng, 200)
    q = g.quaternion_from_matrix(R)
    assert q.shape == (200, 4)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(g.matrix_from_quaternion(q), R, atol=1e-12)


def test_rotvec_and_ur_pose_vector_hand_worked():
    R = g.matrix_from_rotvec([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(g.rotvec_from_matrix(np.eye(3)), [0, 0, 0], atol=1e-15)
    # UR pose vector: metres + rotvec -> mm
    T = g.pose_from_rotvec([0.1, -0.2, 0.3, np.pi, 0, 0])
    np.testing.assert_allclose(T[:3, 3], [100, -200, 300])
    np.testing.assert_allclose(T[:3, :3], np.diag([1, -1, -1]), atol=1e-15)


def test_denso_p_hand_worked():
    # rx = 90° only: y -> z
    T = g.matrix_from_denso_p([10, 20, 30, 90, 0, 0])
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [10, 20, 30])
    # rx then rz (fixed axes): Rz(90)·Rx(90)
    T = g.matrix_from_denso_p([0, 0, 0, 90, 0, 90])
    np.testing.assert_allclose(T[:3, :3], [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-15)
    np.testing.assert_allclose(g.denso_p_from_matrix(T), [0, 0, 0, 90, 0, 90], atol=1e-12)


def test_compose_with_inverse_gives_identity():
    rng = np.random.default_rng(1)
    T = g.make_pose(g.random_rotation(rng, 5), rng.normal(0, 100, (5, 3)))
    np.testing.assert_allclose(g.compose(T, g.invert(T)), np.broadcast_to(np.eye(4), T.shape),
                               atol=1e-12)


def test_orthonormalize_fixes_reflection_and_keeps_translation():
    M = np.diag([1.0, 1.0, -1.0])
    R = g.orthonormalize(M)
    assert np.linalg.det(R) == pytest.approx(1.0)
    P = np.eye(4)
    P[:3, :3] = 1.01 * g.matrix_from_rotvec([0.1, 0.2, 0.3])
    P[:3, 3] = [1, 2, 3]
    Q = g.orthonormalize(P)
    np.testing.assert_allclose(Q[:3, :3], g.matrix_from_rotvec([0.1, 0.2, 0.3]), atol=1e-12)
    np.testing.assert_allclose(Q[:3, 3], [1, 2, 3])


def test_rotation_angle_30deg_and_mean_of_symmetric_spread():
    R = g.rot_x(np.radians(30.0))
    assert np.degrees(g.rotation_angle(R)) == pytest.approx(30.0)
    # symmetric spread around a rotation averages back to it
    Rs = np.stack([R @ g.rot_z(a) for a in np.radians([-5.0, 5.0])])
    np.testing.assert_allclose(g.rotation_mean(Rs), R, atol=1e-12)


def test_absolute_orientation_recovers_pose():
    rng = np.random.default_rng(2)
    pts = rng.normal(0, 50, (4, 3))
    T = g.make_pose(g.random_rotation(rng), [10.0, -20.0, -1500.0])
    seen = (T[:3, :3] @ pts.T).T + T[:3, 3]
    np.testing.assert_allclose(g.absolute_orientation(pts, seen), T, atol=1e-9)


def test_check_pose_errors_quote_shape_and_problem():
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        g.check_pose(np.eye(3))
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        g.check_pose(bad)
    shear = np.eye(4)
    shear[0, 1] = 0.3
    with pytest.raises(ValueError, match="not rigid"):
        g.check_pose(shear)


# --- the conversions against scipy.spatial.transform.Rotation over random rotations -----------

_SCIPY_N = 500


def _random_rotations(seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.random(_SCIPY_N, random_state=seed).as_matrix()


def test_matrix_from_quaternion_matches_scipy_scalar_first():
    from scipy.spatial.transform import Rotation
    q = np.random.default_rng(10).standard_normal((_SCIPY_N, 4))  # not normalised on purpose
    want = Rotation.from_quat(q, scalar_first=True).as_matrix()
    np.testing.assert_allclose(g.matrix_from_quaternion(q), want, atol=1e-14)


def test_quaternion_from_matrix_matches_scipy_up_to_sign():
    from scipy.spatial.transform import Rotation
    R = _random_rotations(11)
    want = Rotation.from_matrix(R).as_quat(scalar_first=True)
    want *= np.where(want[:, :1] < 0, -1.0, 1.0)  # tmscal returns q0 ≥ 0
    np.testing.assert_allclose(g.quaternion_from_matrix(R), want, atol=1e-14)


def test_rotvec_conversions_match_scipy_both_ways():
    from scipy.spatial.transform import Rotation
    R = _random_rotations(12)
    rv = Rotation.from_matrix(R).as_rotvec()
    np.testing.assert_allclose(g.rotvec_from_matrix(R), rv, atol=1e-12)
    np.testing.assert_allclose(g.matrix_from_rotvec(rv), R, atol=1e-14)


def test_denso_p_is_scipy_extrinsic_xyz_both_ways():
    from scipy.spatial.transform import Rotation
    R = _random_rotations(13)
    rpy = Rotation.from_matrix(R).as_euler("xyz", degrees=True)  # ry in [−90°, 90°]
    xyz = np.random.default_rng(13).uniform(-500, 500, (_SCIPY_N, 3))
    T = g.matrix_from_denso_p(np.concatenate([xyz, rpy], axis=1))
    np.testing.assert_allclose(T[:, :3, :3], R, atol=1e-14)
    np.testing.assert_allclose(T[:, :3, 3], xyz)
    np.testing.assert_allclose(g.denso_p_from_matrix(g.make_pose(R, xyz)),
                               np.concatenate([xyz, rpy], axis=1), atol=1e-9)


def test_elementary_rotations_match_scipy():
    from scipy.spatial.transform import Rotation
    a = np.random.default_rng(14).uniform(-np.pi, np.pi, _SCIPY_N)
    for axis, rot in zip("xyz", (g.rot_x, g.rot_y, g.rot_z)):
        want = Rotation.from_euler(axis, a[:, None]).as_matrix()
        np.testing.assert_allclose(rot(a), want, atol=1e-15)


def test_rotation_angle_matches_scipy_magnitude():
    from scipy.spatial.transform import Rotation
    R = _random_rotations(15)
    np.testing.assert_allclose(g.rotation_angle(R), Rotation.from_matrix(R).magnitude(),
                               atol=1e-12)


def test_check_poses_tolerance_is_the_public_default():
    P = np.eye(4)
    P[0, 0] += 0.4 * g.RIGID_TOL_DEFAULT  # |R Rᵀ − I| ≈ 0.8 tol: accepted
    g.check_pose(P)
    P[0, 0] = 1.0 + 2 * g.RIGID_TOL_DEFAULT  # ≈ 4 tol: rejected
    with pytest.raises(ValueError, match="not rigid"):
        g.check_pose(P)


def test_skew_is_the_cross_product_batched():
    """[v]× u = v × u for single vectors and stacks; antisymmetric."""
    from tmscal.geometry import skew

    rng = np.random.default_rng(12)
    v, u = rng.normal(size=(4, 5, 3)), rng.normal(size=(4, 5, 3))
    np.testing.assert_allclose(np.einsum("abij,abj->abi", skew(v), u), np.cross(v, u),
                               rtol=1e-14, atol=1e-14)
    np.testing.assert_array_equal(skew(v[0, 0]), -skew(v[0, 0]).T)
    assert skew([1.0, 2.0, 3.0]).shape == (3, 3)


@pytest.mark.parametrize("angle", [1e-9, 1e-5, 5e-5, 1e-3, 0.7, 2.0, 2.2, 3.0, np.pi - 1e-7])
def test_exp_and_log_match_scipy_across_the_branches(angle):
    # the hand-written exp switches to its Taylor series at 1e-4 rad and the log to the
    # quaternion beyond 120°: both sides of each switch, and near π
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(7)
    axes = rng.normal(size=(20, 3))
    rv = axes / np.linalg.norm(axes, axis=1, keepdims=True) * angle
    R = Rotation.from_rotvec(rv).as_matrix()
    np.testing.assert_allclose(g.matrix_from_rotvec(rv), R, atol=2e-15)
    np.testing.assert_allclose(g.rotvec_from_matrix(R), rv, atol=1e-8 if angle > 3 else 1e-13)
    np.testing.assert_allclose(g.rotvec_from_matrix(R[0]), rv[0], atol=1e-8)


@pytest.mark.parametrize("rv", [[0.3, -0.7, 1.1], [2e-5, -1e-5, 3e-5], [0.0, 0.0, 2.9]])
def test_right_jacobian_by_differences_and_its_inverse(rv):
    rv = np.array(rv)
    h = 1e-6
    R0 = g.matrix_from_rotvec(rv)
    # exp(rv + h e_k) = exp(rv) exp(h J_r e_k): the k-th column is log(R0ᵀ exp(rv + h e_k))/h
    num = np.stack([g.rotvec_from_matrix(R0.T @ g.matrix_from_rotvec(rv + h * e)) / h
                    for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(g.right_jacobian(rv), num, atol=1e-6)
    np.testing.assert_allclose(g.right_jacobian_inv(rv) @ g.right_jacobian(rv), np.eye(3),
                               atol=1e-12)
    batch = np.stack([rv, 0.5 * rv])
    assert g.right_jacobian_inv(batch).shape == (2, 3, 3)
