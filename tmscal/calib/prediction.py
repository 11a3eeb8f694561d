"""Adaptive acquisition's mathematics: predict the coil-placement error of the calibration so
far, choose the next pose, decide when to stop (docs/methods.md, "Adaptive acquisition").
Pure numerics, no I/O: the acquisition loop (tmscal.acquisition.adaptive_run) moves the robot.

Frames and units as everywhere (docs/conventions.md): A = base_from_flange, B =
tracker_from_marker, C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker; 4×4, mm. Robot time in s.

The pieces:

* the candidate pool is the config's plan with ``settings.pool`` poses (so it is regenerated
  from a session header and checked against the safety envelope before anything moves); the
  region where the rig will place coils is its first ``settings.region`` poses;
* :func:`bootstrap_indices`: well-spread start poses (greedy farthest point);
* :func:`predict`: QR36 then ``ml`` (its covariance), and the predicted coil-placement error
  over the region at a confidence (:class:`Prediction`);
* :func:`choose_next`: the candidate with the largest expected reduction of the mean-square
  coil-placement error over the region per second of robot time (an L-optimal design);
* :func:`stop_reason`: "target" or "max_poses";
* :func:`candidate_cost_s`: robot time per candidate by the one motion model
  (tmscal.motion);
* :func:`true_coil_error`: the error against a known truth (simulation, benchmarks).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import angle_between, invert, skew
from ..motion import trapezoid_duration
from .calibration import Calibration
from .methods import solve
from .metrics import placement_errors
from .ml import ml_solve
from .ml_model import (
    Problem,
    g_of,
    noise_covariance,
    tracker_covs,
    undistort,
    undistortion,
    whitener,
)

__all__ = ["AdaptiveSettings", "SettingError", "MAX_TARGET_MM", "MAX_POOL", "Prediction",
           "minimum_poses", "bootstrap_indices", "predict", "placement_jacobians",
           "residual_jacobians", "candidate_information", "choose_next", "stop_reason",
           "candidate_cost_s", "true_coil_error", "placement_offsets", "MC_DRAWS",
           "PREDICTION_DISTORTION"]

#: Monte Carlo draws of the parameter error behind the predicted quantile (fixed seed 0)
MC_DRAWS = 4000
#: the tracker distortion the prediction's ml fits: an isotropic scale, always, so that a
#: tracker whose length scale differs from the robot's by an amount the poses so far cannot
#: yet tell from noise is counted in the prediction's uncertainty, not ignored (issue 21)
PREDICTION_DISTORTION = "scale"


def minimum_poses(bodies: int) -> int:
    """The fewest poses that make the calibration well posed: 3, for one body (marker) or two
    (marker and probe). Eliminating Z from A_i X = Z B_i leaves (A_j⁻¹ A_i) X = X (B_j⁻¹ B_i),
    the hand–eye equation AX = XB; one relative motion leaves X free to turn about and slide
    along its screw axis, two motions with non-parallel rotation axes fix it (Tsai and Lenz
    1989), i.e. three poses. Z then follows from any pose, and Y (the probe) from Z and the
    probe poses, so the second body needs no further pose."""
    if isinstance(bodies, bool) or bodies not in (1, 2):
        raise ValueError(f"bodies must be 1 (marker) or 2 (marker and probe), got {bodies!r}")
    return 3


#: the largest coil-placement target an adaptive run takes (mm): a larger one is a unit mistake
MAX_TARGET_MM = 100.0
#: the most candidate poses (the plan's length limit)
MAX_POOL = 100_000


class SettingError(ValueError):
    """An ``AdaptiveSettings`` field out of range: ``field`` names it, ``reason`` says why
    (the config parser names the key ``adaptive.<field>`` with it)."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"AdaptiveSettings.{field} {reason}")
        self.field = field
        self.reason = reason


def _int_in(name: str, v: Any, low: int, high: int, high_name: str | None = None) -> int:
    if (isinstance(v, bool) or not isinstance(v, (int, np.integer))
            or not low <= v <= high):
        bound = f"{high} ({high_name})" if high_name else f"{high}"
        raise SettingError(name, f"must be an integer in {low}…{bound}, got {v!r}")
    return int(v)


