"""The classic methods (sgo, quat, shah, li, handheld): exact recovery, accuracy on noisy data
against QR36 and OpenCV's calibrateRobotWorldHandEye, agreement with OpenCV, SGO's seeding, and
the errors for unusable data. Poses 4×4 mm (docs/conventions.md)."""

import numpy as np
import pytest

from tmscal import geometry as g
from tmscal.calib import solve
from tmscal.errors import CalibrationError
from tmscal.sim import Noise

from ..rigs import simulated

cv2 = pytest.importorskip("cv2")
if not hasattr(cv2, "calibrateRobotWorldHandEye"):  # OpenCV 5 removed it
    pytest.skip("cv2.calibrateRobotWorldHandEye not available", allow_module_level=True)

#: (method, options): the closed forms, the refined and unrefined quaternion method, SGO
METHODS = [("shah", {}), ("li", {}), ("li", {"resolve": True}), ("quat", {}),
           ("quat", {"refine": False}), ("sgo", {})]


def pose_errors(est: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """(translation mm, rotation deg) between two 4×4 poses."""
    dt = float(np.linalg.norm(est[:3, 3] - true[:3, 3]))
    return dt, float(np.degrees(g.angle_between(est[:3, :3], true[:3, :3])))


def cv_solve(A: np.ndarray, B: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV: cTw·wTb = cTg·gTb, A as world2cam and B as base2gripper → (X, Z), 4×4 mm."""
    R1, t1, R2, t2 = cv2.calibrateRobotWorldHandEye(
        list(A[:, :3, :3]), list(A[:, :3, 3:]), list(B[:, :3, :3]), list(B[:, :3, 3:]),
        method=getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{name}"))
    return g.make_pose(R1, t1[:, 0]), g.make_pose(R2, t2[:, 0])


@pytest.mark.parametrize("plan", ["eq14", "random"])
@pytest.mark.parametrize("bodies", [1, 2])
@pytest.mark.parametrize("method,opts", METHODS)
def test_noise_free_data_recovers_truth(method, opts, bodies, plan):
    """Tolerance 1e-6 mm and 1e-6° for every method (the iterative ones included: they
    converge to rounding; measured ≤ 1e-10 mm)."""
    truth, d = simulated(30, seed=21, plan=plan, noise=Noise.none())
    C = d["probe"] if bodies == 2 else None
    cal = solve(d["A"], d["marker"], C, method=method, **opts)
    assert cal.method == method and cal.n_poses == 30
    pairs = [(cal.X, truth.X), (cal.Z, truth.Z), (cal.X_raw, truth.X), (cal.Z_raw, truth.Z)]
    if bodies == 2:
        pairs += [(cal.Y, truth.Y), (cal.Y_raw, truth.Y)]
    else:
        assert cal.Y is None
    for est, true in pairs:
        dt, dr = pose_errors(est, true)
        assert dt < 1e-6 and dr < 1e-6
        np.testing.assert_allclose(est[3], [0, 0, 0, 1], atol=0)


def _truth_error(cal, truth, probe: bool) -> float:
    """Σ of the translation errors (mm) of X, Z (and Y) against the truth."""
    e = pose_errors(cal.X, truth.X)[0] + pose_errors(cal.Z, truth.Z)[0]
    return e + (pose_errors(cal.Y, truth.Y)[0] if probe else 0.0)


#: stated factors over QR36's mean ground-truth error (6 seeded rigs, 30 Eq. 14 poses, the
#: paper's noise). Shah's rotations come from the rotations alone, so the ~1.5 m tracker lever
#: arm turns its rotation noise into mm of translation error (measured 6.2×, allowed 10×). LI,
#: as OpenCV implements it, keeps the translations of its linear system, where rotation and
#: translation entries are mixed unscaled (measured 1.8×, allowed 2.5×). quat and sgo measured
#: 0.99× and 1.02×, allowed 1.3×.
FACTOR_VS_QR36 = {"shah": 10.0, "li": 2.5, "quat": 1.3, "sgo": 1.3}


@pytest.fixture(scope="module")
def noisy_runs():
    """Per seed: truth, poses, and the truth errors of each method and of OpenCV's solvers."""
    runs = []
    for seed in range(6):
        truth, d = simulated(30, seed=300 + seed, plan="eq14", noise=Noise())
        A, B, C = d["A"], d["marker"], d["probe"]
        err = {"qr36": _truth_error(solve(A, B, C, "qr36", orthonormal=True), truth, True)}
        for m in FACTOR_VS_QR36:
            err[m] = _truth_error(solve(A, B, C, m), truth, True)
            err[m + "/marker"] = _truth_error(solve(A, B, None, m), truth, False)
        for name in ("SHAH", "LI"):
            X, Z = cv_solve(A, B, name)
            err["cv" + name] = pose_errors(X, truth.X)[0] + pose_errors(Z, truth.Z)[0]
        runs.append(err)
    return {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}


@pytest.mark.parametrize("method", list(FACTOR_VS_QR36))
def test_noisy_accuracy_within_a_stated_factor_of_qr36(noisy_runs, method):
    assert noisy_runs[method] <= FACTOR_VS_QR36[method] * noisy_runs["qr36"]


@pytest.mark.parametrize("method", list(FACTOR_VS_QR36))
def test_noisy_accuracy_not_worse_than_opencv(noisy_runs, method):
    """Marker only, as OpenCV solves: ours ≤ 1.05 × the better of OpenCV's SHAH and LI
    (shah ≤ 1.0001 × OpenCV's SHAH, which it reproduces)."""
    ours = noisy_runs[method + "/marker"]
    if method == "shah":
        assert ours <= 1.0001 * noisy_runs["cvSHAH"]
    else:
        assert ours <= 1.05 * min(noisy_runs["cvSHAH"], noisy_runs["cvLI"])


@pytest.mark.parametrize("plan", ["eq14", "random"])
@pytest.mark.parametrize("name", ["SHAH", "LI"])
def test_shah_and_li_agree_with_opencv(name, plan):
    """Same noisy poses, marker only: X and Z agree to 1e-7 mm and 1e-8° (rounding; the
    methods' own errors are ~0.1 mm)."""
    _, d = simulated(40, seed=7, plan=plan, noise=Noise())
    A, B = d["A"], d["marker"]
    X_cv, Z_cv = cv_solve(A, B, name)
    cal = solve(A, B, None, method=name.lower())
    for est, ref in ((cal.X, X_cv), (cal.Z, Z_cv)):
        dt, dr = pose_errors(est, ref)
        assert dt < 1e-7 and dr < 1e-8


def test_sgo_is_reproducible_with_a_seed_and_seeds_agree_within_noise():
    truth, d = simulated(40, seed=8, plan="eq14", noise=Noise())
    A, B, C = d["A"], d["marker"], d["probe"]
    a = solve(A, B, C, method="sgo", seed=3)
    b = solve(A, B, C, method="sgo", seed=3)
    for M in ("X", "Y", "Z"):
        np.testing.assert_array_equal(getattr(a, M), getattr(b, M))
    assert a.extra["local_searches"] == b.extra["local_searches"]
    # another seed finds the same global minimum: the difference is far below the error
    # against the truth (noise, ~0.1 mm): stated 1e-6 mm and 1e-6°
    c = solve(A, B, C, method="sgo", seed=4)
    for M in ("X", "Y", "Z"):
        dt, dr = pose_errors(getattr(a, M), getattr(c, M))
        assert dt < 1e-6 and dr < 1e-6
    assert pose_errors(a.Y, truth.Y)[0] > 1e-3  # the data are noisy


def _one_axis_poses():
    A = np.stack([g.make_pose(g.rot_z(a), [a * 10, a * 20, 0]) for a in np.linspace(0, 1, 10)])
    return A, np.stack([np.eye(4)] * 10)


@pytest.mark.parametrize("method", ["sgo", "quat", "shah", "li", "handheld"])
def test_degenerate_inputs_raise_the_qr36_errors(method):
    A, B = _one_axis_poses()
    opts = {"handheld_B": np.eye(4), "handheld_C": np.eye(4)} if method == "handheld" else {}
    with pytest.raises(CalibrationError) as qr36:
        solve(A, B, B, method="qr36")
    with pytest.raises(CalibrationError) as ours:
        solve(A, B, B, method=method, **opts)
    assert "rotation diversity" in str(qr36.value)
    assert str(ours.value) == str(qr36.value)
    _, d = simulated(2, seed=1, plan="random", noise=Noise.none())
    with pytest.raises(CalibrationError, match="need at least 3 poses, got 2"):
        solve(d["A"], d["marker"], d["probe"], method=method, **opts)


def test_handheld_with_an_exact_measurement_recovers_y():
    truth, d = simulated(30, seed=5, plan="eq14", noise=Noise.none())
    # the extra measurement: the probe held at the coil centre, seen with the marker
    Ba, Ca = d["marker"][0], d["probe"][0]
    for base in ("qr24", "sgo"):
        cal = solve(d["A"], d["marker"], None, method="handheld", handheld_B=Ba,
                    handheld_C=Ca, base=base)
        assert cal.method == "handheld" and cal.extra["base"] == base
        for est, true in ((cal.Y, truth.Y), (cal.Y_raw, truth.Y), (cal.X, truth.X),
                          (cal.Z, truth.Z)):
            dt, dr = pose_errors(est, true)
            assert dt < 1e-6 and dr < 1e-6


def test_handheld_needs_the_extra_measurement_and_a_known_base():
    _, d = simulated(10, seed=5, plan="random", noise=Noise.none())
    with pytest.raises(CalibrationError, match="handheld_B and handheld_C"):
        solve(d["A"], d["marker"], d["probe"], method="handheld")
    with pytest.raises(CalibrationError,
                       match=r"^handheld: option base: unknown method 'nope'; known: qr24, "):
        solve(d["A"], d["marker"], None, method="handheld", handheld_B=np.eye(4),
              handheld_C=np.eye(4), base="nope")
    with pytest.raises(CalibrationError, match="base cannot be 'handheld' itself"):
        solve(d["A"], d["marker"], None, method="handheld", handheld_B=np.eye(4),
              handheld_C=np.eye(4), base="handheld")
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(CalibrationError, match="handheld_B"):
        solve(d["A"], d["marker"], None, method="handheld", handheld_B=bad,
              handheld_C=np.eye(4))


@pytest.mark.parametrize("method", ["sgo", "quat", "shah", "li"])
def test_unknown_option_is_a_calibration_error(method):
    _, d = simulated(10, seed=5, plan="random", noise=Noise.none())
    with pytest.raises(CalibrationError, match="bogus"):
        solve(d["A"], d["marker"], None, method=method, bogus=1)


@pytest.mark.parametrize("bodies", [1, 2])
def test_li_resolved_equals_the_orthonormal_qr_solution(bodies):
    """Li's rows are QR24's rows times R_Ai per pose (an orthogonal map), so both linear
    systems have the same least-squares minimiser; with the rotations projected and the
    translations re-solved, li(resolve=True) must equal QR24 (one body) or QR36 (two)
    orthonormal on noisy data, to 1e-6 mm and 1e-6° (conditioning of the two systems)."""
    _, d = simulated(25, seed=9, plan="eq14", noise=Noise())
    C = d["probe"] if bodies == 2 else None
    li = solve(d["A"], d["marker"], C, method="li", resolve=True)
    qr = solve(d["A"], d["marker"], C, method="qr36" if bodies == 2 else "qr24")
    for M in ("X", "Z") + (("Y",) if bodies == 2 else ()):
        dt, dr = pose_errors(getattr(li, M), getattr(qr, M))
        assert dt < 1e-6 and dr < 1e-6
