"""The live monitor's decision rule (``tmscal.calib.alarm``) on simulated residuals, fixed
seeds, no timing: a step of a given size is detected within a stated number of frames, the
false-alarm share of unchanged holds is the stated level, one bad frame cannot raise the
alarm, the tolerances gate it, and the frame noise is learnt from successive differences."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.calib import diagnose as dg
from tmscal.calib.alarm import Detector, FrameNoise, Rule, simulate_holds
from tmscal.errors import CalibrationError

#: a body's residual covariance per hold, as the paper's noise gives it (about 0.06 mm and
#: 0.06° per axis), and the tracker's frame noise (a Polaris at 1.5 m: ~0.025 mm, 0.024°)
S6 = np.diag([0.06 ** 2] * 3 + [0.06 ** 2] * 3)
SF6 = np.diag([0.025 ** 2] * 3 + [0.024 ** 2] * 3)
BODY = ("marker",)


@pytest.mark.parametrize("step", [[1.0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0.5, 0],
                                  [0, -0.6, 0.8, 0, 0, 0]])
def test_a_step_of_one_mm_or_half_a_degree_is_detected_within_the_window_and_persistence(step):
    rule = Rule(window=15)
    res = simulate_holds(rule, S6, SF6, holds=40, frames=200, rng=np.random.default_rng(4),
                         step=np.asarray(step, float), step_at=100)
    assert res["alarms"] == 40
    # the window fills with the new mean and then persistence frames must stay over
    bound = rule.window + rule.frames_to_alarm
    assert max(res["delays"]) <= bound, res["delays"]
    # and not before the step: persistence frames at least after it
    assert min(res["delays"]) >= rule.frames_to_alarm


def test_the_false_alarm_share_of_unchanged_holds_is_the_level():
    rule = Rule(window=15, level=0.01)
    res = simulate_holds(rule, S6, SF6, holds=3000, frames=120, rng=np.random.default_rng(5))
    # a hold's statistic is χ²₆ of its shared error u (P = level) plus the window's frame
    # noise, which adds a few crossings: between the level and twice it (binomial sd 0.0018)
    assert 0.006 <= res["share"] <= 0.02, res


def test_one_bad_frame_cannot_raise_the_alarm_but_a_lasting_step_does():
    rule = Rule(window=10)
    det = Detector(rule)
    r0 = np.zeros(6)
    steps = [det.update(r0, BODY, S6, SF6) for _ in range(30)]
    bad = np.array([50.0, 0, 0, 0, 0, 0])  # 50 mm in one frame: over for `window` frames
    steps.append(det.update(bad, BODY, S6, SF6))
    steps += [det.update(r0, BODY, S6, SF6) for _ in range(40)]
    assert sum(s.over for s in steps) == rule.window
    assert not any(s.alarm for s in steps)
    step = np.array([1.0, 0, 0, 0, 0, 0])
    more = [det.update(step, BODY, S6, SF6) for _ in range(40)]
    first = next(i for i, s in enumerate(more) if s.alarm)
    assert first < rule.window + rule.frames_to_alarm
    assert det.alarmed
    # the step undone: the alarm clears after `persistence` frames under the bound
    back = [det.update(r0, BODY, S6, SF6) for _ in range(40)]
    assert sum(s.clear for s in back) == 1 and not det.alarmed


def test_an_unusable_frame_empties_the_window():
    rule = Rule(window=10)
    det = Detector(rule)
    step = np.array([1.0, 0, 0, 0, 0, 0])
    for _ in range(9):
        assert det.update(step, BODY, S6, SF6).statistic is None
    assert det.update(None).statistic is None  # the robot moved: start again
    for _ in range(9):
        assert det.update(step, BODY, S6, SF6).statistic is None
    assert det.update(step, BODY, S6, SF6).statistic is not None


def test_a_change_below_the_tolerances_raises_nothing():
    small = np.array([0.5, 0, 0, 0.2, 0, 0])  # significant (≫ 0.06), below 0.8 mm and 0.3°
    for rule, alarm in ((Rule(window=5), True),
                        (Rule(window=5, tolerance_mm=0.8, tolerance_deg=0.3), False),
                        (Rule(window=5, tolerance_mm=0.4), True),
                        (Rule(window=5, tolerance_deg=0.1), True)):
        det = Detector(rule)
        assert any(det.update(small, BODY, S6, SF6).alarm for _ in range(30)) is alarm, rule


def test_the_bound_is_the_chi2_quantile_of_the_level():
    from scipy.stats import chi2

    r = Rule(level=1e-6)
    assert r.threshold(12) == pytest.approx(chi2.ppf(1 - 1e-6, 12))
    assert r.frames_to_alarm == r.window + 1
    assert Rule(window=4, persistence=2).frames_to_alarm == 2


@pytest.mark.parametrize("kw", [{"window": 0}, {"persistence": 0}, {"level": 0.0},
                                {"level": 1.0}, {"tolerance_mm": -1.0},
                                {"tolerance_deg": float("nan")}])
def test_bad_parameters_are_refused(kw):
    with pytest.raises(CalibrationError):
        Rule(**kw)


def test_the_frame_noise_is_learnt_from_successive_differences_and_a_jump_left_out():
    rng = np.random.default_rng(7)
    fn = FrameNoise(("marker",), warmup=2000)
    r = rng.standard_normal((2001, 6)) @ np.sqrt(SF6)
    r[1000:] += np.array([5.0, 0, 0, 0, 0, 0])  # a bump: one difference of 5 mm
    for i in range(1, 2001):
        fn.add("marker", r[i] - r[i - 1])
    assert fn.ready
    est = np.sqrt(np.diag(fn.cov(("marker",))))
    assert np.allclose(est, np.sqrt(np.diag(SF6)), rtol=0.1), est
    # frozen after the warm-up: a later change is not learnt as noise
    fn.add("marker", np.full(6, 100.0))
    assert np.allclose(np.sqrt(np.diag(fn.cov(("marker",)))), est)
    # two bodies: block diagonal, zeros for a body not learnt yet
    two = FrameNoise(("marker", "probe"), warmup=3)
    for _ in range(3):
        two.add("marker", np.ones(6))
    assert not two.ready
    C = two.cov(("marker", "probe"))
    assert C.shape == (12, 12) and np.all(C[6:, 6:] == 0) and np.all(C[:6, 6:] == 0)


def test_pose_covariance_adds_the_calibrations_own_error_at_each_pose():
    from tmscal.calib.calibration import Calibration
    from tmscal.sim import Noise, simulate, tms_rig_truth

    truth, sim = simulate(30, np.random.default_rng(8), noise=Noise(), truth=tms_rig_truth())
    from tmscal.calib.methods import solve

    cal: Calibration = solve(sim["A"], sim["marker"], sim["probe"], method="qr36")
    nm = dg.calibration_noise(cal, sim["A"], sim["marker"], sim["probe"])
    fr = dg.frames(cal, sim["A"][:3], sim["marker"][:3], sim["probe"][:3])
    P = dg.pose_covariance(fr, nm)
    assert P.shape == (3, 12, 12)
    plain = dg.pose_covariance(fr, dg.NoiseModel(nm.cov, nm.bodies))
    assert np.allclose(plain, nm.cov[None])
    for i in range(3):  # Σ + J C Jᵀ: symmetric, and at least Σ
        assert np.allclose(P[i], P[i].T)
        assert np.linalg.eigvalsh(P[i] - nm.cov).min() > -1e-12
        assert np.trace(P[i]) > np.trace(nm.cov)
