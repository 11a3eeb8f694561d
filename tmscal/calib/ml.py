"""Maximum-likelihood calibration on SE(3) with an optional tracker distortion (``ml``).

Frames and units as everywhere (docs/conventions.md): A = base_from_flange, B =
tracker_from_marker, C = tracker_from_probe, X = flange_from_marker, Y = flange_from_probe,
Z = base_from_tracker; 4×4, mm.

Model. The robot's flange really sits at A_i δ_i (δ_i a small rigid error, rotation vector
N(0, σ_r² I) rad in the flange frame, translation N(0, σ_t² I) mm), and the tracker reports
each body with an error ε in the body frame (rotation and translation, covariance Σ_ε, 6×6).
The tracker may be distorted: a 3×3 map D acts on tracker-frame positions (measured = D ·
true) and the tracker fits each tool rigidly to its distorted fiducials, so a measured pose
is undone by G = D⁻¹ (:func:`undistort`). Per pose and body the residual is

    E = (A_i W)⁻¹ Z Ñ_i,  r = [log R(E) (rad); t(E) (mm)]   (W = X or Y, Ñ undistorted)

and to first order r = Ad-like(W) δ + ε, so the residuals of one pose (marker and probe share
δ) have the covariance S = J_W Σ_δ J_Wᵀ + blockdiag(Σ_ε), which whitens them. ``ml``
minimises Σ r_iᵀ S_i⁻¹ r_i by Levenberg–Marquardt, started from QR36 (QR24 on marker-only
data): the Jacobian analytic for X, Y, Z and the distortion (:meth:`Problem.raw_jacobian`),
its column-scaled normal matrix factorised once per
iteration (every damping tried is then a product). D is "none", "scale" (isotropic), "axis"
(per-axis scale) or "affine" (symmetric 3×3: per-axis scale and shear; a rotation part of D
would turn positions and orientations alike and is Z's rotation, so it is not identifiable
and not a parameter).

Model selection ("auto", the default): the rigid model is fitted, then each distortion model
with the same noise weights, and a distortion is kept only when an F test says it lowers χ²
more than noise would (:func:`select_model`: forward none → scale → axis → affine, each step
at level ``ALPHA`` = 1 %; F = (Δχ²/Δk) / (χ²/(m − k)) against F(Δk, m − k), the
likelihood-ratio test with the noise level profiled out in its exact small-sample form for
a linear Gaussian model). Under no distortion the three tests together rarely choose one;
AIC (``criterion="aic"``: m ln(χ²/m) + 2k), whose penalty amounts to a test at about 16 % per
parameter (P(χ²₁ > 2)), chose one far more often on small sessions (issue 21), and BIC
(``"bic"``, + k ln m) is kept for comparison. ``benchmarks/ml_selection.py`` prints how often
each is chosen with and without a 0.1 % tracker scale, the coil placement against QR36 and
the solve time (docs/methods.md).

Noise. The robot's rotation σ (per axis of the rotation vector) and translation σ (per
component) are estimated from the residuals by default (``noise="estimate"``): restricted
maximum likelihood of the variance components (:mod:`tmscal.calib.variance`, which says why
the residuals and not the robot's own reads), on the model linearised at the QR36 start, then
the fit with those weights, then once more at the estimate. The tracker's noise comes from
the session's sample spreads (``spreads``: one session pose record per pose, with "spread"
{body: {trans_mm, rot_deg}} and "samples"; σ = spread / √3 / √samples per component) or
``tracker_cov`` (6×6, body frame, [rot rad; trans mm]) when given; otherwise from
``tracker_sigma_mm`` / ``tracker_sigma_deg`` (per component of the tracked pose) times a
level that is estimated with the robot's. ``robot_sigma_mm`` and ``robot_sigma_deg`` only
start the estimate (defaults 0.05 mm, 0.03° per axis: the simulated rig's; Wang et al. 2018).
The covariance is then (Jᵀ S⁻¹ J)⁻¹ at the estimated noise, split by component in
``extra["covariance_parts"]`` (their sum), with each component's effective degrees of
freedom in ``extra["noise"]["dof"]``. ``noise="given"`` takes every σ as given and, with
``scale_covariance=True``, multiplies the covariance by the a-posteriori variance factor
χ²/(m − k) (the behaviour before issue 21).

``tools_mm`` (the tools' fiducials, (k, 3) mm, one array or {body: array}) lets the
orientation be undistorted as the tracker's rigid fit distorts it (:func:`undistort`); without
it the tool is taken as isotropic.

Parameters (``extra["parameters"]``): per transform X, (Y,) Z, a rotation vector ω (rad) on
the right, R = R̂ exp([ω]×), and a translation offset (mm, parent frame); then the
distortion's undistortion parameters g (dimensionless; G = I + …).
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CalibrationError
from ..geometry import make_pose, orthonormalize
from .bound import uncertainty_at
from .calibration import Applied, Calibration
from .lsq import Solution
from .lsq import levenberg_marquardt as levenberg_marquardt_core
from .methods import register_method, solve
from .ml_model import (
    DISTORTION_MODELS,
    Problem,
    check_sigma,
    covariance_from_jacobian,
    parameter_names,
    robot_parts,
    tool_moment,
    tracker_covs,
    tracker_part,
    whitener,
)
from .variance import COMPONENTS, Components, estimate_components

__all__ = ["ml_solve", "fit_model", "Fit", "levenberg_marquardt", "select_model",
           "NOISE_MODES", "CRITERIA", "ALPHA"]

#: how ml sets the noise: estimated from the residuals (default) or as given
NOISE_MODES = ("estimate", "given")
#: the model-selection rules of distortion "auto"
CRITERIA = ("lrt", "aic", "bic")
#: the level of each F test of the forward selection (criterion "lrt")
ALPHA = 0.01


def _whitened(whiten: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Whitened Jacobian (n·q, k) of a raw one (n, q, k)."""
    Jw = (whiten[None] if whiten.ndim == 2 else whiten) @ J
    return Jw.reshape(-1, J.shape[-1])


