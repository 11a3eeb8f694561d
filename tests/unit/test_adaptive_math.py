"""tmscal.calib.prediction: the prediction, the next-pose criterion, the bootstrap and the stopping
rule of adaptive acquisition, against simulated rigs with known truth (tmscal.sim.SimRig
driven directly: move_flange, then averaged observations)."""

from __future__ import annotations

import numpy as np
import pytest

from tmscal.acquisition.sample import spread_of
from tmscal.calib import Applied, Calibration, solve
from tmscal.calib import prediction as ad
from tmscal.calib.bound import STEPS, crb, placement_error, sim_noise_options
from tmscal.calib.ml_model import Problem
from tmscal.errors import CalibrationError
from tmscal.geometry import angle_between, make_pose, pose_mean
from tmscal.poses import make_plan
from tmscal.sim import TMS_RIG_P0, TOOL_8700340_MM, Noise, SimRig, tms_rig_truth

TRUTH = tms_rig_truth()
POOL = make_plan("eq14", TMS_RIG_P0, 300, 1, 100.0, 10.0)
REGION = POOL[:100]


class Session:
    """Poses measured on a SimRig: A (reported), averaged B, C, and ml's ``spreads``."""

    def __init__(self, rig: SimRig, samples: int = 20) -> None:
        self.rig, self.samples = rig, samples
        self.A: list[np.ndarray] = []
        self.B: list[np.ndarray] = []
        self.C: list[np.ndarray] = []
        self.spreads: list[dict] = []

    def measure(self, P: np.ndarray) -> None:
        self.rig.move_flange(P)
        self.A.append(self.rig.reported_flange())
        rec: dict = {"spread": {}, "samples": {}}
        for body, out, key in (("marker", self.B, "B"), ("probe", self.C, "C")):
            obs = self.rig.observe(body, self.samples)
            m = pose_mean(obs)
            out.append(m)
            rec["spread"][body] = spread_of(obs, m)
            rec["samples"][key] = self.samples
        self.spreads.append(rec)

    def arrays(self) -> tuple[np.ndarray | None, ...]:
        if not self.A:
            return None, None, None
        return np.array(self.A), np.array(self.B), np.array(self.C)

    def predict(self, settings: ad.AdaptiveSettings, region: np.ndarray = REGION
                ) -> ad.Prediction:
        A, B, C = self.arrays()
        return ad.predict(A, B, C, region, settings, spreads=self.spreads)


def rig(seed: int, noise: Noise | None = None) -> SimRig:
    return SimRig(TRUTH, noise or Noise(), np.random.default_rng(seed), start=TMS_RIG_P0)


def run_adaptive(r: SimRig, settings: ad.AdaptiveSettings, pool: np.ndarray = POOL,
                 samples: int = 20) -> tuple[str, ad.Prediction, list[int]]:
    """A simulated adaptive run on the rig: the bootstrap, then predict → stop_reason →
    choose_next (robot time by the motion model at 250 mm/s, 1200 mm/s², + 0.5 s per pose)
    until it stops. Returns (stop reason, last prediction, pool indices measured)."""
    s = Session(r, samples)
    used = ad.bootstrap_indices(pool, settings.bootstrap_poses(2), TMS_RIG_P0)
    for i in used:
        s.measure(pool[i])
    while True:
        pred = s.predict(settings, pool[:settings.region])
        why = ad.stop_reason(pred, len(used), settings)
        if why is not None:
            return why, pred, used
        avail = np.ones(len(pool), dtype=bool)
        avail[used] = False
        cost = ad.candidate_cost_s(r.commanded, pool, 250.0, 1200.0, 0.5)
        i, _ = ad.choose_next(pred, pool, avail, cost)
        used.append(i)
        s.measure(pool[i])


# --- settings and minimum ---

