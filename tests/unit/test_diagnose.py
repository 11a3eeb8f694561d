"""What moved, and the partial re-registration (tmscal.calib.diagnose; docs/lab-day.md).

The data are built here, not by the code under test: a UR5e's nominal forward kinematics of
random joints gives A (the arm's base frame), the mock rig's X, Y, Z give B = Z⁻¹ A X and
C = Z⁻¹ A Y, and the changes come from ``tmscal.sim.changes.changed`` (the mock rig's own
rule) or, for the arm, joints offset before the forward kinematics. The calibration is the
unchanged truth, so on noise-free data every hypothesis must come back exactly."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.calib import Calibration
from tmscal.calib import diagnose as dg
from tmscal.calib.kinematics.arms import arm_by_name
from tmscal.calib.kinematics.model import base_from_flange
from tmscal.errors import CalibrationError
from tmscal.geometry import invert, make_pose, matrix_from_rotvec, rotation_angle
from tmscal.sim import tms_rig_truth
from tmscal.sim.changes import changed

ARM = arm_by_name("ur5e")
Q0 = np.array([0.0, -1.3, 1.6, -1.9, -1.57, 0.3])
#: a plausible noise model: 0.05 mm and 0.05° per axis, both bodies
NOISE = dg.NoiseModel(np.kron(np.eye(2), np.diag([0.05 ** 2] * 6)), ("marker", "probe"),
                      "test")


def _joints(n: int, seed: int, spread: float = 0.35) -> np.ndarray:
    return Q0 + np.random.default_rng(seed).uniform(-spread, spread, (n, 6))


def _session(truth, q: np.ndarray, q_true: np.ndarray | None = None, noise: float = 0.0,
             seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C): A the nominal kinematics of q; B, C where the tracker sees the tools of
    the flange the arm really reaches (joints ``q_true``, default q); optional noise (mm and
    degrees per axis, on the tracker poses)."""
    A = base_from_flange(ARM, q)
    A_true = A if q_true is None else base_from_flange(ARM, q_true)
    Zi = invert(truth.Z)
    B = Zi @ A_true @ truth.X
    C = Zi @ A_true @ truth.Y
    if noise:
        rng = np.random.default_rng(seed)
        for N in (B, C):
            for i in range(len(N)):
                N[i] = N[i] @ make_pose(matrix_from_rotvec(np.radians(
                    rng.normal(0, noise, 3))), rng.normal(0, noise, 3))
    return A, B, C


def _calibration(truth) -> Calibration:
    return Calibration("qr36", 40, X=truth.X, Z=truth.Z, X_raw=truth.X.copy(),
                       Z_raw=truth.Z.copy(), Y=truth.Y, Y_raw=truth.Y.copy(),
                       applied="orthonormal")


def _frames(cal, A, B, C, q=None) -> dg.Frames:
    fk = None if q is None else (lambda qq: base_from_flange(ARM, qq))
    return dg.frames(cal, A, B, C, q, fk)


CHANGES = [("tracker", [2.0, 0.0, 0.0], [0.0, 0.0, 0.5]),
           ("coil", [0.4, -0.3, 0.2], [0.3, 0.0, 0.2]),
           ("marker", [0.5, 0.0, 0.3], [0.0, 0.4, 0.0]),
           ("coil_centre", [0.0, 0.6, 0.0], [0.2, 0.0, 0.0])]


@pytest.mark.parametrize("move, mm, deg", CHANGES)
def test_every_rigid_change_is_recovered_on_noise_free_data(move, mm, deg) -> None:
    truth = tms_rig_truth()
    after = changed(truth, move, mm, deg)
    q = _joints(10, 1)
    A, B, C = _session(after, q)
    fr = _frames(_calibration(truth), A, B, C, q)
    d = dg.diagnose(fr, NOISE)
    assert d.changed == move, (d.changed, d.notes)
    ft = d.fits[move]
    want = {"tracker": (invert(truth.Z) @ after.Z, "z"),
            "marker": (invert(truth.X) @ after.X, "x"),
            "coil_centre": (invert(truth.Y) @ after.Y, "y"),
            "coil": (after.X @ invert(truth.X), "coil")}[move]
    np.testing.assert_allclose(ft.delta(want[1]), want[0], atol=1e-7)
    j = d.to_json()
    # the size is the change as the mock rig was told it (the coil's: about its centre)
    assert j["delta_mm"] == pytest.approx(np.linalg.norm(mm), abs=1e-6)
    assert j["delta_deg"] == pytest.approx(np.linalg.norm(deg), abs=1e-6)