def _wres(whiten: np.ndarray, r: np.ndarray) -> np.ndarray:
    return (r @ whiten.T if whiten.ndim == 2 else np.einsum("nij,nj->ni", whiten, r)).ravel()


def levenberg_marquardt(prob: Problem, whiten: np.ndarray, max_iter: int = 50
                        ) -> tuple[Problem, int]:
    """Minimise the whitened χ² from the problem's start with the one least-squares loop
    (:func:`tmscal.calib.lsq.levenberg_marquardt`); returns (the problem re-centred at the
    estimate, iterations)."""
    sol = _minimise(prob, whiten, max_iter)
    return sol.state, sol.iterations


def _minimise(prob: Problem, whiten: np.ndarray, max_iter: int) -> Solution[Problem]:
    """:func:`levenberg_marquardt` with the whole solution (residuals and whitened Jacobian
    at the estimate, so that the fit does not evaluate them again). The analytic Jacobian
    (:meth:`Problem.raw_jacobian`) at each estimate. Converged when χ² falls by less than
    1e-10 of itself (far below any difference the model selection's tests or the covariance
    could notice) or the scaled step is negligible."""
    zero = np.zeros(prob.n_params)

    def evaluate(p: Problem, jac: bool) -> tuple[np.ndarray, np.ndarray | None]:
        return _wres(whiten, p.residuals(zero)), \
            (_whitened(whiten, p.raw_jacobian()) if jac else None)

    sol = levenberg_marquardt_core(evaluate, prob, lambda p, dx: p.recentred(dx),
                                   max_iter=max_iter, ftol=1e-10,
                                   xtol=1e-12 * np.sqrt(prob.n_params))
    return sol


