"""QR24 / QR36: exact recovery, the linear system against an independent construction,
metrics, and the typed errors for unusable data."""

import numpy as np
import pytest

from tmscal import geometry as g
from tmscal.calib import design_matrix, solve
from tmscal.calib.linear import unvec34, vec34
from tmscal.calib.metrics import coil_placement_errors, holdout_errors
from tmscal.calib.study import convergence, summarize, threshold_n
from tmscal.errors import CalibrationError
from tmscal.sim import Noise, Truth, simulate

from ..rigs import simulated


@pytest.mark.parametrize("plan", ["random", "eq14"])
@pytest.mark.parametrize("method", ["qr24", "qr36"])
def test_noise_free_data_recovers_truth_to_1e9_mm(plan, method):
    truth, d = simulated(60, seed=11, plan=plan, noise=Noise.none())
    cal = solve(d["A"], d["marker"], d["probe"], method=method)
    for est, true in ((cal.X, truth.X), (cal.Y, truth.Y), (cal.Z, truth.Z),
                      (cal.X_raw, truth.X), (cal.Y_raw, truth.Y), (cal.Z_raw, truth.Z)):
        np.testing.assert_allclose(est, true, atol=1e-9, rtol=0)
    if method == "qr24":
        np.testing.assert_allclose(cal.Z_probe, truth.Z, atol=1e-9, rtol=0)


def test_design_matrix_rows_equal_pose_residuals_for_any_unknowns():
    """D w − b must equal vec(A⁻¹ Z B − X) (and the probe analogue) for ANY w, evaluated by
    plain matrix arithmetic on arbitrary (non-rigid) Z, X, Y."""
    rng = np.random.default_rng(3)
    _, d = simulate(7, rng, plan="random", noise=Noise())
    A, B, C = d["A"], d["marker"], d["probe"]
    Z, X, Y = (np.vstack([rng.normal(size=(3, 4)), [0, 0, 0, 1]]) for _ in range(3))
    D, b = design_matrix(A, B, C)
    assert D.shape == (24 * 7, 36)
    w = np.concatenate([vec34(Z), vec34(X), vec34(Y)])
    got = (D @ w - b).reshape(7, 2, 12)
    for i in range(7):
        Ainv = np.linalg.inv(A[i])
        expect_m = (Ainv @ Z @ B[i] - X)[:3, :].T.reshape(-1)  # column-major vec
        expect_p = (Ainv @ Z @ C[i] - Y)[:3, :].T.reshape(-1)
        np.testing.assert_allclose(got[i, 0], expect_m, atol=1e-8)
        np.testing.assert_allclose(got[i, 1], expect_p, atol=1e-8)


def test_structured_solve_equals_dense_least_squares():
    _, d = simulated(40, seed=4, plan="eq14", noise=Noise())
    cal = solve(d["A"], d["marker"], d["probe"], method="qr36")
    D, b = design_matrix(d["A"], d["marker"], d["probe"])
    Q, R = np.linalg.qr(D)
    w = np.linalg.solve(R, Q.T @ b)
    np.testing.assert_allclose(unvec34(w[:12]), cal.Z_raw, atol=1e-7)
    np.testing.assert_allclose(unvec34(w[12:24]), cal.X_raw, atol=1e-7)
    np.testing.assert_allclose(unvec34(w[24:]), cal.Y_raw, atol=1e-7)


def test_vec34_is_column_major():
    M = np.eye(4)
    M[:3, :] = np.arange(12).reshape(3, 4)
    assert vec34(M).tolist() == [0, 4, 8, 1, 5, 9, 2, 6, 10, 3, 7, 11]
    np.testing.assert_array_equal(unvec34(vec34(M)), M)


def test_noisy_errors_near_noise_floor_and_qr24_ez_penalty():
    truth, d = simulated(500, seed=5, plan="eq14", noise=Noise())
    A, B, C = d["A"], d["marker"], d["probe"]
    tr, te = slice(0, 250), slice(250, 500)
    floor = holdout_errors(A[te], {"marker": B[te], "probe": C[te]},
                           {"marker": truth.X, "probe": truth.Y},
                           {"marker": truth.Z, "probe": truth.Z})["e_t_mm"]
    e36 = solve(A[tr], B[tr], C[tr], "qr36").errors(A[te], B[te], C[te])
    e24 = solve(A[tr], B[tr], C[tr], "qr24").errors(A[te], B[te], C[te])
    assert floor < e36["e_t_mm"] < 1.1 * floor
    assert e24["e_z_mm"] > 0
    assert e24["e_t_mm"] > e36["e_t_mm"]


