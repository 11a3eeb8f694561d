"""``tmscal compare`` and ``tmscal.solving.compare``: the fold protocol, the skip note on
marker-only sessions, the optional bound, the table, the JSON and the figures."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal import calib
from tmscal.calib.study import cross_validate
from tmscal.cli import main
from tmscal.errors import CalibrationError
from tmscal.report.compare import format_compare
from tmscal.sim import Noise, simulate
from tmscal.solving.compare import compare_arrays, default_ns


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def poses():
    truth, d = simulate(60, np.random.default_rng(11), plan="eq14", noise=Noise())
    return truth, d


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compare")
    both, marker = tmp / "sim.jsonl", tmp / "marker.jsonl"
    assert run("simulate", "-o", both, "--poses", 60, "--seed", 4).exit_code == 0
    assert run("simulate", "-o", marker, "--poses", 60, "--seed", 4,
               "--marker-only").exit_code == 0
    return both, marker


def test_at_the_largest_n_the_folds_are_those_of_cross_validation(poses) -> None:
    _, d = poses
    A, B, C = d["A"], d["marker"], d["probe"]
    res = compare_arrays(A, B, C, ["qr24", "qr36"], ns=[48], folds=5)
    for m in ("qr24", "qr36"):
        cv = cross_validate(A, B, C, method=m, k=5)
        for k in ("e_t_mm", "theta_t_deg"):
            assert res["methods"][m][k]["mean"][0] == pytest.approx(cv["mean"][k], rel=1e-9)
            assert res["methods"][m][k]["sd"][0] == pytest.approx(cv["sd"][k], rel=1e-9)
        assert res["methods"][m]["time_ms"]["mean"][0] > 0


def test_noise_free_poses_give_zero_errors_and_exact_truth() -> None:
    truth, d = simulate(40, np.random.default_rng(2), plan="eq14", noise=Noise.none())
    res = compare_arrays(d["A"], d["marker"], d["probe"], ["qr36"], ns=[10, 32], folds=5,
                         truth=truth.as_dict() | {k: getattr(truth, k) for k in "XYZ"})
    r = res["methods"]["qr36"]
    assert max(r["e_t_mm"]["mean"]) < 1e-6
    assert max(r["truth"]["Y_trans_mm"]["mean"]) < 1e-6
    assert max(r["truth"]["coil_placement_mm"]["mean"]) < 1e-6


def test_more_poses_bring_the_truth_error_down(poses) -> None:
    truth, d = poses
    t = {k: getattr(truth, k) for k in "XYZ"}
    res = compare_arrays(d["A"], d["marker"], d["probe"], ["qr36"], ns=[5, 48], folds=5,
                         truth=t)
    y = res["methods"]["qr36"]["truth"]["Y_trans_mm"]["mean"]
    assert y[1] < y[0]


def test_marker_only_skips_methods_that_need_the_probe(poses) -> None:
    truth, d = poses
    res = compare_arrays(d["A"], d["marker"], None, ["qr24", "qr36"], ns=[10], folds=3,
                         truth={"X": truth.X, "Z": truth.Z})
    assert list(res["methods"]) == ["qr24"] and "qr36" in res["skipped"]
    assert "probe" in res["skipped"]["qr36"]
    assert "X_trans_mm" in res["methods"]["qr24"]["truth"]
    text = format_compare(res)
    assert "skipped qr36:" in text and "truth X mm" in text


def test_bad_counts_are_calibration_errors(poses) -> None:
    _, d = poses
    with pytest.raises(CalibrationError, match="ns=49"):
        compare_arrays(d["A"], d["marker"], d["probe"], ["qr36"], ns=[49], folds=5)
    with pytest.raises(CalibrationError, match="unknown method 'nope'"):
        compare_arrays(d["A"], d["marker"], d["probe"], ["nope"], ns=[10])
    assert default_ns(48) == [5, 7, 10, 14, 20, 30, 48]
    assert default_ns(50) == [5, 7, 10, 14, 20, 30, 50]


def test_a_bound_function_when_calib_has_one_is_shown(poses, monkeypatch) -> None:
    truth, d = poses
    seen = []

    def fake_bound(A, B, C, truth, noise):
        seen.append((len(A), noise["robot_sigma_mm"]))
        return {"X_trans_mm": 2.0 / len(A), "Y_trans_mm": 1.0 / len(A)}

    import tmscal.solving.compare as cmp
    monkeypatch.setattr(cmp, "find_bound", lambda: fake_bound)
    t = {k: getattr(truth, k) for k in "XYZ"}
    res = compare_arrays(d["A"], d["marker"], d["probe"], ["qr36"], ns=[10, 40], folds=5,
                         truth=t, noise={"robot_sigma_mm": 0.05})
    assert seen == [(10, 0.05), (40, 0.05)]
    assert res["bound"]["Y_trans_mm"] == [0.1, 0.025]
    text = format_compare(res)
    assert any(ln.split()[:2] == ["40", "bound"] and ln.split()[-1] == "0.0250"
               for ln in text.splitlines())
    # without a noise model there is no bound
    res = compare_arrays(d["A"], d["marker"], d["probe"], ["qr36"], ns=[10], folds=5, truth=t)
    assert res["bound"] is None and " bound " not in format_compare(res).split("truth:")[0]


def test_the_real_bound_is_below_the_spread_of_qr36(sessions) -> None:
    """On a simulated session the Cramér–Rao bound (tmscal.calib.bound, when present) of Y's
    RMS translation error is positive, falls with n, and the mean truth error of QR36 over 5
    folds is not below a third of it (statistical: the mean of a norm is ≥ ~0.9 × its RMS
    for 3-D Gaussian errors; a third leaves room for 5 folds' spread)."""
    pytest.importorskip("tmscal.calib.bound")
    both, _ = sessions
    from tmscal.session import read_session
    from tmscal.solving.compare import compare_session
    res = compare_session(read_session(both), ["qr36"], ns=[10, 48], folds=5)
    b = res["bound"]["Y_trans_mm"]
    assert 0 < b[1] < b[0]
    y = res["methods"]["qr36"]["truth"]["Y_trans_mm"]["mean"]
    assert y[0] > b[0] / 3 and y[1] > b[1] / 3


def test_table_lines_fit_and_name_every_method(poses) -> None:
    truth, d = poses
    res = compare_arrays(d["A"], d["marker"], d["probe"], ["qr24", "qr36"], ns=[7, 20],
                         folds=4, truth={k: getattr(truth, k) for k in "XYZ"})
    text = format_compare(res)
    assert max(len(ln) for ln in text.splitlines()) <= 100
    rows = [ln.split() for ln in text.splitlines() if ln.strip().split()[:1] in (["7"], ["20"])]
    assert sorted((r[0], r[1]) for r in rows) == [("20", "qr24"), ("20", "qr36"),
                                                 ("7", "qr24"), ("7", "qr36")]


def test_cli_json_and_plots(sessions, tmp_path) -> None:
    both, marker = sessions
    r = run("compare", both, "--methods", "qr24,qr36", "--n", "7,20", "--folds", 3, "--json")
    assert r.exit_code == 0, r.output
    res = json.loads(r.output)
    assert res["ns"] == [7, 20] and set(res["methods"]) == {"qr24", "qr36"}
    assert res["truth"] is True and res["session"] == str(both)
    out = tmp_path / "figs"
    r = run("compare", marker, "--methods", "qr24,qr36", "--n", "7,20", "--plot", out)
    assert r.exit_code == 0, r.output
    assert "skipped qr36" in r.output
    for f in ("compare-errors.png", "compare-time.png", "compare-truth.png"):
        assert (out / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = run("compare", marker, "--methods", "qr24", "--n", "7", "--plot", out)
    assert r.exit_code == 2 and "already exists" in r.output and "--force" in r.output


@pytest.mark.parametrize("args, words", [
    (["--n", "x"], ["--n", "whole numbers"]),
    (["--n", "500"], ["--n 500"]),
    (["--methods", "nope"], ["unknown method 'nope'"]),
    (["--folds", "1"], ["--folds"]),
])
def test_cli_bad_input_is_one_error_line(sessions, args, words) -> None:
    both, _ = sessions
    r = run("compare", both, *args)
    assert r.exit_code != 0
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.output
    for w in words:
        assert w in lines[0]


# --- tmscal solve: every registered method, method options, uncertainty and distortion ------

@pytest.fixture
def fake_method(monkeypatch):
    """A registered method that is QR36 plus the optional fields of a statistical solver
    (given values) and that records the options it was called with."""
    calls: list[dict] = []

    def fake(A, B, C, orthonormal, **options):
        calls.append(options)
        cal = calib.solve(A, B, C, method="qr36", orthonormal=orthonormal)
        cal.method = "fake"
        cal.uncertainty = {"coil_centre_mm": {"sigma": 0.0123, "p95": 0.0456},
                           "coil_axis_deg": {"sigma": 0.0321, "p95": 0.0654},
                           "target_note": "the session's mean probe pose"}
        cal.distortion = {"model": "scale", "matrix": np.eye(3) * 1.0008,
                          "scale_percent": 0.08}
        return cal

    monkeypatch.setitem(calib.METHODS, "fake", fake)
    return calls


def test_solve_offers_every_registered_method_and_prints_uncertainty(sessions, fake_method,
                                                                     tmp_path):
    both, _ = sessions
    r = run("solve", "--help")
    for m in calib.METHODS:
        assert m in r.output
    out = tmp_path / "cal.yaml"
    r = run("solve", both, "--method", "fake", "--train", 40, "-o", out)
    assert r.exit_code == 0, r.output
    assert "tracker scale +0.080 %" in r.output
    rows = {ln.split("(")[0].strip(): ln.split() for ln in r.output.splitlines()
            if ln.strip().startswith(("coil centre", "coil axis"))}
    # the coil centre's error is printed once, as the calibration's predicted
    # coil-placement error (issue 31); the JSON keeps the solver's coil-centre uncertainty
    assert "coil centre" not in rows
    assert r.output.count("predicted coil-placement error of the FAKE calibration") == 1
    assert rows["coil axis"][-2:] == ["0.0321", "0.0654"]
    import yaml
    doc = yaml.safe_load(out.read_text())
    assert doc["distortion"]["scale_percent"] == 0.08
    assert np.allclose(doc["distortion"]["matrix"], np.eye(3) * 1.0008)
    res = json.loads(run("solve", both, "--method", "fake", "--train", 40, "--json").output)
    assert res["uncertainty"]["coil_centre_mm"]["p95"] == 0.0456
    assert "uncertainty" not in json.loads(run("solve", both, "--train", 40, "--json").output)


def test_solve_passes_method_options_and_the_handheld_pose(sessions, fake_method):
    both, _ = sessions
    from tmscal.session import read_session
    pose = next(p for p in read_session(both).poses if p.index == 3)
    r = run("solve", both, "--method", "fake", "--train", 40, "--option", "distortion=axis",
            "--option", "max_iter=7", "--handheld-pose", 3)
    assert r.exit_code == 0, r.output
    opts = fake_method[-1]
    assert opts["distortion"] == "axis" and opts["max_iter"] == 7
    np.testing.assert_array_equal(opts["handheld_B"], pose.B)
    np.testing.assert_array_equal(opts["handheld_C"], pose.C)
    msg = [ln for ln in run("solve", both, "--handheld-pose", 999).output.splitlines() if ln]
    assert len(msg) == 1 and "--handheld-pose 999" in msg[0]
    msg = [ln for ln in run("solve", both, "--option", "nokey").output.splitlines() if ln]
    assert len(msg) == 1 and "--option" in msg[0] and "KEY=VALUE" in msg[0]


def test_placement_with_a_found_distortion_commands_the_true_flange_pose() -> None:
    """Noise-free poses from a tracker that scales by 1.01: with the true rigid Y, Z and the
    distortion D, the placement inputs give (Z C_cmd Y⁻¹) = the flange pose that really put the
    probe at each measured C (to rounding); the measured C used as is would be ≈ 1 % × 1.5 m
    off."""
    from tmscal.calib import Calibration

    truth, d = simulate(10, np.random.default_rng(5), plan="eq14",
                        noise=Noise(0, 0, 0, tracker_scale=1.01))
    D = np.eye(3) * 1.01
    cal = Calibration("fake", 10, X=truth.X, Z=truth.Z, X_raw=truth.X, Z_raw=truth.Z,
                      Y=truth.Y, Y_raw=truth.Y, distortion={"model": "scale", "matrix": D})
    C_cmd, Y, Z = cal.placement(d["probe"])
    A_cmd = Z @ C_cmd @ np.linalg.inv(Y)
    np.testing.assert_allclose(A_cmd[:, :3, 3], d["A"][:, :3, 3], atol=1e-6)
    naive = Z @ d["probe"] @ np.linalg.inv(Y)
    assert np.linalg.norm(naive[:, :3, 3] - d["A"][:, :3, 3], axis=1).min() > 5.0
