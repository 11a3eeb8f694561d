"""DENSO P-type ↔ 4×4 (geometry.matrix_from_denso_p / denso_p_from_matrix) against
hand-computed poses, and the driver's SPEED option."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tmscal.drivers.denso.robot import speed_option
from tmscal.geometry import angle_between, denso_p_from_matrix, matrix_from_denso_p
from tmscal.sim.rig import TMS_RIG_P0

CASES = [
    # (P-type x, y, z, rx, ry, rz; expected rotation, hand-computed)
    ([10, 20, 30, 90, 0, 0], [[1, 0, 0], [0, 0, -1], [0, 1, 0]]),
    ([10, 20, 30, 0, 90, 0], [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
    ([10, 20, 30, 0, 0, 90], [[0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    # Rz(90)·Rx(90): RX first about the base x, then RZ about the base z
    ([-5, 0, 400, 90, 0, 90], [[0, 0, 1], [1, 0, 0], [0, 1, 0]]),
    # Rz(90)·Rx(180)
    ([400, 50, 300, 180, 0, 90], [[0, 1, 0], [1, 0, 0], [0, 0, -1]]),
]


@pytest.mark.parametrize("p,R", CASES)
def test_matrix_from_denso_p_hand_computed(p: list[float], R: list[list[float]]) -> None:
    T = matrix_from_denso_p(p)
    assert np.allclose(T[:3, :3], R, atol=1e-12)
    assert np.allclose(T[:3, 3], p[:3])
    assert np.allclose(T[3], [0, 0, 0, 1])


@pytest.mark.parametrize("p,R", CASES)
def test_denso_p_from_matrix_back_to_same_pose(p: list[float], R: list[list[float]]) -> None:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p[:3]
    q = denso_p_from_matrix(T)
    assert np.allclose(q[:3], p[:3])
    assert np.allclose(matrix_from_denso_p(q), T, atol=1e-12)


def test_combined_angles_match_scipy_extrinsic_xyz() -> None:
    p = [1.0, 2.0, 3.0, 30.0, 45.0, 60.0]
    R = Rotation.from_euler("xyz", [30, 45, 60], degrees=True).as_matrix()
    assert np.allclose(matrix_from_denso_p(p)[:3, :3], R, atol=1e-12)
    assert np.allclose(denso_p_from_matrix(matrix_from_denso_p(p)), p, atol=1e-9)


def test_fig_is_ignored_and_rig_start_pose() -> None:
    assert np.allclose(matrix_from_denso_p([500, 0, 400, 180, 0, 0, 5]), TMS_RIG_P0)
    q = denso_p_from_matrix(TMS_RIG_P0)
    assert np.allclose(q[:3], [500, 0, 400])
    assert abs(abs(q[3]) - 180) < 1e-9 and abs(q[4]) < 1e-9 and abs(q[5]) < 1e-9


def test_random_round_trip() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        p = np.concatenate([rng.uniform(-800, 800, 3), rng.uniform(-179, 179, 1),
                            rng.uniform(-89, 89, 1), rng.uniform(-179, 179, 1)])
        T = matrix_from_denso_p(p)
        assert np.allclose(denso_p_from_matrix(T), p, atol=1e-8)
        assert angle_between(matrix_from_denso_p(denso_p_from_matrix(T)), T) < 1e-9


def test_speed_option() -> None:
    assert speed_option(100.0, 1000.0) == "SPEED=10"
    assert speed_option(12.5, 1000.0) == "SPEED=1.25"
    assert speed_option(5000.0, 1000.0) == "SPEED=100"
    assert speed_option(1e-6, 1000.0) == "SPEED=0.01"
    # rounded down, never up: 12.3456 mm/s of 1000 is 1.23456 % → 1.23 %
    assert speed_option(12.3456, 1000.0) == "SPEED=1.23"
    assert speed_option(12.3499, 1000.0) == "SPEED=1.23"