def test_orthonormal_variant_is_rigid_and_holds_out_below_half_mm():
    truth, d = simulated(100, seed=6, plan="eq14", noise=Noise())
    cal = solve(d["A"], d["marker"], d["probe"], "qr36", orthonormal=True)
    assert cal.applied == "orthonormal"
    for M in (cal.X, cal.Y, cal.Z):
        g.check_pose(M, tol=1e-9)
    assert np.linalg.norm(cal.Y[:3, 3] - truth.Y[:3, 3]) < 0.5
    err = cal.errors(d["A"], d["marker"], d["probe"])
    assert err["e_t_mm"] < 0.5


def test_ez_metric_hand_computed():
    A = np.stack([g.make_pose(g.rot_x(a) @ g.rot_y(2 * a), [a, 0, 0]) for a in (0.1, 0.2)])
    B = np.stack([np.eye(4)] * 2)
    ZM = np.eye(4)
    ZP = g.make_pose(g.rot_z(np.radians(2.0)), [3.0, 4.0, 0.0])
    out = holdout_errors(A, {"marker": B, "probe": B}, {"marker": np.eye(4), "probe": np.eye(4)},
                         {"marker": ZM, "probe": ZP})
    assert out["e_z_mm"] == pytest.approx(5.0)
    assert out["theta_z_deg"] == pytest.approx(2.0)


def test_coil_placement_zero_with_true_transforms_and_known_offset():
    rng = np.random.default_rng(8)
    truth = Truth.random(rng)
    C = g.make_pose(g.random_rotation(rng, 4), rng.normal(0, 100, (4, 3)))
    assert coil_placement_errors(C, truth.Y, truth.Z, truth.Y, truth.Z).max() < 1e-9
    # a Z estimate shifted by 2 mm along base x moves the coil by exactly 2 mm
    Zs = truth.Z.copy()
    Zs[0, 3] += 2.0
    np.testing.assert_allclose(coil_placement_errors(C, truth.Y, Zs, truth.Y, truth.Z), 2.0)


def test_fewer_than_3_poses_is_a_calibration_error():
    _, d = simulated(2, seed=0, plan="random", noise=Noise.none())
    with pytest.raises(CalibrationError, match="at least 3 poses"):
        solve(d["A"], d["marker"], d["probe"])


def test_rotations_about_one_axis_are_rejected():
    A = np.stack([g.make_pose(g.rot_z(a), [a * 10, a * 20, 0]) for a in np.linspace(0, 1, 10)])
    B = np.stack([np.eye(4)] * 10)
    with pytest.raises(CalibrationError, match="rotation diversity"):
        solve(A, B, B)


def test_nan_and_non_rigid_poses_are_rejected_naming_the_pose():
    _, d = simulated(10, seed=1, plan="random", noise=Noise.none())
    A = d["A"].copy()
    A[3, 0, 0] = np.nan
    with pytest.raises(CalibrationError, match="pose 3 contains NaN"):
        solve(A, d["marker"], d["probe"])
    B = d["marker"].copy()
    B[2, :3, :3] *= 1.1
    with pytest.raises(CalibrationError, match=r"B \(tracker_from_marker\): pose 2 is not rigid"):
        solve(d["A"], B, d["probe"])


def test_qr36_needs_probe_poses_and_qr24_runs_marker_only():
    _, d = simulated(10, seed=1, plan="random", noise=Noise.none(), with_probe=False)
    with pytest.raises(CalibrationError, match="qr36 needs probe"):
        solve(d["A"], d["marker"], None, "qr36")
    cal = solve(d["A"], d["marker"], None, "qr24")
    assert cal.Y is None


def test_summary_and_threshold_n_on_a_hand_made_curve():
    ns = [5, 6, 7, 8, 9]
    vals = [0.9, 0.35, 0.5, 0.3, 0.2]
    assert threshold_n(vals, ns, 0.4) == 8
    assert threshold_n(vals, ns, 0.1) is None
    s = summarize(vals, ns)
    assert s["min"] == {"value": 0.2, "n": 9}
    assert s["max"] == {"value": 0.9, "n": 5}
    assert s["median"]["value"] == pytest.approx(0.35)


def test_convergence_curve_lengths_and_too_few_test_poses():
    _, d = simulated(40, seed=2, plan="eq14", noise=Noise())
    out = convergence(d["A"], d["marker"], d["probe"], ("qr36",), n_min=5, n_max=20)
    assert out["n"] == list(range(5, 21)) and out["n_test"] == 20
    assert len(out["methods"]["qr36"]["e_t_mm"]) == 16
    with pytest.raises(CalibrationError, match="needs more than"):
        convergence(d["A"], d["marker"], d["probe"], ("qr36",), n_max=40)