@dataclass(frozen=True)
class AdaptiveSettings:
    """Settings of an adaptive run: the config's ``adaptive:`` section (docs/adaptive.md),
    a session header's ``adaptive`` entry, the command line's overrides.

    ``target_mm``: stop when the predicted coil-placement error (mean over the region, at
    ``confidence``) is at or below this (mm; at most ``MAX_TARGET_MM``). ``confidence``:
    0 < c < 1. ``max_poses``: stop there in any case (3 ≤ max_poses ≤ pool: 3 poses are
    the fewest that fix X, Y and Z). ``bootstrap``: number of well-spread start poses (None:
    the minimum that makes the problem well posed plus one, :meth:`bootstrap_poses`; else
    3 … max_poses). ``pool``: candidate poses (the plan with this many poses, at most
    ``MAX_POOL``). ``region``: the first ``region`` pool poses (1 … pool), where the rig will
    place coils (the prediction's average). ``SettingError`` (a ValueError) naming the
    field."""

    target_mm: float = 0.05
    confidence: float = 0.95
    max_poses: int = 40
    bootstrap: int | None = None
    pool: int = 1000
    region: int = 200

    def __post_init__(self) -> None:
        t = self.target_mm
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not (
                math.isfinite(t) and 0 < t <= MAX_TARGET_MM):
            raise SettingError("target_mm", f"must be a finite number in (0, "
                               f"{MAX_TARGET_MM:g}] (mm), got {t!r}")
        c = self.confidence
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not 0 < c < 1:
            raise SettingError("confidence", f"must be a number in (0, 1), got {c!r}")
        low = minimum_poses(2)
        pool = _int_in("pool", self.pool, low, MAX_POOL)
        mx = _int_in("max_poses", self.max_poses, low, pool, "pool")
        _int_in("region", self.region, 1, pool, "pool")
        if self.bootstrap is not None:
            _int_in("bootstrap", self.bootstrap, low, mx, "max_poses")

    def bootstrap_poses(self, bodies: int = 2) -> int:
        """The number of bootstrap poses: ``bootstrap``, or minimum_poses(bodies) + 1 (one
        more than the minimum, so that the first fit has residual degrees of freedom to
        estimate the noise level from), at most ``max_poses``."""
        b = minimum_poses(bodies) + 1 if self.bootstrap is None else self.bootstrap
        return min(b, self.max_poses)


@dataclass
class Prediction:
    """The predicted coil-placement error of a calibration over the region.

    ``coil_mm``: the ``confidence`` quantile of the mean over the region of the coil-centre
    placement error (mm); ``sigma_mm``: its RMS over the region and the parameter error (mm);
    ``n_poses``; ``calibration``: the Calibration whose placement is predicted (the ``ml``
    one, or the ``placed`` one of :func:`predict`); ``reference``: the ``ml`` Calibration
    whose covariance the prediction propagates when it is not ``calibration`` (else None).
    For :func:`choose_next`:
    ``problem`` (ml's Problem at the estimate), ``covariance`` (unscaled, the inverse of the
    whitened information), ``variance_factor`` and ``dof`` (its scale and degrees of
    freedom), ``region_q`` (Q = mean_r J_rᵀ J_r, the region's placement Jacobians J_r (3×k)),
    ``noise`` (robot σ mm, robot σ rad per axis, as ml estimated them, and the mean tracker
    covariance per body (m, 6, 6)); ``draws_mm``: the Monte Carlo draws of the mean placement
    error behind ``coil_mm``; ``model_error_mm``: the RMS of the robot's per-pose error at
    a target when it counts as model error (0 when it does not; :func:`predict`)."""

    coil_mm: float
    sigma_mm: float
    confidence: float
    n_poses: int
    calibration: Calibration
    problem: Problem
    covariance: np.ndarray
    variance_factor: float
    dof: int
    region_q: np.ndarray
    noise: tuple[float, float, np.ndarray]
    draws_mm: np.ndarray
    model_error_mm: float = 0.0
    reference: Calibration | None = None

    def quantile(self, q: float) -> float:
        """The predicted mean coil-placement error over the region (mm) at confidence q."""
        return float(np.quantile(self.draws_mm, q))

    @property
    def criterion_mm2(self) -> float:
        """Expected mean-square coil-placement error over the region (mm²):
        mean_r tr(J_r Σ J_rᵀ), Σ the scaled covariance."""
        return float(self.variance_factor * np.sum(self.covariance * self.region_q))

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary: predicted_coil_mm, sigma_mm, confidence, n_poses, the fit's
        variance factor and residual degrees of freedom, the distortion model, the robot's
        noise as ml estimated it (robot_sigma_mm per component, robot_sigma_deg per axis)
        and the model error's RMS (model_error_mm)."""
        return {"predicted_coil_mm": self.coil_mm, "sigma_mm": self.sigma_mm,
                "confidence": self.confidence, "n_poses": self.n_poses,
                "variance_factor": self.variance_factor, "dof": self.dof,
                "distortion": self.problem.model, "robot_sigma_mm": self.noise[0],
                "robot_sigma_deg": float(np.degrees(self.noise[1])),
                "model_error_mm": self.model_error_mm}


