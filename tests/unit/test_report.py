"""The solve report: cross-validated errors by default (against a hand-made k-fold loop and a
large fresh test set from the same simulated rig), labels and legend of the human table, the
outlier rule (a pose corrupted on purpose is named, no other), and the study's noise floor."""

from __future__ import annotations

import re

import numpy as np
import pytest

from tmscal import geometry as g
from tmscal import solving
from tmscal.calib import solve
from tmscal.report.text import format_result, format_study
from tmscal.session import make_header, read_session, records_from_arrays, write_session
from tmscal.sim import simulate
from tmscal.solving.outliers import find_outliers, outlier_threshold
from tmscal.solving.solve import SolveResult
from tmscal.solving.study import study_session


def write_sim(path, truth, d):
    header = make_header(["marker", "probe"], truth=truth.as_dict())
    write_session(path, header, records_from_arrays(d["A"], d["marker"], d["probe"],
                                                    d["commanded"], 1))
    return read_session(path)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """A 100-pose session and 2000 fresh poses of the same simulated rig (the true hold-out)."""
    rng = np.random.default_rng(21)
    truth, d = simulate(100, rng, plan="eq14")
    _, fresh = simulate(2000, rng, plan="eq14", truth=truth)
    s = write_sim(tmp_path_factory.mktemp("rep") / "s.jsonl", truth, d)
    return s, d, fresh, truth


def test_default_errors_are_cross_validated_and_near_the_true_hold_out(rig):
    s, _, fresh, _ = rig
    res = solving.solve(s, method="qr36")
    cal = res.calibration
    assert res.errors_on == "cross-validated (5 folds)" and res.n_solve == 100
    true = cal.errors(fresh["A"], fresh["marker"], fresh["probe"])
    for k in ("e_t_mm", "theta_t_deg"):
        assert res.errors[k] == pytest.approx(true[k], rel=0.12), k
    # the calibration reported is the one solved on all poses
    np.testing.assert_allclose(cal.X_raw, solve(*(s.arrays(True)[:3])).X_raw, atol=1e-12)


def test_cross_validation_equals_a_hand_made_contiguous_k_fold_loop(rig):
    s, d, _, _ = rig
    A, B, C = d["A"], d["marker"], d["probe"]
    per = []
    for j in range(4):  # 100 poses, 4 folds of 25 in order
        test = np.arange(25 * j, 25 * (j + 1))
        train = np.setdiff1d(np.arange(100), test)
        e = solve(A[train], B[train], C[train]).errors(A[test], B[test], C[test])
        per.append([e["e_t_mm"], e["theta_t_deg"], e["bodies"]["probe"]["trans_mm"]])
    per = np.array(per)
    res = solving.solve(s, method="qr36", folds=4)
    assert res.cv == {"folds": 4, "split": "contiguous", "fold_sizes": [25] * 4}
    got = [res.errors["e_t_mm"], res.errors["theta_t_deg"], res.errors["probe"]["trans_mm"]]
    np.testing.assert_allclose(got, per.mean(axis=0), rtol=1e-9)
    sd = [res.errors_sd["e_t_mm"], res.errors_sd["theta_t_deg"],
          res.errors_sd["probe"]["trans_mm"]]
    np.testing.assert_allclose(sd, per.std(axis=0, ddof=1), rtol=1e-9)


def test_in_sample_only_on_request_and_labelled(rig):
    s, d, _, _ = rig
    res = solving.solve(s, method="qr36", in_sample=True)
    assert res.errors_on == "in-sample" and res.errors_sd is None and res.cv is None
    e = solve(d["A"], d["marker"], d["probe"]).errors(d["A"], d["marker"], d["probe"])
    assert res.errors["e_t_mm"] == pytest.approx(e["e_t_mm"], rel=1e-12)
    assert "IN-SAMPLE" in format_result(res)


def _result(**kw):
    base = dict(method="qr36", applied="raw", n_solve=7, n_test=7,
                errors_on="cross-validated (5 folds)", n_skipped=0, X=np.eye(4),
                Y=np.eye(4), Z=np.eye(4), raw={},
                errors={"e_t_mm": 0.3, "theta_t_deg": 0.7,
                        "marker": {"trans_mm": 0.1, "rot_deg": 0.3},
                        "probe": {"trans_mm": 0.2, "rot_deg": 0.4}},
                errors_sd={"e_t_mm": 0.03, "theta_t_deg": 0.07,
                           "marker": {"trans_mm": 0.01, "rot_deg": 0.03},
                           "probe": {"trans_mm": 0.02, "rot_deg": 0.04}},
                cv={"folds": 5, "split": "contiguous", "fold_sizes": [2, 2, 1, 1, 1]},
                truth={"coil_placement_mm": 0.0123, "coil_placement_max_mm": 0.0456,
                       "coil_placement_n": 7})
    base.update(kw)
    return SolveResult(**base)