@pytest.mark.parametrize("field,value", [
    ("target_mm", 0.0), ("target_mm", float("nan")), ("target_mm", "0.1"),
    ("confidence", 1.0), ("confidence", 0.0), ("max_poses", 2), ("max_poses", 10.0),
    ("bootstrap", 2), ("bootstrap", 50), ("pool", 10), ("region", 0), ("region", 2000),
    ("max_poses", True)])
def test_settings_refuse_bad_values_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        ad.AdaptiveSettings(**{field: value})


def test_bootstrap_default_is_minimum_plus_one() -> None:
    assert ad.AdaptiveSettings().bootstrap_poses(2) == ad.minimum_poses(2) + 1
    assert ad.AdaptiveSettings(bootstrap=7).bootstrap_poses(2) == 7
    with pytest.raises(ValueError, match="bodies"):
        ad.minimum_poses(3)


@pytest.mark.parametrize("bodies", [1, 2])
def test_minimum_poses_is_where_the_information_becomes_full_rank(bodies: int) -> None:
    truth = {"X": TRUTH.X, "Y": TRUTH.Y, "Z": TRUTH.Z}
    noise = sim_noise_options(0.05, 0.05, 0.05, TOOL_8700340_MM)
    m = ad.minimum_poses(bodies)
    idx = ad.bootstrap_indices(POOL, m, TMS_RIG_P0)
    C = POOL if bodies == 2 else None
    with pytest.raises(CalibrationError, match="not identifiable"):
        crb(POOL[idx[:m - 1]], POOL[idx[:m - 1]], None if C is None else C[idx[:m - 1]],
            truth, noise)
    cov = crb(POOL[idx], POOL[idx], None if C is None else C[idx], truth, noise)
    assert np.all(np.isfinite(cov))


def test_probe_poses_with_a_marker_only_calibration_are_refused() -> None:
    """``predict`` with ``calibration`` an ml solve on the marker alone (no Y) and probe poses
    C: a CalibrationError naming it, not a None Y inside ml's problem; the same calibration
    without C predicts the marker's placement."""
    s = Session(rig(4), samples=5)
    for P in POOL[:15]:
        s.measure(P)
    A, B, C = s.arrays()
    cal = solve(A, B, None, method="ml", distortion=ad.PREDICTION_DISTORTION)
    assert cal.Y is None and "covariance_parts" in cal.extra
    with pytest.raises(CalibrationError, match="marker-only"):
        ad.predict(A, B, C, REGION, ad.AdaptiveSettings(), calibration=cal)
    pred = ad.predict(A, B, None, REGION, ad.AdaptiveSettings(), calibration=cal)
    assert pred.calibration is cal and np.isfinite(pred.coil_mm)


# --- the placement Jacobian against calib.bound's error model ---

@pytest.mark.parametrize("model,g0", [("none", None), ("axis", np.array([1e-3, -1e-3, 0.0])),
                                      ("affine", np.array([1e-3, 0, 0, 5e-4, 0, 0]))])