def bootstrap_indices(pool: np.ndarray, k: int, p0: np.ndarray) -> list[int]:
    """k well-spread pool indices (pool: (n, 4, 4) base_from_flange mm; p0 4×4 mm).

    Rule (deterministic): greedy farthest point in a combined distance d² = (Δt / s_t)² +
    (Δθ / s_θ)², Δt the distance between flange origins (mm), Δθ the rotation angle between
    them (rad), s_t and s_θ the RMS offset and RMS rotation of the pool from P0 (so a pool's
    translations and rotations weigh alike). The first pose is the one farthest from P0, each
    next one maximises its distance to the nearest pose already chosen; ties go to the lower
    index."""
    pool = np.asarray(pool, dtype=float)
    p0 = np.asarray(p0, dtype=float)
    n = len(pool)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= n:
        raise ValueError(f"bootstrap_indices: k must be an integer in 1..{n}, got {k!r}")
    t = pool[:, :3, 3]
    s_t = float(np.sqrt(np.mean(np.sum((t - p0[:3, 3]) ** 2, axis=1)))) or 1.0
    s_r = float(np.sqrt(np.mean(angle_between(p0, pool) ** 2))) or 1.0

    def dist(ref: np.ndarray) -> np.ndarray:
        dt = np.linalg.norm(t - ref[:3, 3], axis=1) / s_t
        return np.sqrt(dt ** 2 + (angle_between(ref, pool) / s_r) ** 2)

    nearest = dist(p0)
    chosen: list[int] = []
    for _ in range(k):
        i = int(np.argmax(np.where(np.isin(np.arange(n), chosen), -np.inf, nearest)))
        chosen.append(i)
        nearest = dist(pool[i]) if len(chosen) == 1 else np.minimum(nearest, dist(pool[i]))
    return chosen


def _ml_defaults() -> dict[str, Any]:
    """ml's own defaults of its noise options (one place: ml_solve's signature)."""
    sig = inspect.signature(ml_solve).parameters
    keys = ("robot_sigma_mm", "robot_sigma_deg", "tracker_sigma_mm", "tracker_sigma_deg",
            "tracker_cov", "spreads")
    return {k: sig[k].default for k in keys}


def _problem_of(cal: Calibration, A: np.ndarray, bodies: list[np.ndarray]) -> Problem:
    """ml's Problem re-centred at the calibration's estimate (θ = 0 is the estimate)."""
    d = cal.distortion or {}
    model = d.get("model", "none")
    G = np.asarray(d.get("undistort", np.eye(3)), dtype=float)
    if len(bodies) == 1:
        Ws = [cal.X]
    elif cal.Y is None:  # predict checks it first: a marker-only calibration has no probe
        raise CalibrationError("a marker-only calibration (no Y) with probe poses")
    else:
        Ws = [cal.X, cal.Y]
    tm = d.get("tool_moments") or {}
    moments = [tm.get(nm) for nm in ("marker", "probe")[:len(bodies)]]
    return Problem(A, bodies, Ws, cal.Z, model, g_of(model, G), moments)