def test_nothing_changed_on_noise_free_data_and_under_noise() -> None:
    truth = tms_rig_truth()
    q = _joints(10, 2)
    cal = _calibration(truth)
    assert dg.diagnose(_frames(cal, *_session(truth, q), q), NOISE).changed == "none"
    # the noise the model states: nothing claimed in any of 20 sessions at α = 0.01
    claimed = [dg.diagnose(_frames(cal, *_session(truth, q, noise=0.05, seed=s), q),
                           NOISE).changed for s in range(20)]
    assert claimed.count("none") >= 19, claimed


def test_an_arm_joint_offset_is_the_arm() -> None:
    truth = tms_rig_truth()
    q = _joints(12, 3)
    delta = np.radians([0.0, 0.15, 0.0, 0.0, 0.0, 0.0])
    A, B, C = _session(truth, q, q_true=q + delta)
    d = dg.diagnose(_frames(_calibration(truth), A, B, C, q), NOISE)
    assert d.changed == "arm", (d.changed, d.notes)
    np.testing.assert_allclose(d.fits["arm"].params["arm"], delta, atol=1e-7)
    j = d.to_json()
    assert j["joint"] == 2 and j["delta_deg"] == pytest.approx(0.15, abs=1e-5)


def test_without_joints_the_arm_is_not_a_hypothesis() -> None:
    truth = tms_rig_truth()
    q = _joints(12, 3)
    A, B, C = _session(truth, q, q_true=q + np.radians([0, 0.15, 0, 0, 0, 0]))
    d = dg.diagnose(_frames(_calibration(truth), A, B, C), NOISE)
    assert "arm" not in d.fits and d.changed != "arm"


def test_a_marker_bump_behind_a_tracker_move_is_refused() -> None:
    truth = tms_rig_truth()
    after = changed(changed(truth, "tracker", [2.0, 0, 0], [0, 0, 0.5]), "marker",
                    [0.5, 0, 0], [0, 0, 0])
    q = _joints(10, 4)
    fr = _frames(_calibration(truth), *_session(after, q, noise=0.02, seed=4), q)
    d = dg.diagnose(fr, NOISE)
    assert d.changed == "unexplained" and d.pair == ("tracker", "marker"), (d.changed,
                                                                            d.pair)
    with pytest.raises(dg.UpdateRefused, match="marker") as e:
        dg.update(fr, NOISE, ["z"])
    assert e.value.diagnosis is not None and e.value.diagnosis.changed == "unexplained"
    # both named: the update explains the session
    ft = dg.update(fr, NOISE, ["z", "x"])
    np.testing.assert_allclose(ft.delta("x"), invert(truth.X) @ after.X, atol=0.05)


def test_update_keeps_the_untouched_transforms_and_the_arm_bit_for_bit() -> None:
    truth = tms_rig_truth()
    after = changed(truth, "tracker", [3.0, -1.0, 0.0], [0.5, 0, 0])
    q = _joints(6, 5)
    cal = _calibration(truth)
    cal.arm = object()  # type: ignore[assignment]  # any arm: carried, never touched
    cal.Z_probe = cal.Z.copy()
    cal.Z_probe_raw = cal.Z.copy()
    fr = _frames(_calibration(truth), *_session(after, q), q)
    new = dg.updated(cal, dg.update(fr, NOISE, ["z"]))
    assert new.X is cal.X and new.Y is cal.Y and new.X_raw is cal.X_raw
    assert new.Y_raw is cal.Y_raw and new.arm is cal.arm
    np.testing.assert_allclose(new.Z, after.Z, atol=1e-7)
    np.testing.assert_allclose(new.Z_raw, after.Z, atol=1e-7)
    np.testing.assert_allclose(new.Z_probe, after.Z, atol=1e-7)
    assert new.covariance is None and new.extra["updated"] == ["z"]


def test_coil_update_moves_x_and_y_together() -> None:
    truth = tms_rig_truth()
    after = changed(truth, "coil", [0.5, 0.2, 0.0], [0.0, 0.4, 0.0])
    q = _joints(6, 6)
    cal = _calibration(truth)
    new = dg.updated(cal, dg.update(_frames(cal, *_session(after, q), q), NOISE, ["coil"]))
    np.testing.assert_allclose(new.X, after.X, atol=1e-7)
    np.testing.assert_allclose(new.Y, after.Y, atol=1e-7)
    assert new.Z is cal.Z