@dataclass
class Fit:
    """One fitted model: the problem re-centred at the estimate (θ = 0), the whitened
    Jacobian there, the covariance (noise as weighted), χ², counts, and the noise factors it
    was weighted with (``theta``: robot rotation rad², robot translation mm², tracker factor)."""

    prob: Problem
    J: np.ndarray
    P: np.ndarray
    chi2: float
    m: int
    iterations: int
    theta: np.ndarray | None = None

    def criterion(self, name: str) -> float:
        """The information criterion ("aic" or "bic") with the noise level profiled out:
        m ln(χ²/m) + 2k (AIC) or + k ln m (BIC)."""
        k = self.prob.n_params
        fit = self.m * np.log(max(self.chi2 / self.m, 1e-30))
        return fit + (2.0 * k if name == "aic" else k * np.log(self.m))


def _covariance(Ws: list[np.ndarray], theta: np.ndarray, T: np.ndarray, n: int
                ) -> np.ndarray:
    """The residual covariance per pose (n, q, q) of the noise factors ``theta``."""
    Qr, Qt = robot_parts(Ws)
    S = theta[0] * Qr + theta[1] * Qt + theta[2] * T
    return np.broadcast_to(S, (n,) + S.shape[-2:])


def _residual_count(prob: Problem) -> int:
    """m, the number of residuals; CalibrationError when the model has as many parameters."""
    m = prob.A.shape[0] * 6 * len(prob.bodies)
    if prob.n_params >= m:
        raise CalibrationError(f"distortion model {prob.model!r} has {prob.n_params} "
                               f"parameters but {prob.A.shape[0]} poses give only {m} "
                               "residuals")
    return m


def _fit(prob: Problem, theta: np.ndarray, T: np.ndarray, max_iter: int) -> Fit:
    """Fit ``prob`` with the noise factors ``theta`` (the robot's part carried through the
    start's X, Y)."""
    m = _residual_count(prob)
    whiten = whitener(_covariance(prob.Ws, theta, T, len(prob.A)))
    sol = _minimise(prob, whiten, max_iter)
    J = sol.jacobian if sol.jacobian is not None else _whitened(whiten, sol.state.raw_jacobian())
    P = covariance_from_jacobian(J, f"the ml model (distortion {sol.state.model!r})")
    return Fit(sol.state, J, P, sol.cost, m, sol.iterations, theta.copy())


def _components(prob: Problem, theta: np.ndarray, T: np.ndarray, estimate: np.ndarray
                ) -> Components:
    """The variance components at the problem's start
    (:func:`tmscal.calib.variance.estimate_components`, the model linearised there)."""
    Qr, Qt = robot_parts(prob.Ws)
    return estimate_components(prob.raw_jacobian(), prob.residuals(np.zeros(prob.n_params)),
                               [Qr, Qt, T], theta, estimate,
                               max_iter=60 if estimate.any() else 0)


def fit_model(prob: Problem, theta: np.ndarray, T: np.ndarray, estimate: np.ndarray,
              max_iter: int = 50) -> tuple[Fit, Components]:
    """Fit one problem with the noise: from the factors ``theta`` (robot rotation rad² per
    axis, robot translation mm² per component, tracker factor on ``T`` (n, q, q)), those
    flagged in ``estimate`` estimated from the residuals by REML on the model linearised at
    the start (its weighted least-squares step included), the fit with those, and the
    components once more at the estimate (returned with the fit). With none flagged: the
    fit, then the fit again with the noise carried through the estimate's X, Y (as the
    start's may be far off)."""
    _residual_count(prob)
    if estimate.any():
        theta = _components(prob, theta, T, estimate).theta
        fit = _fit(prob, theta, T, max_iter)
        return fit, _components(fit.prob, theta, T, estimate)
    fit = _fit(prob, theta, T, max_iter)
    its = fit.iterations
    fit = _fit(fit.prob, theta, T, max_iter)
    fit.iterations += its
    return fit, _components(fit.prob, theta, T, estimate)