def placement_jacobians(prob: Problem, region: np.ndarray) -> np.ndarray:
    """Jacobians (R, 3, k) of the coil-centre placement error (mm, base frame) with respect to
    ml's parameters, at the estimate, for the flange poses ``region`` (R, 4, 4) mm.

    The robot is told to put the coil at the tracker pose N_r that the estimate gives for
    P_r (Ñ_r = Ẑ⁻¹ P_r Ŷ undistorted, N_r as measured), commands Z Ñ_r Y⁻¹ and the coil
    lands at t(Z Ñ_r Y⁻¹ Ŷ) if (Y, Z, G) are the truth; to first order (the error model of
    ``calib.bound``, analytically): ∂/∂ω_Z = −R̂_Z [t(Ñ_r)]×, ∂/∂t_Z = I, ∂/∂t_Y = −R(P_r),
    ∂/∂g_i = R̂_Z (∂G/∂g_i) t(N_r); X and Y's rotation do not move the coil centre."""
    k, m = prob.n_params, len(prob.Ws)
    Ws, Z, G = prob.unpack(np.zeros(k))
    Nt = invert(Z)[None] @ region @ Ws[-1][None]  # undistorted targets Ñ_r
    tn = Nt[:, :3, 3]
    J = np.zeros((len(region), 3, k))
    RZ = Z[:3, :3]
    jz = 6 * m
    J[:, :, jz:jz + 3] = -RZ[None] @ skew(tn)
    J[:, :, jz + 3:jz + 6] = np.eye(3)
    jy = 6 * (m - 1)
    J[:, :, jy + 3:jy + 6] = -region[:, :3, :3]
    ng = k - 6 * (m + 1)
    if ng:
        t_meas = tn @ np.linalg.inv(G).T
        for i in range(ng):
            e = np.zeros(ng)
            e[i] = 1.0
            dG = undistortion(prob.model, e) - np.eye(3)
            J[:, :, jz + 6 + i] = t_meas @ (RZ @ dG).T
    return J


def _factor_draws(cal: Calibration, rng: np.random.Generator, n: int
                  ) -> dict[str, np.ndarray]:
    """Per variance component of ml's covariance (``extra["covariance_parts"]``) draws (n,)
    of the factor on its standard deviations. A component estimated from the residuals
    (REML, ν effective degrees of freedom, tmscal.calib.variance) is uncertain itself:
    σ²_draw = σ̂² ν / χ²_ν, ν at least 1 (a Student-t-like spread that keeps the prediction
    honest at the bootstrap's few poses). With the noise as given and the covariance scaled
    by the variance factor (ν = m − k residual degrees of freedom), one draw of that form is
    shared by every component; with the noise as given and unscaled, 1."""
    noise = cal.extra["noise"]
    names = list(cal.extra["covariance_parts"])
    if noise.get("scale_covariance"):
        k = len(cal.extra["parameters"])
        nu = max(int(cal.extra["residuals"]) - k, 1)
        f = np.sqrt(nu / rng.chisquare(nu, n))
        return {c: f for c in names}
    out = {}
    for c in names:
        nu = noise.get("dof", {}).get(c)
        out[c] = np.ones(n) if nu is None else np.sqrt(max(nu, 1.0)
                                                        / rng.chisquare(max(nu, 1.0), n))
    return out