@pytest.mark.parametrize("names, match", [
    (["w"], "expected one of"), (["z", "z"], "twice"), (["coil", "x"], "leave out"),
    ([], "at least one")])
def test_update_names_are_checked(names, match) -> None:
    with pytest.raises(CalibrationError, match=match):
        dg.blocks_of_update(names)


def test_too_few_poses_or_one_orientation_is_a_clear_error() -> None:
    truth = tms_rig_truth()
    after = changed(truth, "tracker", [2.0, 0, 0], [0, 0, 0.5])
    cal = _calibration(truth)
    q = _joints(2, 7)
    with pytest.raises(CalibrationError, match="at least 3 usable poses"):
        dg.update(_frames(cal, *_session(after, q), q), NOISE, ["z"])
    # five poses that only translate: Z and a change of the coil's mount cannot be told apart
    A = np.stack([make_pose(np.eye(3), [500 + 20 * i, 10 * i, 400]) for i in range(5)])
    B = invert(after.Z) @ A @ after.X
    C = invert(after.Z) @ A @ after.Y
    with pytest.raises(CalibrationError, match="two different axes|do not determine"):
        dg.update(dg.frames(cal, A, B, C), NOISE, ["z"])
    assert dg.min_poses(["x"], True) == 2 and dg.min_poses(["x"], False) == 3


def test_marker_only_sessions_test_the_tracker_and_the_coil() -> None:
    truth = tms_rig_truth()
    after = changed(truth, "tracker", [1.0, 0, 0], [0, 0.3, 0])
    q = _joints(8, 8)
    A, B, _ = _session(after, q)
    d = dg.diagnose(_frames(_calibration(truth), A, B, None), NOISE)
    assert d.changed == "tracker" and set(d.fits) == {"none", "tracker", "coil"}
    assert any("marker only" in n for n in d.notes)


def test_noise_model_round_trip_and_fallback_from_stored_errors() -> None:
    nm = dg.NoiseModel(np.diag(np.arange(1.0, 13.0)), ("marker", "probe"), "x", 7,
                       np.eye(18) * 1e-4, ("z", "x", "y"))
    back = dg.NoiseModel.from_json(nm.to_json())
    np.testing.assert_array_equal(back.cov, nm.cov)
    np.testing.assert_array_equal(back.cal_cov, nm.cal_cov)
    assert back.cal_blocks == nm.cal_blocks and back.n_poses == 7
    m = nm.for_bodies(["probe"])
    np.testing.assert_array_equal(np.diag(m.cov), np.arange(7.0, 13.0))
    iso = dg.noise_from_errors({"marker": {"trans_mm": 0.08, "rot_deg": 0.04}}, ["marker"])
    # E‖t‖ of a 3-D isotropic Gaussian is 2√(2/π) σ
    assert np.sqrt(iso.cov[0, 0]) == pytest.approx(0.08 / (2 * np.sqrt(2 / np.pi)))
    with pytest.raises(CalibrationError, match="probe"):
        dg.noise_from_errors({"marker": {"trans_mm": 0.1, "rot_deg": 0.1}},
                             ["marker", "probe"])


def test_suggested_tolerances_fail_an_unchanged_rig_about_one_day_in_a_hundred() -> None:
    tol = dg.suggested_tolerances(NOISE, 10)
    rng = np.random.default_rng(99)   # sessions drawn here, not by the code under test
    r = rng.normal(0, 0.05, (3000, 10, 12))
    e_t = sum(np.linalg.norm(r[:, :, k:k + 3], axis=2).mean(axis=1) for k in (0, 6))
    assert 0.003 < np.mean(e_t > tol["tolerance_mm"]) < 0.02


def test_rotation_of_the_update_matches_the_truth_under_noise() -> None:
    """10 poses with noise: the re-registered tracker within 3σ of the true change."""
    truth = tms_rig_truth()
    after = changed(truth, "tracker", [2.0, 0, 0], [0, 0, 0.5])
    q = _joints(10, 9)
    fr = _frames(_calibration(truth), *_session(after, q, noise=0.05, seed=9), q)
    ft = dg.update(fr, NOISE, ["z"])
    s = ft.size("z")
    true_d = invert(truth.Z) @ after.Z
    err = float(np.degrees(rotation_angle(ft.delta("z")[:3, :3].T @ true_d[:3, :3])))
    assert err < 3 * s["sigma_deg"] + 1e-3, (err, s)