def test_table_labels_sd_rows_coil_row_and_legend():
    out = format_result(_result(), show_matrices=False)
    probe = [ln for ln in out.splitlines() if ln.strip().startswith("probe")]
    assert len(probe) == 1 and "(AY)⁻¹ZC" in probe[0] and "(AX)⁻¹ZB" not in probe[0]
    assert re.search(r"probe\s+E = \(AY\)⁻¹ZC\s+0\.2000\s+0\.4000$", probe[0])
    total = [ln for ln in out.splitlines() if "e_t, θ_t" in ln and "0.3000" in ln]
    assert len(total) == 1 and "marker + probe" in total[0]
    assert re.search(r"0\.3000\s+0\.7000$", total[0])
    sd = [ln for ln in out.splitlines() if "± SD over 5 folds" in ln]
    assert [re.findall(r"\d\.\d{4}", ln) for ln in sd] == [
        ["0.0100", "0.0300"], ["0.0200", "0.0400"], ["0.0300", "0.0700"]]
    coil = [ln for ln in out.splitlines() if "coil placement error" in ln]
    assert coil == ["  coil placement error, mm over 7 targets: mean 0.0123, max 0.0456"]
    assert "5-fold cross-validated" in out and "contiguous folds of 1–2" in out
    legend = out[out.index("legend"):]
    for term in ("e_t, θ_t: the total error", "‖t(E⊥)‖", "coil placement:",
                 "raw matrices applied"):
        assert term in legend, term
    assert "e_z" not in out


def test_qr24_rows_name_the_probe_z_and_e_z():
    r = _result(method="qr24", errors={"e_t_mm": 0.35, "theta_t_deg": 0.75, "e_z_mm": 0.05,
                                       "theta_z_deg": 0.05,
                                       "marker": {"trans_mm": 0.1, "rot_deg": 0.3},
                                       "probe": {"trans_mm": 0.2, "rot_deg": 0.4}},
                errors_sd=None, cv=None, errors_on="held-out")
    out = format_result(r, show_matrices=False)
    assert "(AY)⁻¹Z_P C" in out and "marker + probe + e_z" in out
    assert "e_z, θ_z: QR24 solves a separate Z" in out and "± SD" not in out


def test_outlier_threshold_by_hand():
    # log v = 0, 1, 2, 3, 4: median 2, MAD 1 -> exp(2 + 3 * 1.4826)
    v = np.exp([0.0, 1.0, 2.0, 3.0, 4.0])
    assert outlier_threshold(v) == pytest.approx(np.exp(2 + 3 * 1.4826), rel=1e-12)
    assert outlier_threshold([0.0, 0.0, 1e-9]) == float("inf")  # noise-free: nothing flagged


def test_a_pose_corrupted_on_purpose_is_the_one_outlier(tmp_path):
    rng = np.random.default_rng(5)
    truth, d = simulate(120, rng, plan="eq14")
    d["marker"][17] = d["marker"][17] @ g.make_pose(np.eye(3), [0.8, 0.0, 0.0])  # bumped tool
    s = write_sim(tmp_path / "bad.jsonl", truth, d)
    res = solving.solve(s, method="qr36")
    assert [o["index"] for o in res.outliers] == [17]
    assert {(f["body"], f["metric"]) for f in res.outliers[0]["flags"]} >= {
        ("marker", "translation")}
    text = format_result(res)
    assert "outlier poses (session pose index; rule:" in text  # an index, not a count
    assert "pose index 17: marker translation" in text
    clean = write_sim(tmp_path / "ok.jsonl", *simulate(120, np.random.default_rng(5)))
    assert find_outliers({"index": [], "marker": {"trans_mm": [], "rot_deg": []}}) == []
    assert solving.solve(clean, method="qr36").outliers == []


def test_study_reports_the_noise_floor_of_the_true_transforms(rig):
    s, d, _, truth = rig
    st = study_session(s, ["qr36"], n_max=60)
    A, B, C = d["A"][60:], d["marker"][60:], d["probe"][60:]
    e_t = 0.0
    for N, T in ((B, truth.X), (C, truth.Y)):
        E = np.linalg.inv(A @ T) @ truth.Z @ N
        e_t += np.linalg.norm(E[:, :3, 3], axis=1).mean()  # exact rigid: no projection needed
    assert st["noise_floor"]["e_t_mm"] == pytest.approx(e_t, rel=1e-6)
    assert "noise floor" in format_study(st)


def test_a_session_without_tracker_poses_points_to_selfcal_identify(tmp_path):
    from tmscal.errors import CalibrationError
    from tmscal.session import make_header, read_session, write_session
    from tmscal.solving.solve import session_arrays

    path = write_session(tmp_path / "sc.jsonl", make_header(["ft"]), [])
    with pytest.raises(CalibrationError, match="no tracker poses.*selfcal identify"):
        session_arrays(read_session(path), "qr36")