def predict(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, region: np.ndarray,
            settings: AdaptiveSettings, model_error: bool = False,
            calibration: Calibration | None = None, placed: Calibration | None = None,
            **ml_options: Any) -> Prediction:
    """Solve QR36 then ``ml`` on the poses so far (A, B, C: (n, 4, 4) mm; C None for a
    marker-only rig, then the marker is the body placed) and predict the coil-placement error
    over ``region`` (flange poses (R, 4, 4) mm where the rig will place coils).

    ``ml_options`` go to ``ml`` (e.g. ``spreads`` from the session); ``distortion`` defaults
    to :data:`PREDICTION_DISTORTION` ("scale") here: the model is fixed (not chosen by ml's
    test, which at a dozen poses inside the plan's envelope cannot yet separate a 0.1 %
    scale from Z and the noise, and a model switching between steps would make the
    predictions jump), and it includes the scale, so that an unmodelled tracker scale
    cannot make the prediction optimistic: its uncertainty is part of ml's covariance and
    of the prediction (without a scale, about 0.1 % of the envelope's extent went unseen,
    docs/methods.md); pass ``distortion`` to override. ml estimates the robot's rotation and
    translation noise from the residuals (its default ``noise="estimate"``). The parameter
    error is δθ = Σ_k f_k δθ_k, δθ_k ~ N(0, P_k) the part of ml's covariance of each noise
    component and f_k its factor drawn as in :func:`_factor_draws`; e_r = J_r δθ
    (:func:`placement_jacobians`). ``model_error`` (the rig's arm kinematics are not
    modelled, so the robot's per-pose error the residuals show recurs where the coil is
    placed): e_r += R(P_r) (f_t σ_t z + f_r σ_r (w × t_Y)), z, w ~ N(0, I) per target,
    σ_t, σ_r the robot's estimated translation (mm) and rotation (rad per axis) noise.
    ``coil_mm`` is the ``settings.confidence`` quantile of mean_r ‖e_r‖ over
    :data:`MC_DRAWS` draws with a fixed seed, ``sigma_mm`` the RMS of e_r. CalibrationError
    when the poses do not determine the calibration, or for probe poses ``C`` with a
    marker-only ``calibration`` (no Y).

    ``calibration``: an ``ml`` Calibration already solved on these poses with these
    ``ml_options`` (it is not solved again; its own distortion model is the prediction's).
    ``placed``: predict the placement of this calibration instead (any method, e.g. QR36,
    which has no error model of its own): its placement offset from the ml estimate,
    :func:`placement_offsets` d_r (where ``placed`` puts the coil if ml's estimate were the
    truth), is added to every draw, e_r = d_r + J_r δθ (+ the model error): the error of
    ``placed`` is its difference from ml's estimate plus ml's own error. ``placed`` with an
    identified arm is taken in the frame of A (its commands before the arm's conversion to
    the controller's, so A must be the poses of that arm)."""
    opts = {"distortion": PREDICTION_DISTORTION, **ml_options}
    if calibration is None:
        cal = solve(A, B, C, method="ml", **opts)
    elif (calibration.method != "ml" or calibration.arm is not None
          or "covariance_parts" not in calibration.extra):
        raise CalibrationError(f"predict: calibration must be an ml solve without an arm, got "
                               f"{calibration.method}"
                               f"{' with an arm' if calibration.arm is not None else ''}")
    else:
        cal = calibration
    W = cal.X if C is None else cal.Y  # flange ← the body placed
    if W is None:
        raise CalibrationError("predict: probe poses C given with a marker-only calibration "
                               "(no Y): nothing to place the coil with")
    bodies = [np.asarray(B, dtype=float)] + ([] if C is None else [np.asarray(C, dtype=float)])
    A = np.asarray(A, dtype=float)
    prob = _problem_of(cal, A, bodies)
    k = prob.n_params
    nz = cal.extra["noise"]
    vf = float(cal.extra["variance_factor"])
    scaled = bool(nz["scale_covariance"])
    P = np.asarray(cal.covariance, dtype=float) / (vf if scaled and vf > 0 else 1.0)
    if scaled and vf <= 0:
        P = np.zeros_like(P)
    dof = int(cal.extra["residuals"]) - k
    region = np.asarray(region, dtype=float).reshape(-1, 4, 4)
    J = placement_jacobians(prob, region)
    Q = np.einsum("rik,ril->kl", J, J) / len(region)
    rng = np.random.default_rng(0)
    f = _factor_draws(cal, rng, MC_DRAWS)
    d = np.zeros((MC_DRAWS, k))
    for c, Pc in cal.extra["covariance_parts"].items():
        w, V = np.linalg.eigh((Pc + Pc.T) / 2)
        root = V * np.sqrt(np.clip(w, 0.0, None))
        d += f[c][:, None] * (rng.standard_normal((MC_DRAWS, k)) @ root.T)
    e = (J.reshape(-1, k) @ d.T).reshape(len(region), 3, -1)
    v = vf if scaled else 1.0
    var_offset = 0.0
    if placed is not None and placed is not cal:
        off = placement_offsets(placed, cal, region)
        e = e + off[:, :, None]
        var_offset = float(np.mean(np.sum(off ** 2, axis=1)))
    sig_t = float(nz["robot_sigma_mm"])
    sig_r = float(np.radians(nz["robot_sigma_deg"]))
    var_model = 0.0
    if model_error:
        tY = W[:3, 3]
        z = rng.standard_normal((len(region), 3, MC_DRAWS)) * (sig_t * f["robot_trans"])
        wv = rng.standard_normal((len(region), 3, MC_DRAWS)) * (sig_r * f["robot_rot"])
        m = z + np.cross(wv, tY[None, :, None], axis=1)
        e = e + region[:, :3, :3] @ m
        var_model = 3 * sig_t ** 2 + 2 * sig_r ** 2 * float(tY @ tY)
    draws = np.linalg.norm(e, axis=1).mean(0)
    coil = float(np.quantile(draws, settings.confidence))
    names = ["marker", "probe"][:len(bodies)]
    o = {**_ml_defaults(), **opts}
    tracker = tracker_covs(len(A), names, o).mean(axis=0) * float(nz["tracker_factor"])
    noise = (sig_t, sig_r, tracker)
    shown = cal if placed is None else placed
    other = shown is not cal
    return Prediction(coil_mm=coil,
                      sigma_mm=float(np.sqrt(max(v, 0.0) * np.sum(P * Q) + var_model
                                             + var_offset)),
                      confidence=settings.confidence, n_poses=len(A),
                      calibration=shown,
                      problem=prob, covariance=P, variance_factor=v, dof=dof, region_q=Q,
                      noise=noise, draws_mm=draws,
                      model_error_mm=float(np.sqrt(var_model)),
                      reference=cal if other else None)