def select_model(fits: dict[str, Fit], criterion: str, alpha: float = ALPHA
                 ) -> tuple[str, dict[str, float]]:
    """The distortion model among ``fits`` (fitted with the same noise weights): "lrt" is a
    forward selection by F tests (none → scale → axis → affine, nested: each larger model is
    kept only when it lowers χ² more than noise would at level ``alpha``: F = (Δχ²/Δk) /
    (χ²/(m − k)) against F(Δk, m − k), the exact small-sample form of the likelihood-ratio
    test with the noise level profiled out); "aic"/"bic" keep the smallest information
    criterion. Returns (model, {model: p value of its test, or its criterion})."""
    from scipy.special import fdtrc

    if criterion != "lrt":
        vals = {k: f.criterion(criterion) for k, f in fits.items()}
        return min(vals, key=vals.__getitem__), vals
    cur = "none"
    pvals = {"none": 1.0}
    for model in DISTORTION_MODELS:
        if model == "none" or model not in fits:
            continue
        a, b = fits[cur], fits[model]
        dk = b.prob.n_params - a.prob.n_params
        dof = b.m - b.prob.n_params
        F = max(a.chi2 - b.chi2, 0.0) / dk / max(b.chi2 / dof, 1e-300)
        pvals[model] = float(fdtrc(dk, dof, F))
        if pvals[model] < alpha:
            cur = model
    return cur, pvals


def _select(A: np.ndarray, bodies: list[np.ndarray], start: Problem, distortion: str,
            theta: np.ndarray, T: np.ndarray, estimate: np.ndarray, max_iter: int,
            moments: list[np.ndarray | None], criterion: str
            ) -> tuple[Fit, Components, dict[str, float]]:
    """Fit the requested model, or with "auto" the rigid one, then every identifiable
    distortion from its estimate with its noise weights, and keep the one
    :func:`select_model` chooses (refitted with its own noise estimate); returns (fit,
    components, {model: p value or criterion})."""
    if distortion != "auto":
        prob = Problem(A, bodies, start.Ws, start.Z0, distortion, moments=moments)
        fit, comp = fit_model(prob, theta, T, estimate, max_iter)
        return fit, comp, {}
    fit0, comp0 = fit_model(start, theta, T, estimate, max_iter)
    fits = {"none": fit0}
    w = comp0.theta
    for model in DISTORTION_MODELS:
        if model == "none":
            continue
        try:
            prob = Problem(A, bodies, fit0.prob.Ws, fit0.prob.Z0, model, moments=moments)
            fits[model] = _fit(prob, w, T, max_iter)
        except CalibrationError:
            pass
    fits["none"] = _fit(fit0.prob, w, T, max_iter) if not np.array_equal(w, fit0.theta) \
        else fit0
    chosen, vals = select_model(fits, criterion)
    if chosen == "none":
        return fit0, comp0, vals
    fit, comp = fit_model(fits[chosen].prob, w, T, estimate, max_iter)
    return fit, comp, vals


def _noise(n: int, names: list[str], opts: dict[str, Any]
           ) -> tuple[float, float, np.ndarray]:
    rs_mm = check_sigma("robot_sigma_mm", opts["robot_sigma_mm"])
    rs_rad = np.radians(check_sigma("robot_sigma_deg", opts["robot_sigma_deg"]))
    return rs_mm, rs_rad, tracker_covs(n, names, opts)


def _moments(tools_mm: Any, names: list[str]) -> list[np.ndarray | None]:
    """Per body the tool's second moment from ``tools_mm``: None, one (k, 3) array for every
    body, or {body name: (k, 3)}."""
    if tools_mm is None:
        return [None] * len(names)
    if isinstance(tools_mm, dict):
        return [None if tools_mm.get(nm) is None else tool_moment(tools_mm[nm])
                for nm in names]
    M = tool_moment(tools_mm)
    return [M] * len(names)


