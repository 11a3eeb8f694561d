"""The adequacy of every solve (tmscal.calib.adequacy, tmscal.solving.adequacy;
docs/adequacy.md).

The sessions are simulated (tmscal.sim, fixed seeds) and each mistake is made here on the
simulated arrays (an inverse, a division by 1000, a copied reading, a shift by one pose, a
rigid change of the tracker from pose k on), not by the code under test."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tmscal.calib import adequacy as aq
from tmscal.cli import main
from tmscal.geometry import make_pose, matrix_from_rotvec
from tmscal.session import Session, make_header, records_from_arrays, write_session
from tmscal.sim import Noise, make_arm
from tmscal.sim import simulate as run_sim
from tmscal.solving.solve import solve


def _session(n: int = 40, seed: int = 7, sigma: float = 0.05, scale: float = 1.0,
             arm: tuple[str, str] | None = None, mistake: str | None = None,
             k: int = 20) -> Session:
    rng = np.random.default_rng(seed)
    noise = Noise(sigma, sigma, sigma, tracker_scale=(scale,) * 3, tracker_shear=(0, 0, 0))
    pair = None if arm is None else make_arm(arm[0], arm[1], seed)
    truth, d = run_sim(n, rng, plan="eq14", noise=noise, samples=1, with_probe=True, arm=pair)
    A, B, C, q = d["A"].copy(), d["marker"].copy(), d["probe"].copy(), d.get("joints")
    cmd = d["commanded"]
    if mistake == "inverted":
        B, C = np.linalg.inv(B), np.linalg.inv(C)
    elif mistake == "inverted_robot":
        A = np.linalg.inv(A)
    elif mistake == "metres_robot":
        A[:, :3, 3] /= 1000.0
    elif mistake == "metres":
        B[:, :3, 3] /= 1000.0
        C[:, :3, 3] /= 1000.0
    elif mistake == "repeated":
        B[k], C[k] = B[k - 1], C[k - 1]
    elif mistake == "late":
        A, B, C, cmd = A[1:], B[:-1], C[:-1], cmd[1:]
    elif mistake == "tracker_moved":
        D = np.linalg.inv(make_pose(matrix_from_rotvec(np.radians([0.3, -0.2, 0.3])),
                                    [0.8, -0.5, 0.4]))
        B[k:], C[k:] = D @ B[k:], D @ C[k:]
    robot = {"driver": "sim"} if arm is None else {"driver": "sim", "arm": arm[0]}
    h = make_header(["marker", "probe"], truth=truth.as_dict(),
                    devices={"robot": robot, "tracker": {"driver": "sim"}})
    return Session(h, records_from_arrays(A, B, C, cmd, 1, joints=q))


@pytest.mark.parametrize("sigma", [0.02, 0.05, 0.1])
def test_no_warning_on_adequate_sessions(sigma: float) -> None:
    for seed in (21, 22):
        ad = solve(_session(seed=seed, sigma=sigma), method="qr36").adequacy
        assert ad is not None and ad["verdict"] == "adequate", ad
        assert ad["likely_cause"] is None and ad["message"] is None and ad["fix"] is None
        assert ad["p_value"] >= aq.ALPHA


def test_json_keys() -> None:
    out = solve(_session(), method="qr36").to_json()
    ad = out["adequacy"]
    assert {"chi2_per_dof", "p_value", "verdict", "likely_cause"} <= set(ad)
    json.dumps(out)  # plain types
    assert {r["cause"] for r in ad["rules"]} >= {"repeated", "tool_moved", "tracker",
                                                 *aq.MISTAKES}


@pytest.mark.parametrize("mistake,cause", [("inverted", "inverted_tracker"),
                                           ("metres", "metres_tracker"),
                                           ("inverted_robot", "inverted_robot"),
                                           ("metres_robot", "metres_robot"),
                                           ("repeated", "repeated"),
                                           ("late", "late_frames")])
def test_each_mistake_is_named(mistake: str, cause: str) -> None:
    ad = solve(_session(mistake=mistake), method="qr36").adequacy
    assert ad is not None and ad["verdict"] == "inadequate"
    assert ad["likely_cause"] == cause, ad["likely_cause"]
    assert ad["fix"]
    if cause == "repeated":
        rule = next(r for r in ad["rules"] if r["cause"] == "repeated")
        assert rule["poses"] == [[20, 19]]


def test_a_tracker_moved_during_the_session_is_named_with_its_pose() -> None:
    ad = solve(_session(mistake="tracker_moved", k=25), method="qr36").adequacy
    assert ad is not None and ad["likely_cause"] == "tool_moved"
    rule = next(r for r in ad["rules"] if r["cause"] == "tool_moved")
    assert rule["moved"] == "tracker" and abs(rule["pose"] - 25) <= 1
    assert rule["delta_deg"] == pytest.approx(np.degrees(np.linalg.norm(
        np.radians([0.3, -0.2, 0.3]))), abs=0.1)
    assert "pose" in ad["message"]


def test_a_tracker_scale_is_named_and_ml_with_the_distortion_is_adequate() -> None:
    s = _session(scale=1.002, seed=8)
    ad = solve(s, method="qr36").adequacy
    assert ad is not None and ad["likely_cause"] == "tracker"
    assert "distortion=auto" in ad["fix"]
    ok = solve(s, method="ml", options={"distortion": "auto"}).adequacy
    assert ok is not None and ok["verdict"] == "adequate"


def test_kinematic_errors_are_named_and_estimating_them_is_adequate() -> None:
    s = _session(arm=("ur5e", "paper"), seed=3)
    ad = solve(s, method="qr36").adequacy
    assert ad is not None and ad["likely_cause"] == "kinematics", ad["rules"]
    assert "--kinematics estimate" in ad["fix"]
    ok = solve(s, method="ml", kinematics="estimate").adequacy
    assert ok is not None and ok["verdict"] == "adequate"
    assert any("estimated the arm" in n for n in ok["notes"])


def test_exact_arm_gives_no_warning() -> None:
    ad = solve(_session(arm=("ur5e", "none"), seed=5), method="qr36").adequacy
    assert ad is not None and ad["verdict"] == "adequate", ad["rules"]


def test_decide_takes_the_mistake_before_the_structure_and_bonferroni() -> None:
    rules = [aq.Rule("tracker", 1.0, (1, 1), 1e-12, 2.0),
             aq.Rule("inverted_tracker", 50.0, (10, 10), 1e-6, 50.0),
             aq.Rule("tool_moved", 1.0, (6, 100), 0.004, 1.1, multiplicity=1)]
    ad = aq.decide(rules)
    assert ad.likely_cause == "inverted_tracker"
    assert [r.p_adjusted for r in ad.rules] == pytest.approx([3e-12, 3e-6, 0.012])
    assert aq.decide([rules[2]]).verdict == "inadequate"  # 0.004 alone is below 0.01
    assert aq.decide([rules[2], None, rules[2], rules[2]]).verdict == "adequate"


def test_mistaken_corrects_each_mistake() -> None:
    rng = np.random.default_rng(0)
    A = np.stack([make_pose(matrix_from_rotvec(rng.normal(0, 0.3, 3)), rng.normal(0, 100, 3))
                  for _ in range(5)])
    B = A.copy()
    B[:, :3, 3] /= 1000.0
    assert np.allclose(aq.mistaken("metres_tracker", A, B, None)[1], A)
    assert np.allclose(aq.mistaken("inverted_robot", np.linalg.inv(A), A, None)[0], A)
    A4, B4, _ = aq.mistaken("late_frames", A, A, None)
    assert np.allclose(A4, A[:-1]) and np.allclose(B4, A[1:])
    with pytest.raises(Exception, match="unknown mistake"):
        aq.mistaken("upside_down", A, A, None)


def _cli(tmp_path: Path, s: Session, *args: str) -> tuple[int, str]:
    path = tmp_path / "s.jsonl"
    write_session(path, s.header, s.poses, overwrite=True)
    r = CliRunner().invoke(main, ["solve", str(path), *args])
    return r.exit_code, r.output


def test_cli_warns_only_when_inadequate(tmp_path: Path) -> None:
    code, out = _cli(tmp_path, _session(mistake="inverted"))
    assert code == 0 and "WARNING" in out and "inverted" in out and "fix:" in out
    code, out = _cli(tmp_path, _session())
    assert code == 0 and "WARNING" not in out and "adequa" not in out.lower()
    code, out = _cli(tmp_path, _session(), "--json")
    assert json.loads(out)["adequacy"]["verdict"] == "adequate"


def test_text_output_unchanged_when_adequate(tmp_path: Path) -> None:
    """The text of an adequate solve is format_result's alone, as before the rules."""
    from tmscal.report.text import format_result

    s = _session(seed=23)
    code, out = _cli(tmp_path, s)
    res = solve(s, method="qr36", adequacy=False)
    assert code == 0 and out.strip() == format_result(res).strip()