def placement_offsets(placed: Calibration, reference: Calibration, region: np.ndarray
                      ) -> np.ndarray:
    """Where ``placed`` puts the coil centre, minus where it was wanted, if ``reference``'s
    estimate (its Y, Z and tracker distortion D) were the truth: (R, 3) mm in the robot's
    base frame, one row per flange pose of ``region`` (R, 4, 4 base_from_flange mm). The
    targets are the tracker poses the reference gives there, N_r = Ẑ⁻¹ P_r Ŷ, as its tracker
    measures them (D applied, as :func:`true_coil_error` does); ``placed`` commands them
    (``Calibration.flange_command``; an identified arm of ``placed`` is left out: the offsets
    are in the frame of the poses both were solved on) and the coil lands at A_cmd Ŷ where
    P_r Ŷ was wanted. CalibrationError for a marker-only calibration."""
    if placed.Y is None or reference.Y is None:
        raise CalibrationError("a marker-only calibration has no coil (Y): it cannot place "
                               "the coil")
    P = np.asarray(region, dtype=float).reshape(-1, 4, 4)
    Yr, Zr = np.asarray(reference.Y, dtype=float), np.asarray(reference.Z, dtype=float)
    N = invert(Zr)[None] @ P @ Yr[None]
    D = (reference.distortion or {}).get("matrix")
    N_meas = N if D is None else undistort(N, np.asarray(D, dtype=float), "affine")
    flat = placed if placed.arm is None else dataclasses.replace(placed, arm=None)
    landed = flat.flange_command(N_meas) @ Yr[None]
    return landed[:, :3, 3] - (P @ Yr[None])[:, :3, 3]


def residual_jacobians(prob: Problem, poses: np.ndarray) -> np.ndarray:
    """Raw Jacobians (n, 6m, k) of ml's residuals (per body [rotation vector rad; translation
    mm], :meth:`Problem.residuals`) at the estimate, for one more pose at each flange pose of
    ``poses`` (n, 4, 4) mm, measured where the estimate puts the bodies, Ñ = Ẑ⁻¹ P Ŵ (so
    E = (P W)⁻¹ Z Ñ = I). Without a distortion, analytically: for body j, ∂r/∂ω_W = [−I; 0],
    ∂r/∂t_W = [0; −R̂_Wᵀ], ∂r/∂ω_Z = [R_Ñᵀ; −R_Ñᵀ [t_Ñ]×], ∂r/∂t_Z = [0; R_Ñᵀ R̂_Zᵀ]. With a
    distortion, by ml's analytic Jacobian (:meth:`Problem.raw_jacobian`), the positions of
    Ñ distorted to first order by Ĝ⁻¹."""
    k, m = prob.n_params, len(prob.Ws)
    Ws, Z, G = prob.unpack(np.zeros(k))
    N = [invert(Z)[None] @ poses @ W[None] for W in Ws]
    if prob.model != "none":
        for Nj in N:
            Nj[:, :3, 3] = Nj[:, :3, 3] @ np.linalg.inv(G).T
        cand = Problem(poses, N, prob.Ws, prob.Z0, prob.model, prob.g0, prob.moments)
        return cand.raw_jacobian()
    J = np.zeros((len(poses), 6 * m, k))
    for j, (W, Nj) in enumerate(zip(Ws, N, strict=True)):
        r = 6 * j
        RNt = np.swapaxes(Nj[:, :3, :3], 1, 2)
        J[:, r:r + 3, r:r + 3] = -np.eye(3)
        J[:, r + 3:r + 6, r + 3:r + 6] = -W[:3, :3].T
        J[:, r:r + 3, 6 * m:6 * m + 3] = RNt
        J[:, r + 3:r + 6, 6 * m:6 * m + 3] = -RNt @ skew(Nj[:, :3, 3])
        J[:, r + 3:r + 6, 6 * m + 3:6 * m + 6] = RNt @ Z[:3, :3].T
    return J