@register_method("ml")
def ml_solve(A: np.ndarray, B: np.ndarray, C: np.ndarray | None, orthonormal: bool,
             distortion: str = "auto", robot_sigma_mm: float = 0.05,
             robot_sigma_deg: float = 0.03, tracker_sigma_mm: float = 0.025,
             tracker_sigma_deg: float = 0.05, tracker_cov: Any = None, spreads: Any = None,
             tools_mm: Any = None, criterion: str = "lrt", noise: str = "estimate",
             scale_covariance: bool = True, max_iter: int = 50, kinematics: str | None = None,
             joints: Any = None, arm: Any = None, level: str = "auto", tolerances: Any = None,
             folds: int = 5, wrench: Any = None, wrench_sigma: Any = None,
             progress: Any = None) -> Calibration:
    """Maximum-likelihood X, (Y,) Z with tracker distortion ``distortion`` ("auto": chosen
    by ``criterion``, "lrt" F tests by default; "none", "scale", "axis", "affine"); see the
    module docstring for the model, the noise options and the parameters. ``noise``
    "estimate" (default): the robot's rotation and translation noise (and the tracker's level
    when no ``spreads`` or ``tracker_cov`` give it) from the residuals, the robot sigmas
    only the start; "given": the noise as given, the covariance scaled by the variance
    factor when ``scale_covariance``. The raw matrices carry the distortion (Z_raw = Z · G,
    G = D⁻¹), as QR24's absorb it; ``errors`` undoes it either way.

    ``kinematics="estimate"`` estimates the arm's kinematics with X, Y, Z in the same
    likelihood (:mod:`tmscal.calib.kinematics.solve`, docs/kinematics.md): ``joints`` (n, dof)
    rad, ``arm`` the nominal model (an ``Arm`` or a registry name such as "ur5e"), ``level``
    ("auto", "none", "offsets", "full"), ``tolerances`` (a ``Tolerances``: the prior), ``folds``
    of the held-out level choice; ``distortion`` then "none" (default with kinematics) or a
    fixed model ("auto" is not searched with the arm); ``noise`` as here (estimated inside
    the kinematic fit by default, :mod:`tmscal.calib.kinematics.noise`). ``wrench`` (n, 6)
    [N, N·m] and ``wrench_sigma`` (N, N·m): a wrist sensor's averaged wrench per pose, whose
    gravity rows join that likelihood (docs/kinematics.md, "Wrench rows"); only with
    ``kinematics="estimate"``; ``progress`` the kinematic estimate's progress callback
    (:data:`tmscal.calib.kinematics.estimate.Progress`), only with it."""
    if kinematics is not None:
        from .kinematics.solve import solve_with_kinematics

        if kinematics != "estimate":
            raise CalibrationError(f"method 'ml': unknown kinematics {kinematics!r}; expected "
                                   "'estimate' (or none)")
        return solve_with_kinematics(
            A, B, C, joints=joints, arm=arm, level=level, tolerances=tolerances, folds=folds,
            distortion="none" if distortion == "auto" else distortion, tools_mm=tools_mm,
            robot_sigma_mm=robot_sigma_mm, robot_sigma_deg=robot_sigma_deg,
            tracker_sigma_mm=tracker_sigma_mm, tracker_sigma_deg=tracker_sigma_deg,
            tracker_cov=tracker_cov, spreads=spreads, orthonormal=orthonormal, noise=noise,
            wrench=wrench, wrench_sigma=wrench_sigma, progress=progress)
    if progress is not None:
        raise CalibrationError("method 'ml': progress= reports the kinematic estimate; it goes "
                               "with kinematics='estimate'")
    if wrench is not None:
        raise CalibrationError("method 'ml': the wrench rows go with kinematics='estimate' "
                               "(the wrench sees the arm, not X, Y, Z)")
    if distortion not in DISTORTION_MODELS and distortion != "auto":
        raise CalibrationError(f"method 'ml': unknown distortion {distortion!r}; expected "
                               f"auto, {', '.join(DISTORTION_MODELS)}")
    if criterion not in CRITERIA:
        raise CalibrationError(f"method 'ml': unknown criterion {criterion!r}; expected "
                               f"{', '.join(CRITERIA)}")
    if noise not in NOISE_MODES:
        raise CalibrationError(f"method 'ml': unknown noise {noise!r}; expected "
                               f"{' or '.join(NOISE_MODES)}")
    start = solve(A, B, C, method="qr24" if C is None else "qr36")
    bodies = [B] if C is None else [B, C]
    names = ["marker"] if C is None else ["marker", "probe"]
    opts = {"robot_sigma_mm": robot_sigma_mm, "robot_sigma_deg": robot_sigma_deg,
            "tracker_sigma_mm": tracker_sigma_mm, "tracker_sigma_deg": tracker_sigma_deg,
            "tracker_cov": tracker_cov, "spreads": spreads}
    rs_mm, rs_rad, tracker = _noise(len(A), names, opts)
    T = tracker_part(tracker)
    if spreads is None:
        T = T[0]  # one tracker covariance for every pose
    theta = np.array([rs_rad ** 2, rs_mm ** 2, 1.0])
    estimated = noise == "estimate"
    est = np.array([estimated, estimated,
                    estimated and spreads is None and tracker_cov is None])
    Ws0 = [start.X] if C is None else [start.X, start.Y]
    moments = _moments(tools_mm, names)
    prob0 = Problem(A, bodies, Ws0, start.Z, "none", moments=moments)
    fit, comp, crit = _select(A, bodies, prob0, distortion, theta, T, est, int(max_iter),
                              moments, criterion)
    k = fit.prob.n_params
    # the parameter covariance at the final noise: Σ_k θ_k H A_k H = (Jᵀ S⁻¹ J)⁻¹
    P = sum(comp.parts.values())
    vf = fit.chi2 / (fit.m - k)
    scaled = not estimated and scale_covariance
    if scaled:
        P = P * vf
        comp.parts = {kk: v * vf for kk, v in comp.parts.items()}
    Ws, Z, G = fit.prob.unpack(np.zeros(k))
    D = np.linalg.inv(G)
    G4 = np.eye(4)
    G4[:3, :3] = G
    N_ref = make_pose(orthonormalize(bodies[-1][:, :3, :3].mean(axis=0)),
                      bodies[-1][:, :3, 3].mean(axis=0))
    u = uncertainty_at(fit.prob, P, N_ref, len(bodies) - 1)
    pos, ax = ("coil_centre_mm", "coil_axis_deg") if C is not None else \
        ("marker_origin_mm", "marker_axis_deg")
    unc = {pos: u["position_mm"], ax: u["axis_deg"],
           "target": u["target"], "target_note": f"the session's mean {names[-1]} pose"}
    dist = {"model": fit.prob.model, "matrix": D, "undistort": G,
            "scale_percent": float((np.cbrt(np.linalg.det(D)) - 1.0) * 100.0),
            "axis_scale_percent": (np.diag(D) - 1.0) * 100.0,
            "tool_moments": dict(zip(names, moments, strict=True))}
    cal = Calibration("ml", len(A), X=Ws[0], Z=Z, X_raw=Ws[0].copy(), Z_raw=Z @ G4,
                      applied=Applied.ORTHONORMAL if orthonormal else Applied.RAW,
                      covariance=P, uncertainty=unc, distortion=dist)
    if C is not None:
        cal.Y, cal.Y_raw = Ws[1], Ws[1].copy()
    th = comp.theta
    cal.extra = {"parameters": parameter_names(len(bodies), fit.prob.model),
                 "start": start.method, "iterations": fit.iterations, "chi2": fit.chi2,
                 "residuals": fit.m, "variance_factor": float(vf),
                 "criterion": criterion, criterion: crit,
                 "noise": {"mode": noise,
                           "robot_sigma_mm": float(np.sqrt(th[1])),
                           "robot_sigma_deg": float(np.degrees(np.sqrt(th[0]))),
                           "tracker": "spreads" if spreads is not None else
                           ("tracker_cov" if tracker_cov is not None else "sigmas"),
                           "tracker_factor": float(th[2]),
                           "estimated": [c for c, e in zip(COMPONENTS, est, strict=True) if e],
                           "dof": {c: float(v) for c, v in zip(COMPONENTS, comp.dof,
                                                               strict=True)
                                   if np.isfinite(v)},
                           "scale_covariance": bool(scaled)},
                 "covariance_parts": comp.parts}
    return cal