def test_placement_jacobian_matches_finite_differences_of_the_bound_model(
        model: str, g0: np.ndarray | None) -> None:
    rng = np.random.default_rng(4)
    bodies = [np.linalg.inv(TRUTH.Z) @ POOL[:5] @ W for W in (TRUTH.X, TRUTH.Y)]
    Ws = [W @ make_pose(np.eye(3), rng.normal(0, 1, 3)) for W in (TRUTH.X, TRUTH.Y)]
    prob = Problem(POOL[:5], bodies, Ws, TRUTH.Z, model, g0)
    J = ad.placement_jacobians(prob, REGION[:4])
    k = prob.n_params
    _, Z, G = prob.unpack(np.zeros(k))
    for r in range(4):
        Nt = np.linalg.inv(Z) @ REGION[r] @ Ws[1]
        N = Nt.copy()
        N[:3, 3] = np.linalg.solve(G, Nt[:3, 3])  # as measured (distorted positions)
        Jn = np.zeros((3, k))
        for i in range(k):
            h = 1e-7 if i >= 18 else STEPS[(i % 6) // 3]
            e = np.zeros(k)
            e[i] = h
            Jn[:, i] = (placement_error(prob, e, N, 1) - placement_error(prob, -e, N, 1)
                        )[3:] / (2 * h)
        scale = np.abs(Jn).max(axis=0) + 1e-9
        assert np.all(np.abs(J[r] - Jn) <= 1e-4 * scale + 1e-6)


# --- the prediction is honest ---

def test_prediction_covers_the_true_error_at_about_its_confidence() -> None:
    """40 simulated sessions on the same 8 well-spread poses, different noise seeds: the true
    mean coil-placement error over the region must be at or below the 95 % prediction in at
    least 85 % of them (binomial sd at 40 runs: 3.4 points; 85 % is 3 sd below 95 %), and the
    50 % prediction must be neither always nor never exceeded (25–85 %: not merely huge)."""
    idx = ad.bootstrap_indices(POOL, 8, TMS_RIG_P0)
    settings = ad.AdaptiveSettings(confidence=0.95)
    hit95 = hit50 = 0
    runs = 40
    for seed in range(runs):
        s = Session(rig(1000 + seed))
        for i in idx:
            s.measure(POOL[i])
        p = s.predict(settings)
        true = ad.true_coil_error(p.calibration, TRUTH.Y, TRUTH.Z, REGION)
        hit95 += true <= p.coil_mm
        hit50 += true <= p.quantile(0.5)
    assert hit95 >= 0.85 * runs
    assert 0.25 * runs <= hit50 <= 0.85 * runs


def test_prediction_of_a_noise_free_rig_is_zero_and_stops_at_the_bootstrap() -> None:
    settings = ad.AdaptiveSettings()
    why, pred, used = run_adaptive(rig(5, Noise.none()), settings)
    assert why == "target"
    assert len(used) == settings.bootstrap_poses(2)
    # the robot's noise estimated as ~0 from the residuals; the tracker's taken from its
    # sample spreads, which tracker_covs floors at 1e-4 mm per sample (≈ 1e-5 mm averaged)
    assert pred.coil_mm < 1e-4


def test_very_noisy_rig_stops_at_max_poses_and_says_so() -> None:
    noisy = Noise(fiducial_sigma_mm=1.0, robot_rot_sigma_deg=0.5, robot_trans_sigma_mm=1.0)
    settings = ad.AdaptiveSettings(max_poses=7)
    why, pred, used = run_adaptive(rig(6, noisy), settings)
    assert why == "max_poses"
    assert len(used) == 7 and len(set(used)) == 7
    assert pred.coil_mm > settings.target_mm


# --- the next pose ---

def test_candidate_information_predicts_the_covariance_after_measuring_there() -> None:
    """Σ' = (P⁻¹ + I_c)⁻¹ from the current fit against ml's own covariance after the pose is
    really measured (the noise as given and unscaled, so only the Jacobians are compared;
    with the noise estimated, 6 and 7 poses would weigh differently)."""
    s = Session(rig(7), samples=1)
    for i in ad.bootstrap_indices(POOL, 6, TMS_RIG_P0):
        s.measure(POOL[i])
    settings = ad.AdaptiveSettings()
    A, B, C = s.arrays()
    opts = {"scale_covariance": False, "noise": "given"}
    p = ad.predict(A, B, C, REGION, settings, **opts)
    c = 250
    after = float(ad._criteria(p, ad.candidate_information(p, POOL[c:c + 1]))[0])
    s.measure(POOL[c])
    A, B, C = s.arrays()
    q = ad.predict(A, B, C, REGION, settings, **opts)
    assert after == pytest.approx(q.criterion_mm2, rel=0.05)
    assert after < p.criterion_mm2


def test_chosen_poses_beat_random_poses_on_the_true_error() -> None:
    """Same rigs, same bootstrap; then 6 poses by choose_next or 6 random unused pool poses:
    the mean true coil-placement error over 6 rigs must be lower with the chosen ones."""
    settings = ad.AdaptiveSettings(target_mm=1e-9, bootstrap=4, max_poses=10)
    err = {"chosen": [], "random": []}
    for seed in range(6):
        _, pred, used = run_adaptive(rig(2000 + seed), settings, samples=5)
        cal = pred.calibration
        err["chosen"].append(ad.true_coil_error(cal, TRUTH.Y, TRUTH.Z, REGION))
        boot = used[:4]
        pick = np.random.default_rng(seed).choice(np.setdiff1d(np.arange(len(POOL)), boot), 6,
                                                  replace=False)
        s = Session(rig(2000 + seed), samples=5)
        for i in list(boot) + list(pick):
            s.measure(POOL[i])
        cal = s.predict(settings).calibration
        err["random"].append(ad.true_coil_error(cal, TRUTH.Y, TRUTH.Z, REGION))
    assert np.mean(err["chosen"]) < np.mean(err["random"])


def test_choose_next_weighs_robot_time_and_skips_unavailable() -> None:
    s = Session(rig(8))
    for i in ad.bootstrap_indices(POOL, 5, TMS_RIG_P0):
        s.measure(POOL[i])
    p = s.predict(ad.AdaptiveSettings())
    avail = np.ones(len(POOL), dtype=bool)
    best, info = ad.choose_next(p, POOL, avail, np.ones(len(POOL)))
    assert info["gain_mm2"] > 0 and info["criterion_mm2"] < p.criterion_mm2
    cost = np.ones(len(POOL))
    cost[best] = 1e6
    assert ad.choose_next(p, POOL, avail, cost)[0] != best
    avail[best] = False
    assert ad.choose_next(p, POOL, avail, np.ones(len(POOL)))[0] != best
    with pytest.raises(ValueError, match="no candidate"):
        ad.choose_next(p, POOL, np.zeros(len(POOL), dtype=bool), np.ones(len(POOL)))
    with pytest.raises(ValueError, match="cost_s"):
        ad.choose_next(p, POOL, np.ones(len(POOL), dtype=bool), np.zeros(len(POOL)))


# --- bootstrap ---

def _spread(poses: np.ndarray, p0: np.ndarray) -> float:
    """Smallest pairwise distance in the bootstrap's combined metric."""
    s_t = np.sqrt(np.mean(np.sum((POOL[:, :3, 3] - p0[:3, 3]) ** 2, axis=1)))
    s_r = np.sqrt(np.mean(angle_between(p0, POOL) ** 2))
    d = [np.hypot(np.linalg.norm(a[:3, 3] - b[:3, 3]) / s_t, angle_between(a, b) / s_r)
         for i, a in enumerate(poses) for b in poses[i + 1:]]
    return float(min(d))


def test_bootstrap_is_deterministic_and_better_spread_than_random_picks() -> None:
    k = 6
    idx = ad.bootstrap_indices(POOL, k, TMS_RIG_P0)
    assert idx == ad.bootstrap_indices(POOL.copy(), k, TMS_RIG_P0)
    assert len(set(idx)) == k
    far = np.linalg.norm(POOL[:, :3, 3] - TMS_RIG_P0[:3, 3], axis=1)
    assert idx[0] in np.argsort(far)[-len(POOL) // 2:]  # starts far from P0
    rng = np.random.default_rng(0)
    rand = [_spread(POOL[rng.choice(len(POOL), k, replace=False)], TMS_RIG_P0)
            for _ in range(100)]
    assert _spread(POOL[idx], TMS_RIG_P0) > np.max(rand)
    with pytest.raises(ValueError, match="k must be"):
        ad.bootstrap_indices(POOL, 0, TMS_RIG_P0)


def test_a_longer_bootstrap_starts_with_the_shorter_one() -> None:
    """Greedy farthest point is prefix-consistent: the loop replaces a skipped bootstrap pose
    by the next one of a longer list."""
    long = ad.bootstrap_indices(POOL, 12, TMS_RIG_P0)
    for k in (1, 4, 7):
        assert ad.bootstrap_indices(POOL, k, TMS_RIG_P0) == long[:k]


# --- stopping and the true error ---

def test_stop_reason() -> None:
    s = Session(rig(10))
    for i in ad.bootstrap_indices(POOL, 5, TMS_RIG_P0):
        s.measure(POOL[i])
    p = s.predict(ad.AdaptiveSettings())
    above = ad.AdaptiveSettings(target_mm=p.coil_mm * 0.99, max_poses=6)
    at = ad.AdaptiveSettings(target_mm=p.coil_mm, max_poses=6)
    assert ad.stop_reason(p, 5, above) is None
    assert ad.stop_reason(p, 6, above) == "max_poses"
    assert ad.stop_reason(p, 5, at) == "target"
    assert ad.stop_reason(None, 5, at) is None


def test_true_coil_error_is_the_offset_of_z() -> None:
    v = np.array([0.03, -0.04, 0.0])  # a base-frame shift of Z moves every placement by v
    Z = TRUTH.Z.copy()
    Z[:3, 3] += v
    cal = Calibration("test", 3, X=TRUTH.X, Z=Z, X_raw=TRUTH.X, Z_raw=Z, Y=TRUTH.Y,
                      Y_raw=TRUTH.Y, applied=Applied.ORTHONORMAL)
    assert ad.true_coil_error(cal, TRUTH.Y, TRUTH.Z, REGION) == pytest.approx(0.05, rel=1e-9)
    exact = solve(REGION[:5], np.linalg.inv(TRUTH.Z) @ REGION[:5] @ TRUTH.X,
                  np.linalg.inv(TRUTH.Z) @ REGION[:5] @ TRUTH.Y, method="qr36",
                  orthonormal=True)
    assert ad.true_coil_error(exact, TRUTH.Y, TRUTH.Z, REGION) < 1e-6


@pytest.mark.parametrize("rot", [None, (5.0, 10.0)])
def test_candidate_cost_is_the_motion_models_move_time(rot: tuple | None) -> None:
    """Against tmscal.motion.move_duration pose by pose (with slow rotation caps, the rotation
    profile sets the time of some moves)."""
    from tmscal.motion import move_duration
    caps = rot or (None, None)
    cost = ad.candidate_cost_s(POOL[7], POOL[:20], 250.0, 1200.0, 1.5, *caps)
    want = [move_duration(POOL[7], P, 250.0, 1200.0, *caps) + 1.5 for P in POOL[:20]]
    assert cost == pytest.approx(want, rel=1e-12)
    assert cost[7] == pytest.approx(1.5)


def _off_truth() -> tuple[list[np.ndarray], np.ndarray]:
    rng = np.random.default_rng(11)
    Ws = [W @ make_pose(np.eye(3), rng.normal(0, 2, 3)) for W in (TRUTH.X, TRUTH.Y)]
    return Ws, TRUTH.Z @ make_pose(np.eye(3), rng.normal(0, 5, 3))


def test_residual_jacobians_match_ml_central_differences() -> None:
    """The analytic candidate Jacobian against ml's own finite differences of its residuals
    (Problem.jacobian), with an estimate away from the truth."""
    Ws, Z = _off_truth()
    P = POOL[20:26]
    J = ad.residual_jacobians(Problem(POOL[:5], [POOL[:5]] * 2, Ws, Z), P)
    N = [np.linalg.inv(Z) @ P @ W for W in Ws]
    ref = Problem(P, N, Ws, Z).jacobian(np.zeros(18), np.eye(12))
    assert J.shape == (6, 12, 18)
    assert np.allclose(J.reshape(-1, 18), ref, atol=1e-6 * np.abs(ref).max())


def test_residual_jacobians_with_a_small_distortion_approach_the_rigid_ones() -> None:
    """With a tracker scale of 1 + 10⁻⁶ (ml's numerical path) the rigid parameters' columns
    are the analytic rigid ones, and the scale's column is not zero."""
    Ws, Z = _off_truth()
    P = POOL[20:26]
    rigid = ad.residual_jacobians(Problem(POOL[:5], [POOL[:5]] * 2, Ws, Z), P)
    scaled = ad.residual_jacobians(Problem(POOL[:5], [POOL[:5]] * 2, Ws, Z, "scale",
                                           np.array([1e-6])), P)
    assert scaled.shape == (6, 12, 19)
    assert np.allclose(scaled[:, :, :18], rigid, atol=1e-4 * np.abs(rigid).max())
    assert np.abs(scaled[:, 9:12, 18]).max() > 100.0  # mm per unit scale, tools ~1.5 m away


def test_prediction_and_choice_are_reproducible_from_the_same_poses() -> None:
    """A resumed run re-derives its decisions from the session: the same poses must give the
    same prediction and the same next pose (the Monte Carlo has a fixed seed)."""
    s = Session(rig(12))
    for i in ad.bootstrap_indices(POOL, 5, TMS_RIG_P0):
        s.measure(POOL[i])
    p1, p2 = s.predict(ad.AdaptiveSettings()), s.predict(ad.AdaptiveSettings())
    assert p1.coil_mm == p2.coil_mm and p1.sigma_mm == p2.sigma_mm
    cost = ad.candidate_cost_s(POOL[3], POOL, 250.0, 1200.0, 0.5)
    avail = np.ones(len(POOL), dtype=bool)
    assert ad.choose_next(p1, POOL, avail, cost) == ad.choose_next(p2, POOL, avail, cost)


def test_prediction_takes_the_robot_noise_from_the_data() -> None:
    """A rig whose robot translation noise is 3× ml's default start (0.15 mm): after 20
    well-spread poses the prediction's robot σ is within 25 % of it (REML from the
    residuals), and the prediction is larger than on the default rig's same poses."""
    idx = ad.bootstrap_indices(POOL, 20, TMS_RIG_P0)
    preds = {}
    for trans in (0.05, 0.15):
        s = Session(rig(31, Noise(robot_trans_sigma_mm=trans)))
        for i in idx:
            s.measure(POOL[i])
        preds[trans] = s.predict(ad.AdaptiveSettings())
    assert preds[0.15].noise[0] == pytest.approx(0.15, rel=0.25)
    assert preds[0.15].coil_mm > 1.5 * preds[0.05].coil_mm


def test_model_error_adds_the_robots_error_at_the_target() -> None:
    """With the arm's error counted as model error the prediction rises by the robot's own
    per-pose error at a target: model_error_mm = √(3σ_t² + 2σ_r²|t_Y|²) of ml's estimated
    σ, and the predicted mean error is at least the mean norm of that error alone (0.92 ×
    its RMS for a 3-D Gaussian, less Monte Carlo slack)."""
    s = Session(rig(32))
    for i in ad.bootstrap_indices(POOL, 12, TMS_RIG_P0):
        s.measure(POOL[i])
    A, B, C = s.arrays()
    settings = ad.AdaptiveSettings()
    plain = ad.predict(A, B, C, REGION, settings, spreads=s.spreads)
    model = ad.predict(A, B, C, REGION, settings, model_error=True, spreads=s.spreads)
    st, sr = model.noise[0], model.noise[1]
    tY = model.calibration.Y[:3, 3]
    assert plain.model_error_mm == 0.0
    assert model.model_error_mm == pytest.approx(np.sqrt(3 * st ** 2 + 2 * sr ** 2 * tY @ tY))
    assert model.coil_mm > plain.coil_mm
    assert model.quantile(0.5) > 0.85 * model.model_error_mm


def test_realistic_arm_errors_are_covered_with_model_error() -> None:
    """A UR5e with realistic kinematic errors (tmscal.sim.make_arm) under the rig: the true
    mean placement error over the region, where the flange really goes for the commands (the
    true arm at the nominal joints), is above the prediction that ignores the arm on most of
    4 rigs and below the one that counts it as model error on every one."""
    from tmscal.sim import make_arm

    below_plain = covered = 0
    idx = ad.bootstrap_indices(POOL, 16, TMS_RIG_P0)
    for seed in range(4):
        pair = make_arm("ur5e", "realistic", seed)
        r = SimRig(TRUTH, Noise(), np.random.default_rng(seed), start=TMS_RIG_P0, arm=pair)
        s = Session(r)
        for i in idx:
            s.measure(POOL[i])
        A, B, C = s.arrays()
        settings = ad.AdaptiveSettings()
        with_model = ad.predict(A, B, C, REGION, settings, model_error=True,
                                spreads=s.spreads)
        plain = ad.predict(A, B, C, REGION, settings, spreads=s.spreads)

        def reached(cmd: np.ndarray, pair=pair, r=r) -> np.ndarray:
            return np.stack([pair.actual(pair.solve(T, r.joints())) for T in cmd])
        true = ad.true_coil_error(with_model.calibration, TRUTH.Y, TRUTH.Z, REGION, reached)
        covered += true <= with_model.coil_mm
        below_plain += true <= plain.coil_mm
    assert covered == 4
    assert below_plain <= 2


def test_true_coil_error_with_a_distorted_tracker_commands_the_measured_targets() -> None:
    """A tracker that measures positions scaled by 1.001 about its origin (1.5 m away): the
    true X, Y, Z with that distortion recorded place the measured targets exactly; without
    it the targets are missed by the scale's 0.1 % of their ~1.5 m distance."""
    D = 1.001 * np.eye(3)
    kw = dict(X=TRUTH.X, Z=TRUTH.Z, Y=TRUTH.Y, X_raw=TRUTH.X, Z_raw=TRUTH.Z, Y_raw=TRUTH.Y,
              applied=Applied.ORTHONORMAL)
    knows = Calibration("t", 3, distortion={"model": "scale", "matrix": D}, **kw)
    rigid = Calibration("t", 3, **kw)
    assert ad.true_coil_error(knows, TRUTH.Y, TRUTH.Z, REGION, tracker_distortion=D) < 1e-6
    e = ad.true_coil_error(rigid, TRUTH.Y, TRUTH.Z, REGION, tracker_distortion=D)
    assert 1.3 < e < 1.7


def test_prediction_covers_a_tracker_scale_that_a_rigid_model_misses() -> None:
    """A tracker whose positions are scaled by +0.1 % about its origin (issue 21): on 8 rigs
    of 20 well-spread poses the default 95 % prediction (ml with the scale,
    PREDICTION_DISTORTION) covers the true mean placement error over the region, measured as
    that tracker sees the targets, on at least 7 (an honest 95 % misses one of 8 in 28 % of
    draws, two or more in 6 %); the prediction without a distortion model covers it on at
    most one (its calibration keeps the scale's error: true ≈ 0.09–0.10 mm against ≈ 0.08 mm
    predicted)."""
    assert ad.PREDICTION_DISTORTION == "scale"
    idx = ad.bootstrap_indices(POOL, 20, TMS_RIG_P0)
    noise = Noise(tracker_scale=1.001)
    covered = covered_rigid = 0
    for seed in range(8):
        s = Session(rig(seed, noise))
        for i in idx:
            s.measure(POOL[i])
        settings = ad.AdaptiveSettings()
        D = noise.tracker_distortion
        for pred, count in ((s.predict(settings), 1), (None, 0)):
            if pred is None:
                A, B, C = s.arrays()
                pred = ad.predict(A, B, C, REGION, settings, distortion="none",
                                  spreads=s.spreads)
            true = ad.true_coil_error(pred.calibration, TRUTH.Y, TRUTH.Z, REGION,
                                      tracker_distortion=D)
            if count:
                covered += true <= pred.coil_mm
            else:
                covered_rigid += true <= pred.coil_mm
    assert covered >= 7
    assert covered_rigid <= 1