def candidate_information(pred: Prediction, poses: np.ndarray) -> np.ndarray:
    """Fisher information (n, k, k) one more pose at each of ``poses`` (n, 4, 4
    base_from_flange mm) would add, in the units of ``pred.covariance`` (unscaled): J_cᵀ J_c,
    J_c the whitened Jacobian of ml's residuals at the estimate for the tracker poses the
    estimate predicts there (:func:`residual_jacobians`), whitened with ml's noise model
    (robot σ, the session's mean tracker covariance)."""
    prob = pred.problem
    Ws = prob.unpack(np.zeros(prob.n_params))[0]
    rs_mm, rs_rad, tracker = pred.noise
    Li = whitener(noise_covariance(Ws, rs_mm, rs_rad, tracker[None]))
    Jc = Li[None] @ residual_jacobians(prob, np.asarray(poses, dtype=float))
    return np.swapaxes(Jc, 1, 2) @ Jc


def _criteria(pred: Prediction, info: np.ndarray) -> np.ndarray:
    """mean_r tr(J_r Σ' J_rᵀ) (mm²) for Σ' = vf (P⁻¹ + I_c)⁻¹, per candidate information
    I_c (n, k, k); in the correlation scaling of P, by batched solves."""
    P = pred.covariance
    dsc = np.sqrt(np.clip(np.diag(P), 1e-300, None))
    Pn = P / np.outer(dsc, dsc)
    Fn = np.linalg.pinv((Pn + Pn.T) / 2, hermitian=True)
    M = Fn[None] + info * np.outer(dsc, dsc)[None]
    Qn = pred.region_q * np.outer(dsc, dsc)
    X = np.linalg.solve(M, np.broadcast_to(Qn, M.shape))
    return pred.variance_factor * np.trace(X, axis1=1, axis2=2)


def choose_next(pred: Prediction, pool: np.ndarray, available: np.ndarray,
                cost_s: np.ndarray) -> tuple[int, dict[str, float]]:
    """The pool index (pool: (n, 4, 4) base_from_flange mm) with the largest expected
    reduction of the mean-square coil-placement error over the region per second of robot
    time ``cost_s`` (n,) s (travel from where the arm is + settle + sampling), among the
    ``available`` (n,) bool candidates. The criterion is L-optimal (c-optimal on the coil
    centre, averaged over the region): φ(Σ) = mean_r tr(J_r Σ J_rᵀ), Σ' = (Σ⁻¹ + I_c)⁻¹ after
    one more pose at the candidate (:func:`candidate_information`), gain = φ(Σ) − φ(Σ').

    Returns (index, {"gain_mm2", "cost_s", "gain_per_s", "criterion_mm2" (φ after),
    "rms_after_mm" (√φ after), "rms_now_mm"}). ValueError for mismatched shapes, no available
    candidate, or a cost that is not finite and > 0."""
    pool = np.asarray(pool, dtype=float)
    avail = np.asarray(available, dtype=bool)
    cost = np.asarray(cost_s, dtype=float)
    if avail.shape != (len(pool),) or cost.shape != (len(pool),):
        raise ValueError(f"choose_next: available {avail.shape} and cost_s {cost.shape} must "
                         f"be ({len(pool)},) like the pool")
    idx = np.flatnonzero(avail)
    if not len(idx):
        raise ValueError("choose_next: no candidate pose is available")
    if not np.all(np.isfinite(cost[idx]) & (cost[idx] > 0)):
        raise ValueError("choose_next: cost_s must be finite and > 0 s for every available "
                         "candidate")
    now = pred.criterion_mm2
    after = _criteria(pred, candidate_information(pred, pool[idx]))
    gain = now - after
    rate = gain / cost[idx]
    j = int(np.argmax(rate))
    i = int(idx[j])
    return i, {"gain_mm2": float(gain[j]), "cost_s": float(cost[i]),
               "gain_per_s": float(rate[j]), "criterion_mm2": float(after[j]),
               "rms_after_mm": float(np.sqrt(max(after[j], 0.0))),
               "rms_now_mm": float(np.sqrt(max(now, 0.0)))}


def stop_reason(pred: Prediction | None, n_poses: int, settings: AdaptiveSettings
                ) -> str | None:
    """"target" when the predicted error ``pred.coil_mm`` is at or below
    ``settings.target_mm``, else "max_poses" when ``n_poses`` ≥ ``settings.max_poses``, else
    None (go on). ``pred`` None (no prediction yet) stops only at max_poses."""
    if pred is not None and pred.coil_mm <= settings.target_mm:
        return "target"
    if n_poses >= settings.max_poses:
        return "max_poses"
    return None


def candidate_cost_s(current: np.ndarray, pool: np.ndarray, speed_mm_s: float,
                     accel_mm_s2: float, per_pose_s: float | np.ndarray = 0.0,
                     rot_speed_deg_s: float | None = None,
                     rot_accel_deg_s2: float | None = None) -> np.ndarray:
    """Robot time (s) per pool pose (n,): the straight move from ``current`` (base_from_flange
    4×4 mm) under the speed and acceleration caps, as :func:`tmscal.motion.move_duration`
    times it (the longer of the translation and, with rotation caps, the rotation profile;
    the one motion model, through ``trapezoid_duration``), + ``per_pose_s`` (settle +
    sampling, s; a number or (n,))."""
    pool = np.asarray(pool, dtype=float)
    cur = np.asarray(current, dtype=float)
    d = np.linalg.norm(pool[:, :3, 3] - cur[:3, 3], axis=1)
    t = np.array([trapezoid_duration(x, speed_mm_s, accel_mm_s2) for x in d])
    if rot_speed_deg_s is not None and rot_accel_deg_s2 is not None:
        ang = np.degrees(angle_between(cur, pool))
        t = np.maximum(t, [trapezoid_duration(x, rot_speed_deg_s, rot_accel_deg_s2)
                           for x in ang])
    return t + np.asarray(per_pose_s, dtype=float)


def true_coil_error(cal: Calibration, truth_Y: np.ndarray, truth_Z: np.ndarray,
                    region_flange_poses: np.ndarray, reached: Any = None,
                    tracker_distortion: Any = None) -> float:
    """Mean coil-placement error (mm) of ``cal`` over the region against a known truth: the
    targets are where the coil is when the flange is at each region pose, C_i = Z⁻¹ P_i Y
    (true Y, Z; tracker_from_probe), commanded with ``Calibration.flange_command`` and
    measured by ``calib.metrics.placement_errors``; ``reached`` (a callable, e.g. the
    controller of a simulated rig's true arm) says where the flange really goes for the
    commands (default: exactly there). ``tracker_distortion`` (D, 3×3: the tracker measures
    a position p as D p, as ``tmscal.sim.Noise`` simulates it): the targets are commanded as
    that tracker measures them (positions D t, orientations as its rigid fit distorts them,
    ``ml_model.undistort`` with D), and the error is against where they really are."""
    P = np.asarray(region_flange_poses, dtype=float).reshape(-1, 4, 4)
    Yt, Zt = np.asarray(truth_Y, dtype=float), np.asarray(truth_Z, dtype=float)
    C = invert(Zt)[None] @ P @ Yt[None]
    C_meas = C if tracker_distortion is None else \
        undistort(C, np.asarray(tracker_distortion, dtype=float), "affine")
    return float(placement_errors(cal.flange_command(C_meas), C, Yt, Zt, reached).mean())
